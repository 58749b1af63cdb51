"""Live streams: the session resource (``/v1/streams``) and the messages of its WebSocket protocol.

A robot opens a session with ``POST /v1/streams``, connects to its WebSocket and sends frames as binary
messages; the server answers with the JSON messages below. The protocol is documented as an AsyncAPI 3
document (``openapi/asyncapi.json``) generated from these models.

Binary frame message: a 4-byte big-endian length ``L``, then ``L`` bytes of UTF-8 JSON (a
:class:`FrameHeader`), then the image bytes. Flow control follows one rule, :data:`FLOW_CONTROL`.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from api_schemas.parameters import AnalysisParameters, ExcitationSpec
from api_schemas.problem import Problem
from api_schemas.result import AnalysisResult

StreamStatus = Literal["waiting", "streaming", "finishing", "succeeded", "failed"]

#: The protocol's flow-control rule, as the AsyncAPI document states it; the server's relay
#: (``service.streams``) and the Python client (``eigenscope_client.streams``) count by it.
FLOW_CONTROL = (
    "Flow control, one rule: a frame message (binary) is in flight from when the client sends it until "
    "the server acknowledges it. `acked` in `accepted`, `backpressure` and `error` messages counts the frame "
    "messages of this connection the server is done with (taken by the analysis, or refused: dropped or too "
    "large), from 0 at `ready`; it never goes down. In flight = frame messages sent on this connection - "
    "the latest `acked`. Send a frame message only while in flight < `window` (from `ready`). The server "
    "counts the same way (`in_flight` in those messages: those it has received, less `acked`; yours is "
    "at least that, by what is still on the wire): it sends `slow_down` when a message arrives with "
    "3/4 of the window in flight, and refuses a frame message that arrives with the window full "
    "(`backpressure` `dropped`, which acknowledges it). A client that keeps the rule is never dropped; "
    "one that cannot wait (a live camera) may send past it and is told which frames were dropped."
)


class StreamCreate(BaseModel):
    """Request body of ``POST /v1/streams``."""

    model_config = ConfigDict(title="StreamCreate", extra="forbid")

    excitation: ExcitationSpec | None = Field(
        default=None,
        description="How the object is excited (as for a job); without it stiffness and mass are null.",
    )
    parameters: AnalysisParameters = Field(
        default_factory=AnalysisParameters,
        description="Frame rate (`fps`), intrinsics (`fx`, `fy`, `cx`, `cy`) and depth scale when known, "
        "and analysis options. `frames` is the most frames analysed (the window kept from just before the "
        "motion); `method` must be `default`; `start_frame` and the bag topics do not apply.",
    )
    target_relative_uncertainty: float = Field(
        default=0.01,
        gt=0,
        lt=0.5,
        description="`converged` is sent when the eigenfrequency's relative standard uncertainty is at "
        "most this (and the estimate is stable).",
    )
    max_duration_s: float = Field(
        default=60.0, gt=0, description="Longest capture (by frame timestamps) before the server ends it."
    )
    width: int = Field(
        ge=16,
        le=8192,
        description="Frame width, pixels: every frame must declare it (its PNG or JPEG header is read "
        "before it is decoded). Width x height may not pass the server's pixel cap, and the analysis "
        "window of such frames must fit the job memory budget.",
    )
    height: int = Field(ge=16, le=8192, description="Frame height, pixels (see `width`).")


class LiveEstimateModel(BaseModel):
    """The main object's figures from the frames so far (each `*_uncertainty` a standard uncertainty)."""

    model_config = ConfigDict(title="LiveEstimate", json_schema_serialization_defaults_required=True)

    frames_received: int
    frames_used: list[int] = Field(description="[first, last) frame indices whose flow was used.")
    samples_after_release: int = Field(description="Flow samples fitted, from the release on.")
    release_time_s: float = Field(description="Release instant, seconds from the first frame.")
    periods: float = Field(description="Periods of motion fitted.")
    eigenfrequency_hz: float
    eigenfrequency_uncertainty_hz: float
    natural_frequency_hz: float | None = None
    damping_ratio: float | None = None
    damping_ratio_uncertainty: float | None = None
    amplitude_px: float | None = None
    amplitude_m: float | None = None
    amplitude_uncertainty_m: float | None = None
    depth_m: float | None = None
    stiffness_n_per_m: float | None = None
    stiffness_uncertainty_n_per_m: float | None = None
    mass_kg: float | None = None
    mass_uncertainty_kg: float | None = None
    snr_db: float | None = None
    relative_uncertainty: float = Field(description="eigenfrequency_uncertainty_hz / eigenfrequency_hz.")
    converged: bool
    null_reasons: list[str] = Field(default_factory=list)


class StreamModel(BaseModel):
    """A live stream session."""

    model_config = ConfigDict(title="Stream", json_schema_serialization_defaults_required=True)

    id: str
    job_id: str = Field(description="The job the stream ends as (its result, images and clip).")
    clip_id: str = Field(description="The clip the stream's frames are kept as, once it has ended.")
    status: StreamStatus
    websocket_url: str = Field(description="Where to connect: `ws(s)://host/v1/streams/{id}`.")
    resume_token: str | None = Field(
        default=None,
        description="Only in the response that creates the session: send it as `?resume_token=` to "
        "reconnect after a dropped connection.",
    )
    excitation: ExcitationSpec | None = None
    parameters: AnalysisParameters
    target_relative_uncertainty: float
    max_duration_s: float
    frames_received: int = 0
    converged: bool = False
    last_estimate: LiveEstimateModel | None = None
    created_at: datetime
    updated_at: datetime | None = None
    error: Problem | None = None


