"""Live stream sessions on a worker: frames in, estimates out, a job and a clip at the end.

:func:`run_stream_worker` takes sessions from the stream transport (:mod:`backend.stream_transport`) and
runs up to ``Settings.stream_sessions_per_worker`` of them at once, each on a thread of its own
(:class:`Session`). A session:

1. claims the stream's job (lease renewed while it runs; a worker that dies leaves a lease that expires,
   and the API fails the stream with ``worker-lost``);
2. decodes each frame message, checks it (size, encoding, timestamps, depth with its colour frame: a bad
   one gets a non-fatal ``error`` naming the frame and is skipped), feeds it to
   :class:`workers.pipeline.live.LiveAnalysis` and keeps its bytes in the stream's clip (a TUM RGB-D zip:
   colour as received, depth as 16-bit PNG, per-frame timestamps, ``camera.json``);
3. sends ``accepted`` per frame, an ``estimate`` every ``stream_estimate_interval_s`` once motion is seen,
   ``converged`` once, and internal heartbeats;
4. on ``end``, a silent client, a client gone for longer than the resume window, or the duration limit:
   runs the final analysis on the flow already computed, writes the images and ``result.json`` as a job
   does, sends ``result``, completes the job and files the clip.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import struct
import threading
import time
import zipfile
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from api_schemas import AnalysisParameters, FrameHeader, StreamCreate
from backend.errors import PROBLEM_TYPES, problem_document
from backend.settings import Settings
from backend.storage import Storage, tree_bytes
from backend.store import ClaimOutcome, Store, StreamRecord, lease_owner_token
from backend.stream_transport import Item, StreamTransport, transport_for
from backend.strict_json import loads_shallow

if TYPE_CHECKING:
    from workers.metrics import WorkerMetrics

log = logging.getLogger(__name__)

#: However fast frames arrive, an estimate is made at least every this many seconds of the capture.
ESTIMATE_EVERY_CAPTURE_S = 0.5

#: Seconds between heartbeats (the API fails a stream whose worker is silent for stream_worker_timeout_s).
HEARTBEAT_S = 0.5
#: Seconds between writes of the latest estimate to the stream's record (what GET /v1/streams shows).
RECORD_EVERY_S = 0.5
#: Seconds a stopping stream worker gives its sessions to fail their jobs and tell their clients.
STOP_GRACE_S = 3.0


class FrameError(Exception):
    """A frame message that cannot be used; ``frame`` names it when its header could be read."""

    def __init__(self, detail: str, *, frame: int | None, code: str = "invalid-frame") -> None:
        super().__init__(detail)
        self.detail, self.frame, self.code = detail, frame, code


def parse_frame_message(
    data: bytes, *, max_header: int = 4096, max_depth: int = 16
) -> tuple[FrameHeader, bytes]:
    """Split a binary frame message into its header and its image bytes; :class:`FrameError` if bad."""
    if len(data) < 4:
        raise FrameError("a frame message must start with a 4-byte header length", frame=None)
    (length,) = struct.unpack(">I", data[:4])
    if not 2 <= length <= max_header or len(data) < 4 + length:
        raise FrameError(
            f"frame message header length {length} is not in [2, {max_header}] or exceeds the message",
            frame=None,
        )
    try:
        raw = loads_shallow(data[4 : 4 + length], max_depth=max_depth)
    except ValueError as exc:
        raise FrameError(f"frame message header is not JSON: {exc}", frame=None) from None
    frame = raw.get("frame") if isinstance(raw, dict) else None
    try:
        header = FrameHeader.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(x) for x in err.get("loc", ())) or "header"
        raise FrameError(
            f"frame {frame}: header field {where}: {err.get('msg')}"
            if isinstance(frame, int)
            else f"frame message header field {where}: {err.get('msg')}",
            frame=frame if isinstance(frame, int) else None,
        ) from None
    return header, data[4 + length :]


@dataclass
class _Pending:
    """A decoded colour frame waiting for its depth frame."""

    frame: int
    rgb: NDArray[np.uint8]
    timestamp_s: float
    data: bytes
    encoding: str


class ClipWriter:
    """The stream's frames as a TUM RGB-D zip, written as they arrive (colour stored as received, depth as
    16-bit PNG) by a thread of its own: PNG-encoding a 640x480 depth frame costs about 10 ms, which the
    frame loop does not wait for (at most ``max_pending`` frames queue up; then it does)."""

    def __init__(self, path: Path, *, max_pending: int = 32) -> None:
        from concurrent.futures import Future, ThreadPoolExecutor

        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._zip = zipfile.ZipFile(path, "w", zipfile.ZIP_STORED, allowZip64=True)
        self._rgb: list[str] = []
        self._depth: list[str] = []
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="clip-writer")
        self._pending: deque[Future[None]] = deque()
        self._max_pending = max_pending
        self.frames = 0
        self.bytes = 0

    def add(
        self,
        *,
        frame: int,
        timestamp_s: float,
        color: bytes,
        color_ext: str,
        depth: NDArray[np.uint16] | None,
    ) -> None:
        stamp = f"{timestamp_s:.6f}"
        name = f"rgb/{frame:06d}.{color_ext}"
        self._rgb.append(f"{stamp} {name}")
        dname = None
        if depth is not None:
            dname = f"depth/{frame:06d}.png"
            self._depth.append(f"{stamp} {dname}")
        while len(self._pending) >= self._max_pending:
            self._pending.popleft().result()
        self._pending.append(self._pool.submit(self._write, name, color, dname, depth))
        self.frames += 1
        self.bytes += len(color) + (depth.nbytes if depth is not None else 0)  # at most what is stored

    def _write(self, name: str, color: bytes, dname: str | None, depth: NDArray[np.uint16] | None) -> None:
        import cv2

        self._zip.writestr(name, color)
        if dname is not None and depth is not None:
            options = [
                cv2.IMWRITE_PNG_COMPRESSION,
                1,
                cv2.IMWRITE_PNG_STRATEGY,
                cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
            ]
            ok, buf = cv2.imencode(".png", depth, options)
            if not ok:
                raise OSError(f"depth frame {dname} could not be encoded")
            self._zip.writestr(dname, bytes(buf))

    def _drain(self) -> None:
        while self._pending:
            self._pending.popleft().result()
        self._pool.shutdown(wait=True)

    def close(self, camera: dict[str, float]) -> int:
        """Write the lists and ``camera.json``, close; returns the file's size."""
        self._drain()
        header = "# written by an eigenscope live stream: timestamp filename\n"
        self._zip.writestr("rgb.txt", header + "\n".join(self._rgb) + "\n")
        if self._depth and len(self._depth) == len(self._rgb):
            self._zip.writestr("depth.txt", header + "\n".join(self._depth) + "\n")
        self._zip.writestr("camera.json", json.dumps(camera))
        self._zip.close()
        return self.path.stat().st_size

    def discard(self) -> None:
        try:
            self._drain()
            self._zip.close()
        finally:
            self.path.unlink(missing_ok=True)
            if self.path.parent.name.startswith("stream-"):  # its own folder in tmp/
                shutil.rmtree(self.path.parent, ignore_errors=True)


