"""Frames of a ground-truth scene, encoded as a robot would send them, and a raw WebSocket client."""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from eigenscope_client import frame_message
from pydantic import TypeAdapter

from api_schemas import ServerMessage

#: Every server message must parse as one of the protocol's models (those the AsyncAPI document is
#: generated from), so the document says what the server does.
SERVER_MESSAGE: TypeAdapter[Any] = TypeAdapter(ServerMessage)


@dataclass(frozen=True)
class EncodedFrame:
    color_png: bytes
    depth_raw: bytes
    timestamp_s: float


@dataclass(frozen=True)
class SceneFrames:
    frames: list[EncodedFrame]
    width: int
    height: int
    fps: float
    intrinsics: tuple[float, float, float, float]
    truth: dict[str, Any]


@functools.cache
def scene_frames(
    *,
    frames: int = 90,
    width: int = 320,
    height: int = 240,
    frequency_hz: float = 4.5,
    release_frame: int = 10,
) -> SceneFrames:
    """A 4.5 Hz spring-mass object (0.8 kg, held by 6 N) released at ``release_frame``, as PNG colour and
    raw little-endian uint16 depth (millimetres)."""
    from workers.pipeline.synth import Scene, SceneObject, SceneReader

    obj = SceneObject(
        center_px=(width / 2, height / 2),
        size_px=(width * 0.25, height * 0.25),
        frequency_hz=frequency_hz,
        mass_kg=0.8,
        force_n=6.0,
        release_frame=release_frame,
    )
    scene = Scene(width=width, height=height, frames=frames, fps=30.0, objects=(obj,), seed=11)
    reader = SceneReader(scene)
    out = []
    for f in reader.frames():
        ok, png = cv2.imencode(
            ".png", cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1]
        )
        assert ok
        assert f.depth_m is not None
        depth = np.rint(np.nan_to_num(f.depth_m) * 1000).astype("<u2")
        out.append(EncodedFrame(bytes(png), depth.tobytes(), f.timestamp_s))
    return SceneFrames(out, width, height, 30.0, scene.intrinsics, reader.truth["objects"][0])


def session_kwargs(scene: SceneFrames, **extra: Any) -> dict[str, Any]:
    fx, fy, cx, cy = scene.intrinsics
    return {
        "fps": scene.fps,
        "fx": fx,
        "fy": fy,
        "cx": cx,
        "cy": cy,
        "depth_scale": 0.001,
        "excitation": {"type": "step_release", "force_n": 6.0},
        "width": scene.width,
        "height": scene.height,
        **extra,
    }


def send_scene(session: Any, scene: SceneFrames, *, start: int = 0, stop: int | None = None) -> None:
    for f in scene.frames[start:stop]:
        session.send_frame(
            f.color_png,
            timestamp_s=f.timestamp_s,
            depth=f.depth_raw,
            color_encoding="png",
            width=scene.width,
            height=scene.height,
        )


class RawSocket:
    """A bare WebSocket to a stream (to send what a well-behaved client would not)."""

    def __init__(self, url: str, headers: dict[str, str] | None = None) -> None:
        from eigenscope_client.streams import connect_websocket

        self.ws = connect_websocket(url, additional_headers=headers or {}, open_timeout=30, max_size=None)
        self.seen: list[dict[str, Any]] = []

    def recv(self, timeout: float = 60.0) -> dict[str, Any]:
        message: dict[str, Any] = json.loads(self.ws.recv(timeout=timeout))
        SERVER_MESSAGE.validate_python(message)
        self.seen.append(message)
        return message

    def until(self, kind: str, timeout: float = 60.0, **match: Any) -> dict[str, Any]:
        """The next message of type ``kind`` (with the given fields), skipping others."""
        while True:
            m = self.recv(timeout)
            if m["type"] == kind and all(m.get(k) == v for k, v in match.items()):
                return m

    def frame(self, data: bytes, **header: Any) -> None:
        self.ws.send(frame_message(data, **header))

    def close(self) -> None:
        self.ws.close()