class StreamList(BaseModel):
    """A page of streams, newest first."""

    model_config = ConfigDict(title="StreamList", json_schema_serialization_defaults_required=True)

    items: list[StreamModel]


# WebSocket messages ----------------------------------------------------------------------------------


class FrameHeader(BaseModel):
    """The JSON header of a binary frame message (bytes 4 to 4 + L of the message; L is the big-endian
    uint32 of bytes 0-3; the image follows).

    Send each frame's colour message first, then (for RGB-D) its depth message with the same `frame`.
    A colour frame is complete when its depth arrives, or when the next colour frame arrives (no depth).
    """

    model_config = ConfigDict(title="FrameHeader", extra="forbid")

    frame: int = Field(ge=0, description="Frame index, from 0, increasing.")
    kind: Literal["color", "depth"]
    timestamp_s: float = Field(description="Capture time, seconds (any origin); increasing.")
    encoding: Literal["jpeg", "png", "raw"] = Field(
        description="Colour: `jpeg` or `png`. Depth: 16-bit `png` or `raw` little-endian uint16."
    )
    width: int | None = Field(default=None, ge=1, description="Required for `raw` depth.")
    height: int | None = Field(default=None, ge=1, description="Required for `raw` depth.")


class EndMessage(BaseModel):
    """Client -> server (text): no more frames; analyse and send the `result`."""

    model_config = ConfigDict(title="EndMessage", extra="forbid")

    type: Literal["end"]


class ReadyMessage(BaseModel):
    """Server -> client, first on every connection."""

    model_config = ConfigDict(title="ReadyMessage", json_schema_serialization_defaults_required=True)

    type: Literal["ready"]
    stream_id: str
    job_id: str
    window: int = Field(description="Most frame messages in flight (see the flow-control rule).")
    next_frame: int = Field(description="The frame index to send next (after a resume: where to go on).")
    messages: int = Field(
        description="Frame messages the worker had consumed when this connection opened (of the whole "
        "stream, earlier connections included). Flow control needs only `acked`."
    )
    resumed: bool = False


_ACKED = Field(
    description="Frame messages of this connection the server is done with, from 0 at `ready`: in flight = "
    "frame messages sent on this connection - `acked` (see the flow-control rule)."
)
_IN_FLIGHT = Field(description="Frame messages in flight as the server counts them (received, less `acked`).")


class AcceptedMessage(BaseModel):
    """Server -> client: a frame was decoded and taken into the analysis; it acknowledges (`acked`) every
    frame message the analysis has taken so far."""

    model_config = ConfigDict(title="AcceptedMessage")

    type: Literal["accepted"]
    frame: int
    acked: int = _ACKED
    in_flight: int = _IN_FLIGHT
    window: int
    messages: int = Field(
        description="Frame messages (colour and depth) the worker has consumed over the whole stream."
    )


class BackpressureMessage(BaseModel):
    """Server -> client: the worker is behind. `slow_down`: a frame message arrived with three quarters of
    the window in flight; `dropped`: this frame message arrived with the window full and is refused (not
    analysed; `acked` counts it). Whole frames are dropped: a depth message follows its colour message
    (dropped with it, or passed on with it even over a full window)."""

    model_config = ConfigDict(title="BackpressureMessage", json_schema_serialization_defaults_required=True)

    type: Literal["backpressure"]
    action: Literal["slow_down", "dropped"]
    frame: int | None = None
    kind: Literal["color", "depth"] | None = None
    acked: int = _ACKED
    in_flight: int = _IN_FLIGHT
    window: int


class EstimateMessage(BaseModel):
    """Server -> client: the estimate from the frames so far (at least 4 a second once motion is seen)."""

    model_config = ConfigDict(title="EstimateMessage", json_schema_serialization_defaults_required=True)

    type: Literal["estimate"]
    estimate: LiveEstimateModel


class ConvergedMessage(BaseModel):
    """Server -> client: the target uncertainty is reached; the robot may stop recording."""

    model_config = ConfigDict(title="ConvergedMessage", json_schema_serialization_defaults_required=True)

    type: Literal["converged"]
    quantity: Literal["eigenfrequency_hz"] = "eigenfrequency_hz"
    relative_uncertainty: float
    target_relative_uncertainty: float
    frames_received: int
    estimate: LiveEstimateModel


class ResultMessage(BaseModel):
    """Server -> client: the final result (the same schema as a job's), sent as soon as the analysis
    ends, then the server closes. The images it names are drawn after it is sent: the stream's job
    completes (and serves them) a moment later, so wait for the job (`GET /v1/jobs/{id}?wait=`) before
    fetching them."""

    model_config = ConfigDict(title="ResultMessage", json_schema_serialization_defaults_required=True)

    type: Literal["result"]
    job_id: str
    clip_id: str
    result: AnalysisResult


class ErrorMessage(BaseModel):
    """Server -> client: an RFC 9457 problem naming the frame (`frame`) or field; a frame message it names
    is skipped (and acknowledged: `acked`). `fatal`: the session is over (the server closes)."""

    model_config = ConfigDict(title="ErrorMessage")

    type: Literal["error"]
    fatal: bool
    frame: int | None = None
    acked: int | None = Field(default=None, description="As in `accepted` (absent before `ready`).")
    in_flight: int | None = Field(default=None, description="As in `accepted` (absent before `ready`).")
    window: int | None = Field(default=None, description="As in `accepted` (absent before `ready`).")
    messages: int | None = Field(default=None, description="As in `accepted`, when the worker sent it.")
    problem: Problem


ServerMessage = Annotated[
    ReadyMessage
    | AcceptedMessage
    | BackpressureMessage
    | EstimateMessage
    | ConvergedMessage
    | ResultMessage
    | ErrorMessage,
    Field(discriminator="type"),
]