@dataclass
class Session:
    """One live stream on this worker; :meth:`run` blocks until it has ended."""

    stream_id: str
    settings: Settings
    store: Store
    storage: Storage
    transport: StreamTransport
    record: StreamRecord | None = None
    metrics: Any = None  # a workers.metrics.WorkerMetrics: the stream's job is counted as any other
    messages: int = 0
    attached: bool = False
    ever_attached: bool = False
    detached_at: float | None = None
    #: The API relay the client is attached through (each WebSocket connection has its own).
    relay: str | None = None
    last_input: float = field(default_factory=time.monotonic)
    started: float = field(default_factory=time.monotonic)
    _pending: _Pending | None = None
    _last_frame: int = -1
    _last_time: float | None = None
    _first_time: float | None = None
    _size: tuple[int, int] | None = None  # (width, height)
    _live: Any = None
    _clip: ClipWriter | None = None
    _converged_sent: bool = False
    _estimated_at: float | None = None  # capture time (the last frame's timestamp) of the last estimate
    _end_reason: str | None = None
    #: Input read ahead, in order, to see whether the client has ended the stream; handled next.
    _inbox: list[Item] = field(default_factory=list)
    _timings: dict[str, float] = field(default_factory=dict)
    _claimed_at: float = 0.0
    _counted: bool = False  # the job has been counted in the worker metrics (once)
    _has_depth: bool = False
    #: What this stream's frames may take of its key's storage quota.
    _room_bytes: int = 0
    _send_lock: threading.Lock = field(default_factory=threading.Lock)
    _over: threading.Event = field(default_factory=threading.Event)
    #: Set when the stream worker stops: the session ends at once (its job fails as `worker-lost`).
    shutdown: threading.Event = field(default_factory=threading.Event)

    def send(self, message: dict[str, Any]) -> None:
        """Send ``message`` to the client's relay; nothing once ``result`` or a fatal error has gone."""
        kind = message.get("type")
        with self._send_lock:
            if self._over.is_set():
                return
            self.transport.send(self.stream_id, message)
            if kind == "result" or (kind == "error" and message.get("fatal")):
                self._over.set()

    def _heartbeat(self) -> None:
        """Tell the relay this worker is alive every HEARTBEAT_S, whatever the session is busy with (a
        final analysis on a loaded machine may take longer than the relay's patience), until the session
        is over. A worker that dies stops beating: the relay's ``worker-lost``."""
        while not self._over.wait(HEARTBEAT_S):
            self.send({"type": "_heartbeat", "messages": self.messages})

    def error(self, code: str, detail: str, *, frame: int | None = None, fatal: bool = False) -> None:
        extra = {"frame": frame} if frame is not None else {}
        self.send(
            {
                "type": "error",
                "fatal": fatal,
                "frame": frame,
                "messages": self.messages,
                "problem": problem_document(code, detail, **extra),
            }
        )

    # ------------------------------------------------------------------------------------------
    def run(self) -> None:
        record = self.store.find_stream(self.stream_id)
        if record is None:
            log.warning("stream %s: no record (deleted?); dropped", self.stream_id)
            self.transport.cleanup(self.stream_id)
            return
        self.record = record
        owner = lease_owner_token()
        claim = self.store.claim_job(record.job_id, owner)
        if claim.outcome is not ClaimOutcome.CLAIMED:
            self.error(
                "stream-ended", f"stream {self.stream_id} cannot be run ({claim.outcome.value})", fatal=True
            )
            if claim.outcome in (ClaimOutcome.FINISHED, ClaimOutcome.MISSING):
                # It ended before this worker took it up (no worker came in time, it was cancelled):
                # nobody reads its messages any more.
                self.transport.cleanup(self.stream_id)
            return
        from backend.store import Lease

        if self.metrics is not None and claim.job is not None:
            wait = max(time.time() - claim.job.enqueued_at, 0.0) if claim.job.enqueued_at else 0.0
            self.metrics.claimed(claim.job, queue_wait_s=wait)
        self._claimed_at, outcome, failure = time.monotonic(), "aborted", None
        workdir: Path | None = None
        beat = threading.Thread(target=self._heartbeat, name=f"stream-{self.stream_id}-beat", daemon=True)
        beat.start()
        try:
            with Lease(self.store, record.job_id, owner) as lease:
                request = StreamCreate.model_validate(record.request)
                self._size = (request.width, request.height)  # declared, checked at creation
                used = self.store.usage(record.owner).stored_bytes
                self._room_bytes = self.settings.max_stored_bytes_per_key - used
                self._loop(request, lease)
                if lease.lost.is_set():
                    raise _AbortError("the stream's job was cancelled or taken over")
                self.store.update_stream(self.stream_id, status="finishing")
                workdir = self.storage.new_job_workdir(record.job_id, 1)
                self._finish(request, owner, workdir)
                outcome = "succeeded"
        except _AbortError as exc:
            problem = problem_document("stream-aborted", str(exc))
            self.store.update_stream(self.stream_id, status="failed", error=problem)
            self.error("stream-aborted", str(exc), fatal=True)
            self._discard_clip()
        except _FailedError as exc:
            outcome, failure = "failed", str(exc.problem.get("code") or "analysis-failed")
            self._count(outcome, failure)
            self.store.fail_job(record.job_id, owner, exc.problem)
            self.store.update_stream(self.stream_id, status="failed", error=exc.problem)
            self.send({"type": "error", "fatal": True, "frame": None, "problem": exc.problem})
            self._discard_clip()
        except Exception as exc:
            problem = _crash_problem(self.stream_id, exc, self.settings)
            outcome, failure = "failed", str(problem["code"])
            self._count(outcome, failure)
            self.store.fail_job(record.job_id, owner, problem)
            self.store.update_stream(self.stream_id, status="failed", error=problem)
            self.send({"type": "error", "fatal": True, "frame": None, "problem": problem})
            self._discard_clip()
        finally:
            self._over.set()
            self._count(outcome, failure)
            beat.join()
            if self._live is not None:
                self._live.close()
            if workdir is not None:
                shutil.rmtree(workdir, ignore_errors=True)
            if not self.attached:  # nobody will read the rest: remove everything now
                self.transport.cleanup(self.stream_id)

    def _count(self, outcome: str, failure: str | None) -> None:
        """Count the stream's job in the worker metrics, once: before its final state is stored, so whoever
        sees the job end sees it counted (the ``finally`` counts an aborted one)."""
        if self.metrics is None or self._counted:
            return
        self._counted = True
        took = time.monotonic() - self._claimed_at
        self.metrics.ended(outcome=outcome, duration_s=took, failure=failure, timings_s=self._timings)

    def _discard_clip(self) -> None:
        if self._clip is not None:
            self._clip.discard()
            self._clip = None

    def _loop(self, request: StreamCreate, lease: Any) -> None:
        try:
            self._run_loop(request, lease)
        finally:
            log.info("stream %s: input ended (%s)", self.stream_id, self._end_reason or "stopped")

    def _run_loop(self, request: StreamCreate, lease: Any) -> None:
        s = self.settings
        next_estimate = 0.0
        next_record = 0.0
        max_duration = min(request.max_duration_s, s.stream_max_duration_s)
        while self._end_reason is None:
            if lease.lost.is_set():
                return
            if self.shutdown.is_set():
                raise _FailedError(
                    problem_document(
                        "worker-lost",
                        "the stream worker running this stream was stopped; the stream's job is failed: "
                        "open a new stream",
                    )
                )
            items = self._next_input(0.05)
            now = time.monotonic()
            for item in items:
                self._handle(item, request)
                if self._end_reason is not None:
                    break
                if self._capture_estimate_due():
                    # A sender faster than the worker (a recorded stream, a backlog) still gets its
                    # estimates at the same points of the capture as a camera's.
                    next_estimate = time.monotonic() + s.stream_estimate_interval_s
                    self._estimate(request, record=False)
            if items:
                self.send({"type": "_progress", "messages": self.messages})
            now = time.monotonic()
            live = self._live
            # Once the client has ended the stream, the result is what it waits for: no more estimates of
            # the wall clock, also when its end is still queued behind frames (those at points of the
            # capture are kept, so that a recorded stream gets the same estimates however fast it is sent).
            if (
                self._end_reason is None
                and live is not None
                and live.motion_seen
                and now >= next_estimate
                and not self._end_queued()
            ):
                next_estimate = now + s.stream_estimate_interval_s
                self._estimate(request, record=now >= next_record)
                if now >= next_record:
                    next_record = now + RECORD_EVERY_S
            if (
                self._first_time is not None
                and self._last_time is not None
                and (self._last_time - self._first_time >= max_duration)
            ):
                self.error(
                    "max-duration",
                    f"the capture reached max_duration_s={max_duration:g} s; the stream is analysed as it is",
                )
                self._end_reason = "max-duration"
            elif self.attached and now - self.last_input > s.stream_client_timeout_s:
                self.error(
                    "client-timeout",
                    f"no frame or message for {s.stream_client_timeout_s:g} s; the stream is analysed as it "
                    "is",
                )
                self._end_reason = "client-timeout"
            elif not self.attached and now - (self.detached_at or self.started) > max(
                s.stream_resume_window_s, s.stream_start_timeout_s if not self.ever_attached else 0.0
            ):
                self._end_reason = "client-gone"

    def _handle(self, item: Item, request: StreamCreate) -> None:
        self.last_input = time.monotonic()
        if item.kind == "control":
            ctl = item.control or {}
            kind = ctl.get("type")
            if kind == "end":
                self._end_reason = "end"
            elif kind == "_attach":
                self.attached, self.ever_attached, self.detached_at = True, True, None
                self.relay = ctl.get("relay")
                next_frame = self._last_frame + 1 if self._pending is None else self._pending.frame + 1
                self.send(
                    {
                        "type": "_status",
                        "relay": ctl.get("relay"),
                        "messages": self.messages,
                        "next_frame": next_frame,
                    }
                )
            elif kind == "_detach" and ctl.get("relay") == self.relay:
                # A connection the client has already replaced (it reconnected, and the new relay
                # attached before the old one saw the client leave) detaches nothing.
                self.attached, self.detached_at = False, time.monotonic()
            return
        self.messages += 1
        try:
            self._frame(item.data, request)
        except FrameError as exc:
            self.error(exc.code, exc.detail, frame=exc.frame)
        finally:
            # The client's silence counts from when this worker was ready for more: a frame whose push
            # waited on the analysis (a loaded machine) is the worker's delay, not the client's.
            self.last_input = time.monotonic()

    # Frames ------------------------------------------------------------------------------------
    def _frame(self, data: bytes, request: StreamCreate) -> None:
        import cv2

        header, payload = parse_frame_message(data, max_depth=self.settings.stream_max_json_depth)
        i = header.frame
        if header.kind == "color":
            if self._pending is not None and self._pending.frame != i:
                self._complete(self._pending, None, request)
                self._pending = None
            if i <= self._last_frame or (self._pending is not None and self._pending.frame == i):
                raise FrameError(
                    f"frame {i}: index does not follow frame {self._last_frame}; frame indices must increase",
                    frame=i,
                )
            if self._last_time is not None and header.timestamp_s <= self._last_time:
                raise FrameError(
                    f"frame {i}: timestamp {header.timestamp_s} s is not after the previous frame's "
                    f"{self._last_time} s; timestamps must increase",
                    frame=i,
                    code="timestamp-backwards",
                )
            if not math.isfinite(header.timestamp_s):
                raise FrameError(f"frame {i}: timestamp is not finite", frame=i)
            if header.encoding not in ("jpeg", "png"):
                raise FrameError(f"frame {i}: colour must be jpeg or png, not {header.encoding}", frame=i)
            self._check_declared(i, "colour", payload, header.encoding)
            bgr = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_COLOR) if payload else None
            if bgr is None:
                raise FrameError(
                    f"frame {i}: the colour image cannot be decoded as {header.encoding} "
                    f"({len(payload)} bytes)",
                    frame=i,
                    code="undecodable-frame",
                )
            self._check_size(i, "colour", bgr.shape[1], bgr.shape[0])
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            self._pending = _Pending(
                i, rgb, header.timestamp_s, payload, "jpg" if header.encoding == "jpeg" else "png"
            )
            return
        pending = self._pending
        if pending is None or pending.frame != i:
            raise FrameError(
                f"frame {i}: depth frame without its colour frame; send each frame's colour message first, "
                "then its depth",
                frame=i,
                code="depth-without-color",
            )
        depth_raw = self._decode_depth(i, header, payload)
        self._check_size(i, "depth", depth_raw.shape[1], depth_raw.shape[0])
        self._pending = None
        self._complete(pending, depth_raw, request)

    def _decode_depth(self, i: int, header: FrameHeader, payload: bytes) -> NDArray[np.uint16]:
        import cv2

        if header.encoding == "raw":
            if header.width is None or header.height is None:
                raise FrameError(f"frame {i}: raw depth needs width and height in its header", frame=i)
            self._check_size(i, "depth", header.width, header.height)
            expected = header.width * header.height * 2
            if len(payload) != expected:
                raise FrameError(
                    f"frame {i}: raw depth of {header.width}x{header.height} needs {expected} bytes, "
                    f"got {len(payload)}",
                    frame=i,
                    code="wrong-size",
                )
            return np.frombuffer(payload, "<u2").reshape(header.height, header.width).astype(np.uint16)
        if header.encoding != "png":
            raise FrameError(f"frame {i}: depth must be 16-bit png or raw, not {header.encoding}", frame=i)
        self._check_declared(i, "depth", payload, "png")
        img = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_UNCHANGED) if payload else None
        if img is None:
            raise FrameError(
                f"frame {i}: the depth image cannot be decoded as png", frame=i, code="undecodable-frame"
            )
        if img.dtype != np.uint16 or img.ndim != 2:
            raise FrameError(
                f"frame {i}: depth must be a 16-bit single-channel png (got {img.dtype}, {img.ndim} dims)",
                frame=i,
            )
        return np.asarray(img, np.uint16)

    def _check_declared(self, i: int, what: str, payload: bytes, encoding: str) -> None:
        """Refuse a frame from what its image header declares (PNG IHDR, JPEG SOF), before it is decoded:
        it must be the encoding its message names and the stream's declared size."""
        from workers.pipeline.clipio._common import image_header
        from workers.pipeline.errors import ClipError

        try:
            declared = image_header(payload[:65536], f"frame {i}: {what}")
        except ClipError as exc:
            raise FrameError(str(exc), frame=i, code="undecodable-frame") from None
        if declared.kind != encoding:
            raise FrameError(
                f"frame {i}: the {what} image is {declared.kind}, but its header says {encoding}",
                frame=i,
                code="undecodable-frame",
            )
        self._check_size(i, what, declared.width, declared.height)

    def _check_size(self, i: int, what: str, width: int, height: int) -> None:
        """Refuse a frame of another size than the stream's declared one."""
        assert self._size is not None
        w, h = self._size
        if (width, height) != (w, h):
            raise FrameError(
                f"frame {i}: {what} is {width}x{height}, but the stream's frames are {w}x{h}",
                frame=i,
                code="wrong-size",
            )

    def _complete(
        self, pending: _Pending, depth_raw: NDArray[np.uint16] | None, request: StreamCreate
    ) -> None:

        from workers.pipeline.clipio.types import depth_to_metres

        params = request.parameters
        if self._live is None:
            self._start_live(request, pending.rgb.shape[1], pending.rgb.shape[0])
        depth_m = None
        if depth_raw is not None:
            self._has_depth = True
            depth_m = depth_to_metres(depth_raw, params.depth_scale or 0.001)
        try:
            self._live.push(rgb=pending.rgb, depth_m=depth_m, timestamp_s=pending.timestamp_s)
        except Exception as exc:
            if getattr(exc, "code", None) == "invalid-clip":
                raise FrameError(str(exc), frame=pending.frame) from None
            raise
        if self._first_time is None:
            self._first_time = pending.timestamp_s
        self._last_frame, self._last_time = pending.frame, pending.timestamp_s
        assert self._clip is not None
        self._clip.add(
            frame=pending.frame,
            timestamp_s=pending.timestamp_s - self._first_time,
            color=pending.data,
            color_ext=pending.encoding,
            depth=depth_raw,
        )
        if self._clip.bytes >= self._room_bytes and self._end_reason is None:
            mib = self.settings.max_stored_mb_per_key
            self.error(
                "storage-quota-exceeded",
                f"the stream's frames reached this API key's storage quota of {mib} MiB "
                "(EIGENSCOPE_MAX_STORED_MB_PER_KEY); the stream is analysed as it is",
                frame=pending.frame,
            )
            self._end_reason = "storage-quota"
        in_flight = 0
        self.send(
            {
                "type": "accepted",
                "frame": pending.frame,
                "messages": self.messages,
                "in_flight": in_flight,
                "window": self.settings.stream_window,
            }
        )

    def _start_live(self, request: StreamCreate, width: int, height: int) -> None:
        from backend.stream_transport import DEFAULT_WINDOW_FRAMES
        from workers.pipeline.clipio.types import Intrinsics
        from workers.pipeline.live import LiveAnalysis, LiveConfig
        from workers.runner import pipeline_excitations, requested_excitations

        p = request.parameters
        intrinsics = None
        if p.fx is not None or p.fy is not None:
            fx = p.fx if p.fx is not None else p.fy
            fy = p.fy if p.fy is not None else p.fx
            assert fx is not None
            assert fy is not None
            intrinsics = Intrinsics(
                fx=fx,
                fy=fy,
                cx=p.cx if p.cx is not None else (width - 1) / 2,
                cy=p.cy if p.cy is not None else (height - 1) / 2,
            )
        excitations = pipeline_excitations(requested_excitations(request.excitation))
        main = next(
            (e for e in excitations if e.object_id in (None, 1) and e.point_px is None and e.box_px is None),
            None,
        )
        config = LiveConfig(
            fps=p.fps,
            window_frames=p.frames or DEFAULT_WINDOW_FRAMES,
            target_relative_uncertainty=request.target_relative_uncertainty,
            min_frequency_hz=p.min_frequency_hz,
            max_frequency_hz=p.max_frequency_hz,
            depth_m=p.depth_m,
        )
        self._live = LiveAnalysis(
            width=width, height=height, intrinsics=intrinsics, config=config, excitation=main
        )
        assert self.record is not None
        self._clip = ClipWriter(self.storage.root / "tmp" / f"stream-{self.stream_id}" / "clip.zip")

    def _next_input(self, timeout_s: float) -> list[Item]:
        """The input read ahead by :meth:`_end_queued`, else what the transport has within ``timeout_s``."""
        if not self._inbox:
            return self.transport.read(self.stream_id, timeout_s)
        items, self._inbox = self._inbox, []
        return items

    # Estimates ---------------------------------------------------------------------------------
    def _end_queued(self) -> bool:
        """Whether the client has already ended the stream in input not yet handled (what there is to read
        now is read ahead, in order, into the loop's inbox). An estimate of the wall clock made then would
        only delay the result, which is what the client waits for: a camera's last frame and ``end`` come
        moments apart, and an estimate costs tens of milliseconds (40-80 ms on a worker keeping up with
        640 x 480 at 30 fps)."""
        self._inbox.extend(self.transport.read(self.stream_id, 0.0))
        return any(i.kind == "control" and (i.control or {}).get("type") == "end" for i in self._inbox)

    def _capture_estimate_due(self) -> bool:
        """Whether the capture has advanced :data:`ESTIMATE_EVERY_CAPTURE_S` since the last estimate."""
        live, last = self._live, self._last_time
        if live is None or last is None or not live.motion_seen:
            return False
        return self._estimated_at is None or last - self._estimated_at >= ESTIMATE_EVERY_CAPTURE_S

    def _estimate(self, request: StreamCreate, *, record: bool) -> None:
        from workers.pipeline.live_estimate import estimate_dict

        self._estimated_at = self._last_time
        est = self._live.estimate()
        if est is None:
            return
        model = live_estimate_json(estimate_dict(est))
        self.send({"type": "estimate", "estimate": model})
        if est.converged and not self._converged_sent:
            self._converged_sent = True
            self.send(
                {
                    "type": "converged",
                    "quantity": "eigenfrequency_hz",
                    "relative_uncertainty": est.relative_uncertainty,
                    "target_relative_uncertainty": request.target_relative_uncertainty,
                    "frames_received": est.frames_received,
                    "estimate": model,
                }
            )
            record = True
        if record:
            self.store.update_stream(
                self.stream_id,
                frames_received=est.frames_received,
                converged=self._converged_sent,
                last_estimate=model,
            )

    # The end -------------------------------------------------------------------------------------
    def _finish(self, request: StreamCreate, owner: str, workdir: Path) -> None:
        """Analyse the window, send ``result`` at once, then draw the images and complete the job.

        The numbers go out before the images are drawn (a robot waits for the numbers; drawing takes
        about as long as the analysis): the job, with its images, completes a moment later, so a client
        that wants the images waits for the job (``GET /v1/jobs/{id}?wait=``).
        """
        from backend.urls import artifact_url
        from workers.drawing import draw_all
        from workers.pipeline.errors import EigenscopeError
        from workers.pipeline.figures import ARTIFACT_FILES
        from workers.runner import (
            analysis_config,
            build_result,
            pipeline_excitations,
            requested_excitations,
            write_result_json,
        )

        assert self.record is not None
        if self._pending is not None:
            self._complete(self._pending, None, request)
            self._pending = None
        if self._live is None:
            raise _FailedError(
                problem_document(
                    "analysis-failed",
                    f"the stream ended ({self._end_reason}) before any frame arrived",
                )
            )
        params = request.parameters
        requested = requested_excitations(request.excitation)
        config = analysis_config(params.model_copy(update={"frames": None}))
        try:
            analysis = self._live.finish(analysis_config=config, excitations=pipeline_excitations(requested))
        except EigenscopeError as exc:
            raise _FailedError(problem_document(_job_code(exc), str(exc))) from exc
        self._timings = dict(analysis.timings_s)
        result = build_result(analysis, excitation=requested, parameters=params, artifacts=ARTIFACT_FILES)
        job_id = self.record.job_id
        doc = result.model_dump(mode="json")
        served = dict(doc)
        served["artifacts"] = {
            k: artifact_url(job_id, v) if isinstance(v, str) else v for k, v in doc["artifacts"].items()
        }
        self.send({"type": "result", "job_id": job_id, "clip_id": self.record.clip_id, "result": served})
        # Then the images, the job (the same result as sent), and the frames filed as a clip that can be
        # analysed again: the stream has succeeded once all three are done.
        draw_all(analysis, workdir)
        write_result_json(workdir, result)
        self.storage.publish_job_outputs(job_id, workdir)
        self._count("succeeded", None)
        if not self.store.complete_job(
            job_id, owner, doc, output_bytes=tree_bytes(self.storage.job_dir(job_id))
        ):
            raise _AbortError("the stream's job was cancelled")
        self._file_clip(params, analysis.fps)
        self.store.update_stream(
            self.stream_id,
            only_active=False,
            status="succeeded",
            frames_received=self._live.frames_received,
        )

    def _file_clip(self, params: AnalysisParameters, fps: float) -> None:
        """Close the clip and make it the stream's clip record (analysable again as any upload)."""
        from workers.pipeline.clipio import open_clip

        assert self.record is not None
        assert self._clip is not None
        live = self._live
        camera: dict[str, float] = {"fps": fps, "depth_scale": params.depth_scale or 0.001}
        if live.intrinsics is not None:
            k = live.intrinsics
            camera |= {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy}
        size = self._clip.close(camera)
        clip_dir = self.storage.root / "clips" / self.record.clip_id
        clip_dir.mkdir(parents=True, exist_ok=True)
        target = clip_dir / "clip.zip"
        os.replace(self._clip.path, target)
        shutil.rmtree(self._clip.path.parent, ignore_errors=True)
        self._clip = None
        try:
            with open_clip(target) as reader:
                info = reader.info.to_dict()
        except Exception as exc:  # the frames are still there; the record says why it cannot be read
            log.warning("stream %s: its clip cannot be read back: %s", self.stream_id, exc)
            info = {"format": "tum", "frames": 0, "width": 0, "height": 0, "fps": fps, "has_depth": False}
        self.store.update_clip(
            self.record.clip_id,
            path=target.relative_to(self.storage.root).as_posix(),
            info=info,
            size_bytes=size,
        )


