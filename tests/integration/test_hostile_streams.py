"""Streams under abuse (issue 27): what a hostile client sent to a real ``eigenscope serve``.

One embedded service for the module (its stream worker's memory and files are watched); receive
timeouts only guard against hangs, nothing here asserts how long anything took.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import service_harness as h
from stream_helpers import RawSocket

pytestmark = [pytest.mark.integration, pytest.mark.slow]

#: The stream worker runs two sessions under an address-space cap of 2 x JOB_MEMORY_MB over its base.
JOB_MEMORY_MB = 3072
SETTINGS = {
    "stream_worker_timeout_s": "4",
    "stream_client_timeout_s": "4",
    "stream_resume_window_s": "4",
    "stream_start_timeout_s": "20",
    "job_memory_mb": str(JOB_MEMORY_MB),
    "stream_sessions_per_worker": "2",
}
SIZE = {"width": 320, "height": 240}


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    service = h.start_embedded(tmp_path_factory.mktemp("hostile-streams"), **SETTINGS)
    yield service
    service.stop()


@pytest.fixture(scope="module")
def stream_worker(served: h.LiveService) -> int:
    """The pid of the service's stream worker (once it says it is ready)."""
    pid = h.find_process(served.procs[0].pid, "stream-worker")
    h.wait_stream_worker_logged(served)
    return pid


