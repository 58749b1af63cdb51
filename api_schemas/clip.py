"""Clip resource as stored and served."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

#: The containers and layouts the clip readers take (``stream``: a live stream's clip before it is filed).
ClipFormat = Literal[
    "npz", "zip-frames", "tum", "open3d", "k4a-mkv", "video", "ros1-bag", "ros2-bag", "stream"
]
#: Where a clip's frame rate comes from.
ClipFpsSource = Literal["user", "bundle", "container", "timestamps", "metadata"]


class CameraIntrinsicsModel(BaseModel):
    """Pinhole intrinsics in pixels."""

    model_config = ConfigDict(title="CameraIntrinsics", allow_inf_nan=False)

    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float


class ClipInfoModel(BaseModel):
    """What was detected in an uploaded clip (the same as ``eigenscope probe`` prints)."""

    model_config = ConfigDict(
        title="Clip", allow_inf_nan=False, json_schema_serialization_defaults_required=True
    )

    id: str
    format: ClipFormat = Field(
        description="Detected container/layout: `npz`, `zip-frames`, `tum`, `open3d`, `k4a-mkv`, `video`, "
        "`ros1-bag` or `ros2-bag`.",
    )
    frames: int = Field(ge=0)
    fps: float | None = Field(description="Frame rate used for analysis, in Hz.")
    fps_source: ClipFpsSource | None = Field(
        default=None,
        description="Where `fps` came from: `user` (given), `bundle` (the npz or `camera.json`), `container` "
        "(the video or bag), `timestamps` (measured from the frames' times) or `metadata` (a capture rate "
        "the file records).",
    )
    width: int
    height: int
    has_depth: bool
    depth_scale: float | None = Field(default=None, description="Metres per depth unit.")
    intrinsics: CameraIntrinsicsModel | None = None
    duration_s: float | None = None
    dropped_frames: int = 0
    streams: list[str] = Field(default_factory=list, description="Streams or topics found in the file.")
    filename: str | None = Field(default=None, description="Name of the uploaded file.")
    size_bytes: int
    created_at: datetime


class ClipList(BaseModel):
    """A page of clips, newest first."""

    model_config = ConfigDict(title="ClipList", json_schema_serialization_defaults_required=True)

    items: list[ClipInfoModel]
    next_cursor: str | None = None