def _crash_problem(stream_id: str, exc: Exception, settings: Settings) -> dict[str, Any]:
    """The problem of a session that raised ``exc``: over the memory budget, or an internal error."""
    from workers.execution import is_exhaustion

    if is_exhaustion(exc):
        log.warning("stream %s: over its memory budget (%s: %s)", stream_id, type(exc).__name__, exc)
        return problem_document(
            "resources-exhausted",
            f"the stream needed more memory than its budget of {settings.job_memory_mb} MiB "
            "(EIGENSCOPE_JOB_MEMORY_MB); send smaller frames or a shorter window (parameters.frames)",
        )
    log.exception("stream %s failed", stream_id)
    return problem_document("internal-error", f"the stream failed: {type(exc).__name__}: {exc}")


def stream_worker_budget_mb(settings: Settings, in_use_bytes: int) -> int:
    """The stream worker's address-space cap, MiB: what it uses with no session (``in_use_bytes``) plus
    the job memory budget for each session it runs at once (0: no cap, when ``JOB_MEMORY_MB`` is 0)."""
    if settings.job_memory_mb <= 0:
        return 0
    return in_use_bytes // 2**20 + settings.job_memory_mb * settings.stream_sessions_per_worker


class _AbortError(Exception):
    """The stream's job is no longer this worker's."""


