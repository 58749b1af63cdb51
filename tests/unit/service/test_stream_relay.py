"""The WebSocket relay on its own, with a stand-in transport and socket (issue 27, items 13 and 15)."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from backend.settings import Settings
from backend.store import StreamRecord
from service.metrics import Metrics
from service.streams import Relay


class ScriptedTransport:
    """Worker messages by the time they are sent: ``[(seconds after the relay attached, message)]``."""

    def __init__(self, script: list[tuple[float, dict[str, Any]]]) -> None:
        self.script = sorted(script, key=lambda item: item[0])
        self.started = time.monotonic()
        self.pushed: list[dict[str, Any]] = []

    async def last_cursor(self, _sid: str) -> str:
        return "0"

    async def push(
        self, _sid: str, *, frame: bytes | None = None, control: dict[str, Any] | None = None
    ) -> None:
        if control is not None:
            self.pushed.append(control)

    async def receive(self, _sid: str, cursor: str, timeout_s: float) -> tuple[list[dict[str, Any]], str]:
        deadline = time.monotonic() + timeout_s
        while True:
            due = [m for t, m in self.script if self.started + t <= time.monotonic()]
            fresh = due[int(cursor) :]
            if fresh or time.monotonic() >= deadline:
                return [dict(m, relay=self.relay_id()) if m["type"] == "_status" else m for m in fresh], str(
                    int(cursor) + len(fresh)
                )
            await asyncio.sleep(0.01)

    def relay_id(self) -> str | None:
        attach = next((c for c in self.pushed if c.get("type") == "_attach"), None)
        return None if attach is None else str(attach["relay"])

    async def acleanup(self, _sid: str) -> None:
        pass


class QuietSocket:
    """A client that sends nothing and records what it is sent."""

    def __init__(self) -> None:
        self.sent: list[dict[str, Any]] = []

    async def send_text(self, text: str) -> None:
        self.sent.append(json.loads(text))

    async def receive(self) -> dict[str, Any]:
        await asyncio.sleep(3600)
        return {"type": "websocket.disconnect"}


def relay_for(tmp_path: Path, transport: ScriptedTransport, **settings: Any) -> tuple[Relay, QuietSocket]:
    failed: list[dict[str, Any]] = []
    store = SimpleNamespace(fail_stream_job=lambda _job, problem: failed.append(problem))
    ctx = SimpleNamespace(
        settings=Settings(data_dir=tmp_path, **settings),
        stream_transport=transport,
        store=store,
        metrics=Metrics(store),  # type: ignore[arg-type]
    )
    stream = StreamRecord(
        id="s1",
        owner="",
        job_id="j1",
        clip_id="c1",
        status="streaming",
        token_digest="",
        request={},
        frames_received=0,
        converged=False,
        last_estimate=None,
        error=None,
        created_at=None,  # type: ignore[arg-type]
        updated_at=None,
    )
    ws = QuietSocket()
    return Relay(ctx, ws, stream, resumed=False), ws  # type: ignore[arg-type]


def test_the_wait_for_a_worker_is_not_counted_as_its_silence(tmp_path: Path) -> None:
    """Item 13: a stream that waited longer than the silence tolerance for a free worker was failed
    (`worker-lost`) at the first quiet moment after the worker took it up, heartbeats or not."""
    # A pause of 0.6 s after the attach (the worker busy), then heartbeats: within the tolerance of 1 s.
    beats = [(2.4 + 0.3 * i, {"type": "_heartbeat", "messages": 0}) for i in range(5)]
    result = {"type": "result", "job_id": "j1", "clip_id": "c1", "result": {}}
    transport = ScriptedTransport([(1.8, {"type": "_status", "messages": 0}), *beats, (3.9, result)])
    relay, ws = relay_for(tmp_path, transport, stream_worker_timeout_s=1.0, stream_start_timeout_s=10)
    asyncio.run(asyncio.wait_for(relay.run(), timeout=30))
    kinds = [m["type"] for m in ws.sent]
    assert kinds[0] == "ready"
    assert "error" not in kinds, ws.sent
    assert kinds[-1] == "result"


def test_a_worker_silent_after_it_attached_is_still_lost(tmp_path: Path) -> None:
    transport = ScriptedTransport([(0.1, {"type": "_status", "messages": 0})])
    relay, ws = relay_for(tmp_path, transport, stream_worker_timeout_s=1.0)
    asyncio.run(asyncio.wait_for(relay.run(), timeout=30))
    assert ws.sent[-1]["problem"]["code"] == "worker-lost"


def test_deeply_nested_json_is_an_error_not_a_crash() -> None:
    """Item 15: a text message of 50,000 ``[`` or a frame header nested 2,000 deep raised an uncaught
    RecursionError (the socket closed with 1000 and no error)."""
    import struct

    from service.streams import frame_index, text_message
    from workers.streams import FrameError, parse_frame_message

    assert text_message("[" * 50_000, max_depth=16) is None
    assert text_message('{"type": "end"}', max_depth=16) == {"type": "end"}
    assert text_message('{"type": "end", "x": "[[[[[[[[[[[[[[[[[[[[[[[[[["}', max_depth=16) is not None
    header = ("[" * 2000 + "]" * 2000).encode()
    message = struct.pack(">I", len(header)) + header + b"\xff\xd8"
    assert frame_index(message, max_depth=16) == (None, None)
    with pytest.raises(FrameError, match="nested more than 16 levels"):
        parse_frame_message(message, max_depth=16)


def test_a_deep_text_message_gets_a_non_fatal_error_and_the_stream_goes_on(tmp_path: Path) -> None:
    transport = ScriptedTransport([(0.0, {"type": "_status", "messages": 0})])
    relay, ws = relay_for(tmp_path, transport)
    texts = iter(["[" * 50_000, '{"frame": ' * 3000, '{"type": "end"}'])

    async def receive() -> dict[str, Any]:
        text = next(texts, None)
        if text is None:
            await asyncio.sleep(3600)
        return {"type": "websocket.receive", "text": text}

    ws.receive = receive  # type: ignore[method-assign]

    async def run() -> None:
        task = asyncio.create_task(relay.run())
        while not any(c.get("type") == "end" for c in transport.pushed):
            await asyncio.sleep(0.01)
        task.cancel()

    asyncio.run(asyncio.wait_for(run(), timeout=30))
    errors = [m for m in ws.sent if m["type"] == "error"]
    assert [(m["fatal"], m["problem"]["code"]) for m in errors] == [(False, "invalid-message")] * 2


def test_the_depth_of_a_frame_whose_colour_went_on_is_never_dropped(tmp_path: Path) -> None:
    """A full window drops whole frames: a colour message over the window is dropped with its depth, but
    the depth of a colour the worker already holds follows it even when the window has filled meanwhile
    (dropping it left that frame, and a client waiting for its acknowledgement, hanging until the stream
    timed out)."""
    from eigenscope_client.streams import frame_message

    transport = ScriptedTransport([])
    frames: list[bytes] = []

    async def push(_sid: str, *, frame: bytes | None = None, control: dict[str, Any] | None = None) -> None:
        if frame is not None:
            frames.append(frame)

    transport.push = push  # type: ignore[method-assign]
    relay, ws = relay_for(tmp_path, transport, stream_window=2)

    def message(i: int, kind: str) -> bytes:
        return frame_message(b"x", frame=i, kind=kind, timestamp_s=i / 30, encoding="png")

    async def send(i: int, kind: str) -> None:
        await relay._frame(message(i, kind), 1 << 20)

    async def run() -> None:
        await send(0, "color")
        await send(0, "depth")  # the window of 2 is now full ...
        await send(1, "color")  # ... so frame 1's colour is dropped, and its depth with it
        await send(1, "depth")
        relay.consumed += 1  # the worker took frame 0's colour: room for one message
        await send(2, "color")  # goes on, and fills the window again
        await send(2, "depth")  # follows its colour all the same

    asyncio.run(run())
    kinds = [(m["frame"], m["kind"]) for m in ws.sent if m.get("action") == "dropped"]
    assert kinds == [(1, "color"), (1, "depth")]
    assert len(frames) == 4