def big_jpeg(width: int, height: int) -> bytes:
    """A JPEG of a few hundred bytes that declares ``width`` x ``height`` (a decoder would allocate the
    whole picture for it: 200 MB at 8192x8192)."""
    ok, buf = cv2.imencode(".jpg", np.zeros((16, 16, 3), np.uint8))
    assert ok
    data = bytearray(buf)
    sof = data.find(b"\xff\xc0")
    data[sof + 5 : sof + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    return bytes(data)


def open_stream(service: h.LiveService, **body: Any) -> tuple[dict[str, Any], RawSocket]:
    created = service.client.post("/v1/streams", json={"parameters": {"fps": 30}, **SIZE, **body})
    assert created.status_code == 201, created.text
    stream = created.json()
    ws = RawSocket(stream["websocket_url"])
    ws.until("ready")
    return stream, ws


def test_a_streams_frame_size_is_declared_capped_and_checked_before_decoding(
    served: h.LiveService, stream_worker: int
) -> None:
    """Item 2: no stream without a declared size, none over the pixel cap or the memory budget, and
    frames that declare another size are refused before they are decoded: the worker's peak memory
    stays flat under 8192x8192 frames."""
    for body, words in (
        ({"parameters": {"fps": 30}}, "width"),
        ({"width": 8192, "height": 8192}, "EIGENSCOPE_MAX_PIXELS_PER_FRAME"),
        ({"width": 4096, "height": 4096}, "EIGENSCOPE_JOB_MEMORY_MB"),
    ):
        refused = served.client.post("/v1/streams", json=body)
        assert refused.status_code == 422, (body, refused.text)
        assert words in refused.text, (body, refused.text)
    _stream, ws = open_stream(served)
    try:
        Path(f"/proc/{stream_worker}/clear_refs").write_text("5")  # the peak RSS starts again from now
        before_kib = h.proc_status_kib(stream_worker, "VmRSS")
        frame = big_jpeg(8192, 8192)
        for i in range(6):
            ws.frame(frame, frame=i, kind="color", timestamp_s=i / 30, encoding="jpeg")
        codes = [ws.until("error", frame=i)["problem"]["code"] for i in range(6)]
        peak_kib = h.proc_status_kib(stream_worker, "VmHWM")
        assert codes == ["wrong-size"] * 6
        assert peak_kib - before_kib < 64 * 1024, (before_kib, peak_kib)  # one decode would be 200 MB
        ws.ws.send('{"type": "end"}')
        ws.until("error", timeout=60)  # no frame arrived: the stream fails, the worker goes on
    finally:
        ws.close()


def test_the_stream_worker_runs_under_the_job_memory_budget(
    served: h.LiveService, stream_worker: int
) -> None:
    """Item 2: the stream worker's address space is capped at its base plus the job memory budget of
    each session it runs at once."""
    limits = Path(f"/proc/{stream_worker}/limits").read_text()
    line = next(x for x in limits.splitlines() if x.startswith("Max address space"))
    soft = line.split()[3]
    assert soft != "unlimited", line
    cap_mib = int(soft) // 2**20
    in_use_mib = h.proc_status_kib(stream_worker, "VmSize") // 1024
    assert 2 * JOB_MEMORY_MB < cap_mib <= in_use_mib + 2 * JOB_MEMORY_MB, (cap_mib, in_use_mib)
    assert re.search(r"address space capped at \d+ MiB", served.logs())


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_five_stops_after_a_live_stream_leave_no_process(tmp_path: Path) -> None:
    """Item 6: a SIGTERM to ``eigenscope serve`` after a live stream left a stream worker running (the
    watcher respawned it while stopping). Five times: start, stream, SIGTERM serve alone or its whole
    process group; no stream worker is started once the stop has begun (the log names each one that
    was: a respawned one is not among the processes seen before the stop), and every process it had, or
    started since, is gone once it has exited."""
    import os
    import signal

    from stream_helpers import scene_frames

    scene = scene_frames(frames=20)
    left_after: list[list[int]] = []
    respawned: list[list[int]] = []
    for attempt in range(5):
        service = h.start_embedded(tmp_path / f"run{attempt}", **SETTINGS)
        ws = None
        try:
            serve = service.procs[0]
            h.wait_stream_worker_logged(service)
            body = {"width": scene.width, "height": scene.height}
            _stream, ws = open_stream(service, **body)
            for i, f in enumerate(scene.frames[:8]):
                ws.frame(f.color_png, frame=i, kind="color", timestamp_s=f.timestamp_s, encoding="png")
            ws.until("accepted", frame=6)  # the session is live on the stream worker
            family = h.descendants(serve.pid)
            assert any("stream-worker" in h.cmdline(p) for p in family)
            if attempt % 2:
                os.kill(serve.pid, signal.SIGTERM)  # serve alone, as an operator does
            else:
                os.killpg(serve.pid, signal.SIGTERM)  # all of them at once, as systemd or a Ctrl-C does
            serve.popen.wait(timeout=60)
            log = serve.log_path.read_text()
            started = {int(pid) for pid in re.findall(r"stream worker (\d+) ready", log)}
            respawned.append(sorted(started - set(family)))
            family = [*family, *respawned[-1]]
            deadline = time.monotonic() + 5  # the orphans' exit statuses land
            while any(_alive(p) for p in family) and time.monotonic() < deadline:
                time.sleep(0.05)
            left_after.append([p for p in family if _alive(p)])
        finally:
            if ws is not None:
                ws.close()
            service.stop()
    print(f"\nFAULT five stops after a live stream: processes left {[len(x) for x in left_after]}")
    assert respawned == [[]] * 5, f"stream workers started while stopping: {respawned}"
    assert left_after == [[]] * 5, [[h.cmdline(p) or p for p in left] for left in left_after]


def twenty_mib_frame(ws: RawSocket, frame: int) -> None:
    ws.frame(
        b"\xff\xd8" + bytes(20 * 2**20), frame=frame, kind="color", timestamp_s=frame / 30, encoding="jpeg"
    )


def test_a_20_mib_frame_under_the_32_mib_limit_reaches_the_worker(served: h.LiveService) -> None:
    """Item 7: uvicorn's own 16 MiB message limit closed the connection (1009) on frames the stream's
    limit (32 MiB) allows; now the frame reaches the worker, which says what is wrong with it."""
    _stream, ws = open_stream(served)
    try:
        twenty_mib_frame(ws, 0)
        error = ws.until("error", frame=0)
        assert error["fatal"] is False
        assert error["problem"]["code"] == "undecodable-frame"
        ws.ws.send('{"type": "end"}')
        assert ws.until("error", timeout=60)["fatal"] is True  # the stream ends: no frame arrived
    finally:
        ws.close()


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    """A service with small limits: 8 MiB frames, 1 MiB of storage per key."""
    settings = {**SETTINGS, "stream_max_frame_mb": "8", "max_stored_mb_per_key": "1"}
    service = h.start_embedded(tmp_path_factory.mktemp("small-limits"), **settings)
    h.wait_stream_worker_logged(service)
    yield service
    service.stop()


def test_a_20_mib_frame_over_an_8_mib_limit_gets_frame_too_large_and_the_stream_goes_on(
    small: h.LiveService,
) -> None:
    from stream_helpers import scene_frames

    scene = scene_frames(frames=20)
    _stream, ws = open_stream(small)
    try:
        twenty_mib_frame(ws, 0)
        error = ws.until("error", frame=0)
        assert (error["fatal"], error["problem"]["code"]) == (False, "frame-too-large")
        f = scene.frames[1]
        ws.frame(f.color_png, frame=1, kind="color", timestamp_s=f.timestamp_s, encoding="png")
        ws.frame(f.color_png, frame=2, kind="color", timestamp_s=f.timestamp_s + 0.1, encoding="png")
        assert ws.until("accepted", frame=1)["frame"] == 1  # the same connection goes on
    finally:
        ws.close()


def test_a_stream_stops_at_its_keys_storage_quota(small: h.LiveService) -> None:
    """Item 11: streams made clips with no quota check; now a stream's frames end it, analysed as it
    is, once they reach the key's quota (1 MiB here: a few 320x240 RGB-D frames)."""
    from stream_helpers import scene_frames

    scene = scene_frames(frames=90)
    _stream, ws = open_stream(small)
    try:
        quota_error = None
        for i, f in enumerate(scene.frames):
            ws.frame(f.color_png, frame=i, kind="color", timestamp_s=f.timestamp_s, encoding="png")
            raw = {"encoding": "raw", "width": scene.width, "height": scene.height}
            ws.frame(f.depth_raw, frame=i, kind="depth", timestamp_s=f.timestamp_s, **raw)
            m = ws.recv()
            while m["type"] not in ("accepted", "error"):
                m = ws.recv()
            if m["type"] == "error":
                quota_error = m
                break
        assert quota_error is not None, "90 frames of 300 KB each fitted a quota of 1 MiB"
        assert (quota_error["fatal"], quota_error["problem"]["code"]) == (False, "storage-quota-exceeded")
        end = ws.recv(timeout=120)
        while end["type"] not in ("result", "error"):
            end = ws.recv(timeout=120)
        assert end["type"] == "result" or end["fatal"] is True  # the stream ended with what it had
    finally:
        ws.close()


def test_deeply_nested_json_gets_non_fatal_errors_on_a_live_stream(served: h.LiveService) -> None:
    """Item 15: 50,000 ``[`` as a text message, or a frame header nested 2,000 deep, killed the relay
    (an uncaught RecursionError, the socket closed with 1000 and no error)."""
    import struct

    _stream, ws = open_stream(served)
    try:
        ws.ws.send("[" * 50_000)
        assert ws.until("error")["problem"]["code"] == "invalid-message"
        header = ("[" * 2000 + "]" * 2000).encode()
        ws.ws.send(struct.pack(">I", len(header)) + header + b"\xff\xd8")
        error = ws.until("error")
        assert (error["fatal"], error["problem"]["code"]) == (False, "invalid-frame")
        ws.ws.send('{"type": "end"}')
        assert ws.until("error", timeout=60)["fatal"] is True  # the same connection is still served
    finally:
        ws.close()