def _job_code(exc: BaseException) -> str:
    """The error code of a pipeline error, ``analysis-failed`` when it has none of the table's."""
    code = getattr(exc, "code", None)
    return code if isinstance(code, str) and code in PROBLEM_TYPES else "analysis-failed"


class _FailedError(Exception):
    def __init__(self, problem: dict[str, Any]) -> None:
        super().__init__(problem.get("detail"))
        self.problem = problem


def live_estimate_json(values: dict[str, Any]) -> dict[str, Any]:
    """A live estimate (``estimate_dict``) as the API gives it (:class:`LiveEstimateModel`: the pipeline's
    names are the API's)."""
    from api_schemas import LiveEstimateModel

    return LiveEstimateModel.model_validate(values).model_dump(mode="json")


def _address_cap() -> str:
    import resource

    soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
    return "nothing" if soft == resource.RLIM_INFINITY else f"{soft // 2**20} MiB"


def run_stream_worker(settings: Settings, *, stop: threading.Event | None = None) -> None:
    """Take stream sessions and run them, ``stream_sessions_per_worker`` at a time, until ``stop``."""
    # The pipeline and matplotlib are imported now, not after a stream's last frame.
    import workers.pipeline.live  # noqa: F401 - imported before any session needs it
    from workers.drawing import warm_up
    from workers.metrics import WorkerMetrics

    warm_up()
    from workers.execution import memory_budget, vm_size_bytes

    with memory_budget(stream_worker_budget_mb(settings, vm_size_bytes())):
        _serve_sessions(settings, stop or threading.Event(), WorkerMetrics())


