"""A stream's session on a worker (workers.streams.Session), run on the local transport with frames
already queued, as a sender faster than the worker leaves them: what it sends back, in order."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from eigenscope_client.streams import frame_message

from backend.settings import Settings
from backend.storage import Storage
from backend.store import NewClip, NewStream, Store, StreamRecord
from backend.stream_transport import LocalTransport
from workers.pipeline.synth import Scene, SceneObject, SceneReader

WIDTH, HEIGHT, FRAMES = 192, 144, 72


def _stream(store: Store) -> StreamRecord:
    stream, _job = store.create_stream(
        NewStream(
            stream_id="s1",
            owner="",
            token_digest="0" * 64,
            request={"width": WIDTH, "height": HEIGHT, "parameters": {"fps": 30.0}},
            expires_at=None,
            clip=NewClip(
                clip_id="cs1", filename="stream.zip", path="clips/cs1/clip.zip", info={}, size_bytes=0
            ),
            excitation=None,
            parameters={},
        )
    )
    return stream


def _queue_frames(transport: LocalTransport, stream_id: str, *, end: bool) -> None:
    """A connection's relay attaching, a ring-down's colour frames as JPEG, then (``end``) the client's
    ``end``, all queued at once."""
    obj = SceneObject(
        center_px=(WIDTH / 2, HEIGHT / 2),
        size_px=(50.0, 40.0),
        frequency_hz=4.5,
        force_n=6.0,
        release_frame=4,
    )
    scene = Scene(width=WIDTH, height=HEIGHT, frames=FRAMES, fps=30.0, objects=(obj,), seed=3)

    async def push() -> None:
        await transport.push(stream_id, control={"type": "_attach", "relay": "r1"})  # as the API's relay does
        for f in SceneReader(scene, depth=False).frames():
            bgr = cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR)
            jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])[1]
            message = frame_message(
                jpeg.tobytes(), frame=f.index, kind="color", timestamp_s=f.timestamp_s, encoding="jpeg"
            )
            await transport.push(stream_id, frame=message)
        if end:
            await transport.push(stream_id, control={"type": "end"})

    asyncio.run(push())


def _session(
    store: Store, settings: Settings, transport: LocalTransport, *, end: bool
) -> list[dict[str, Any]]:
    """A stream's frames (and ``end``) queued before a worker takes it up and runs its session to its
    end; every message the session sent."""
    from workers.streams import Session

    stream = _stream(store)
    asyncio.run(transport.dispatch(stream.id))
    assert transport.claim(0.1) == stream.id
    _queue_frames(transport, stream.id, end=end)
    storage = Storage(settings.data_path)
    storage.ensure()
    Session(stream.id, settings, store, storage, transport).run()
    messages, _cursor = asyncio.run(transport.receive(stream.id, "0", 0.1))
    kinds = [m["type"] for m in messages]
    assert kinds.count("accepted") == FRAMES, kinds
    assert kinds[-1] == "result", kinds
    return messages


@pytest.fixture
def transport(tmp_path: Path) -> LocalTransport:
    return LocalTransport(tmp_path / "streams")


def test_an_end_queued_behind_frames_leaves_only_the_estimates_at_points_of_the_capture(
    store: Store, settings: Settings, transport: LocalTransport
) -> None:
    """The client has ended the stream: every frame it sent is analysed, each gets the estimates due at
    points of its capture (every ESTIMATE_EVERY_CAPTURE_S: a recorded stream gets the same ones however
    fast it is sent), and none of the wall clock delays the result (due after every batch here, the end of
    the first would otherwise bring one, a few frames after the last point of the capture)."""
    from workers.streams import ESTIMATE_EVERY_CAPTURE_S

    eager = settings.model_copy(update={"stream_estimate_interval_s": 0.001})
    sent = _session(store, eager, transport, end=True)
    at = [m["estimate"]["frames_received"] for m in sent if m["type"] == "estimate"]
    assert len(at) >= 2, at
    assert min(np.diff(at)) >= round(ESTIMATE_EVERY_CAPTURE_S * 30.0), at


def test_frames_queued_faster_than_the_worker_still_get_estimates_until_the_stream_ends(
    store: Store, settings: Settings, transport: LocalTransport
) -> None:
    """Without an ``end`` queued, a backlog gets its estimates at points of the capture, as a camera's
    frames do (the stream then ends when the client falls silent)."""
    quiet = settings.model_copy(update={"stream_client_timeout_s": 0.5})
    kinds = [m["type"] for m in _session(store, quiet, transport, end=False)]
    assert kinds.count("estimate") >= 2, [(i, k) for i, k in enumerate(kinds) if k != "accepted"]


def test_a_connection_the_client_replaced_detaches_nothing(
    store: Store, settings: Settings, transport: LocalTransport, tmp_path: Path
) -> None:
    """The client reconnected: the new connection's relay attached before the old one saw the client
    leave. The old relay's ``_detach`` leaves the stream attached; the current relay's detaches it."""
    from api_schemas.stream import StreamCreate
    from backend.stream_transport import Item
    from workers.streams import Session

    stream = _stream(store)
    session = Session(stream.id, settings, store, Storage(tmp_path / "data"), transport)
    request = StreamCreate.model_validate(stream.request)

    def control(kind: str, relay: str) -> None:
        session._handle(Item("control", b"", {"type": kind, "relay": relay}), request)

    control("_attach", "r1")
    control("_attach", "r2")
    control("_detach", "r1")
    assert session.attached
    assert session.detached_at is None
    control("_detach", "r2")
    assert not session.attached
    assert session.detached_at is not None