def _serve_sessions(settings: Settings, stop: threading.Event, metrics: WorkerMetrics) -> None:
    transport = transport_for(settings)
    store = Store(settings.effective_database_url, lease_s=settings.lease_s, max_attempts=1)
    storage = Storage(settings.data_path)
    storage.ensure()
    slots = threading.Semaphore(settings.stream_sessions_per_worker)
    log.info(
        "stream worker %d ready: %d session(s) at once, %s transport, address space capped at %s",
        os.getpid(),
        settings.stream_sessions_per_worker,
        "redis" if settings.redis_url else "local",
        _address_cap(),
    )

    shutdown = threading.Event()
    sessions: list[threading.Thread] = []

    def run(stream_id: str) -> None:
        try:
            Session(
                stream_id,
                settings,
                store,
                storage,
                transport_for(settings),
                metrics=metrics,
                shutdown=shutdown,
            ).run()
        except Exception:
            log.exception("stream %s: session crashed", stream_id)
        finally:
            slots.release()

    try:
        _take_sessions(settings, transport, slots, stop, run, sessions)
    finally:
        shutdown.set()  # the sessions under way end now, and fail their jobs
        deadline = time.monotonic() + STOP_GRACE_S
        for thread in sessions:
            thread.join(timeout=max(deadline - time.monotonic(), 0.0))
        log.info("stream worker %d stopped", os.getpid())


def _take_sessions(
    settings: Settings,
    transport: StreamTransport,
    slots: threading.Semaphore,
    stop: threading.Event,
    run: Any,
    sessions: list[threading.Thread],
) -> None:
    """Claim sessions and start each on a thread of its own (listed in ``sessions``) until ``stop``."""
    while not stop.is_set():
        if not slots.acquire(timeout=0.5):
            continue
        try:
            stream_id = transport.claim(1.0)
        except Exception:
            log.warning("stream worker: the transport is unavailable", exc_info=True)
            slots.release()
            stop.wait(1.0)
            continue
        if stream_id is None:
            slots.release()
            continue
        log.info("stream %s: taken up", stream_id)
        thread = threading.Thread(target=run, args=(stream_id,), name=f"stream-{stream_id[:8]}", daemon=True)
        thread.start()
        sessions[:] = [t for t in sessions if t.is_alive()] + [thread]
