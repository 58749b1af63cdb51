"""Live streams: session creation and views, and the WebSocket relay between a client and its worker.

The relay (:class:`Relay`) never decodes a frame. It passes the client's binary frame messages to the
session's worker through the stream transport, and the worker's messages back, and it does the flow
control by the protocol's one rule (:data:`api_schemas.stream.FLOW_CONTROL`): a frame message is in
flight from its arrival until it is *acknowledged* (consumed by the worker, or refused); each
``accepted``, ``backpressure`` and ``error`` carries ``acked``, the connection's acknowledged frame
messages so far, and at most ``Settings.stream_window`` may be in flight. At three quarters of the window
the client gets a ``backpressure`` ``slow_down``; a frame message beyond it is refused with a
``backpressure`` ``dropped`` naming the frame, never lost silently nor buffered without bound. A worker
that is silent for ``stream_worker_timeout_s`` (or never takes the session up within
``stream_start_timeout_s``) ends the session with a fatal ``error`` and fails its job.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import json
import logging
import struct
import time
import uuid
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.websockets import WebSocket, WebSocketDisconnect

from api_schemas import StreamCreate, StreamModel
from backend.errors import InvalidInputError, ServiceError, UnavailableError, problem_document
from backend.store import NewClip, NewStream, StreamRecord, new_id
from backend.stream_transport import DEFAULT_WINDOW_FRAMES, new_token
from backend.strict_json import loads_shallow
from service.auth import authenticate, client_address
from service.context import ServiceContext
from service.retention import expiry
from service.views import excitation_json

log = logging.getLogger(__name__)

#: Parameters of a job that do not apply to a stream.
_NOT_FOR_STREAMS = ("start_frame", "color_topic", "depth_topic")
#: Bytes a stream's worker keeps per pixel of each frame in its window: the grey image (1) and the depth
#: in metres (4) (:class:`workers.pipeline.live.LiveAnalysis`).
_WINDOW_BYTES_PER_PIXEL = 5


def stream_memory_mib(width: int, height: int, frames: int) -> float:
    """Address space a stream's analysis window of ``frames`` frames of ``width`` x ``height`` takes,
    MiB: what its worker keeps per frame, twice over (address space runs at about twice the resident
    memory, as for a job's budget, ``JOB_MEMORY_MB``)."""
    return 2 * frames * width * height * _WINDOW_BYTES_PER_PIXEL / 2**20


def token_digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def _invalid(field: str, msg: str) -> InvalidInputError:
    return InvalidInputError(
        f"{field}: {msg}", code="invalid-parameter", errors=[{"loc": ["body", *field.split(".")], "msg": msg}]
    )


def websocket_url(base_url: str, root_path: str, stream_id: str) -> str:
    """``ws(s)://host[/root]/v1/streams/{id}`` for an API reached at ``base_url``."""
    scheme, _, rest = base_url.partition("://")
    host = rest.split("/", 1)[0]
    ws = "wss" if scheme == "https" else "ws"
    return f"{ws}://{host}{root_path}/v1/streams/{stream_id}"


def stream_view(stream: StreamRecord, *, ws_url: str, token: str | None = None) -> StreamModel:
    request = stream.request
    return StreamModel.model_validate(
        {
            "id": stream.id,
            "job_id": stream.job_id,
            "clip_id": stream.clip_id,
            "status": stream.status,
            "websocket_url": ws_url,
            "resume_token": token,
            "excitation": request.get("excitation"),
            "parameters": request.get("parameters") or {},
            "target_relative_uncertainty": request.get("target_relative_uncertainty", 0.01),
            "max_duration_s": request.get("max_duration_s", 60.0),
            "frames_received": stream.frames_received,
            "converged": stream.converged,
            "last_estimate": stream.last_estimate,
            "created_at": stream.created_at,
            "updated_at": stream.updated_at,
            "error": stream.error,
        }
    )


def check_request(ctx: ServiceContext, body: StreamCreate) -> None:
    """Reject options a stream cannot honour, before anything is recorded."""
    p = body.parameters
    if p.method != "default":
        raise _invalid("parameters.method", "streams are analysed with the default method only")
    for name in _NOT_FOR_STREAMS:
        if getattr(p, name) is not None:
            raise _invalid(f"parameters.{name}", f"{name} does not apply to a live stream; leave it out")
    _check_frame_size(ctx, body)
    limit = ctx.settings.stream_max_duration_s
    if body.max_duration_s > limit:
        raise _invalid(
            "max_duration_s", f"at most {limit:g} s on this server (EIGENSCOPE_STREAM_MAX_DURATION_S)"
        )


def _check_frame_size(ctx: ServiceContext, body: StreamCreate) -> None:
    """The declared frame size under the pixel cap, and its analysis window under the memory budget."""
    settings = ctx.settings
    pixels = body.width * body.height
    if pixels > settings.max_pixels_per_frame:
        raise _invalid(
            "width",
            f"frames of {body.width}x{body.height} have {pixels} pixels, over this server's cap of "
            f"{settings.max_pixels_per_frame} (EIGENSCOPE_MAX_PIXELS_PER_FRAME); send smaller frames",
        )
    frames = body.parameters.frames or DEFAULT_WINDOW_FRAMES
    need = stream_memory_mib(body.width, body.height, frames)
    if settings.job_memory_mb and need > settings.job_memory_mb:
        raise _invalid(
            "width",
            f"an analysis window of {frames} frames of {body.width}x{body.height} needs about "
            f"{need:.0f} MiB, over the job memory budget of {settings.job_memory_mb} MiB "
            "(EIGENSCOPE_JOB_MEMORY_MB); send smaller frames or a shorter window (parameters.frames)",
        )


async def create_stream(
    ctx: ServiceContext, body: StreamCreate, *, tenant: str, base_url: str, root_path: str
) -> StreamModel:
    """Record the stream, its clip and its job, and hand the session to the workers."""
    check_request(ctx, body)
    stream_id, clip_id, token = new_id(), new_id(), new_token()
    request = body.model_dump(mode="json", exclude_none=True)
    request["parameters"] = body.parameters.model_dump(mode="json", exclude_none=True)
    info = {
        "format": "stream",
        "frames": 0,
        "width": body.width,
        "height": body.height,
        "fps": body.parameters.fps,
        "fps_source": "user" if body.parameters.fps else None,
        "has_depth": False,
        "streams": ["live stream " + stream_id],
    }
    new = NewStream(
        stream_id=stream_id,
        owner=tenant,
        token_digest=token_digest(token),
        request=request,
        expires_at=expiry(time.time(), ctx.settings.retention_s),
        clip=NewClip(
            clip_id=clip_id,
            filename=f"stream-{stream_id}.zip",
            path=f"clips/{clip_id}/clip.zip",
            info=info,
            size_bytes=0,
        ),
        excitation=excitation_json(body.excitation),
        parameters=request["parameters"],
    )
    stream, job = await run_in_threadpool(ctx.store.create_stream, new, limits=ctx.tenant_limits)
    try:
        await ctx.stream_transport.dispatch(stream_id)
    except Exception as exc:
        problem = problem_document("unavailable", f"the stream transport failed: {exc}")
        await run_in_threadpool(ctx.store.fail_stream_job, job.id, problem)
        raise UnavailableError("the stream workers cannot be reached; try again shortly") from exc
    ctx.metrics.jobs_created.inc()
    log.info("stream %s: created (job %s, clip %s)", stream_id, job.id, clip_id)
    return stream_view(stream, ws_url=websocket_url(base_url, root_path, stream_id), token=token)


# The relay --------------------------------------------------------------------------------------


#: Largest JSON header of a frame message, and largest text message, bytes.
MAX_HEADER_BYTES = 4096


def frame_index(data: bytes, *, max_depth: int) -> tuple[int | None, str | None]:
    """The ``frame`` and ``kind`` of a frame message's header, if it can be read (no image is decoded)."""
    try:
        (length,) = struct.unpack(">I", data[:4])
        if length > MAX_HEADER_BYTES:
            return None, None
        header = loads_shallow(data[4 : 4 + length], max_depth=max_depth)
        frame, kind = header.get("frame"), header.get("kind")
        return (frame if isinstance(frame, int) else None), (kind if kind in ("color", "depth") else None)
    except (struct.error, ValueError, AttributeError):
        return None, None


def text_message(text: str, *, max_depth: int) -> dict[str, Any] | None:
    """A client's text message as a JSON object, None when it is not one (too long, nested too deep,
    malformed): it is answered with a non-fatal ``invalid-message`` error, never a crash."""
    if len(text) > MAX_HEADER_BYTES:
        return None
    try:
        doc = loads_shallow(text, max_depth=max_depth)
    except ValueError:
        return None
    return doc if isinstance(doc, dict) else None


class Relay:
    """One WebSocket connection of a stream, relayed to and from its worker."""

    def __init__(self, ctx: ServiceContext, ws: WebSocket, stream: StreamRecord, *, resumed: bool) -> None:
        self.ctx, self.ws, self.stream, self.resumed = ctx, ws, stream, resumed
        self.settings = ctx.settings
        self.transport = ctx.stream_transport
        self.window = self.settings.stream_window
        self.relay_id = uuid.uuid4().hex
        self.received = 0  # frame messages this connection received (passed on or refused)
        self.refused = 0  # ... of which refused here (over the window, too large)
        self.base: int | None = None  # messages the worker had consumed when this connection attached
        self.consumed = 0
        self.ended_at: float | None = None  # when the client said `end` (the result's latency)
        self.slowed = False
        self.dropped: set[int] = set()
        #: The last frame whose colour message went on to the worker.
        self.colour_sent: int | None = None
        self.last_worker = time.monotonic()
        self.done = asyncio.Event()
        self.sid = stream.id

    @property
    def acked(self) -> int:
        """This connection's frame messages the server is done with: consumed by the worker or refused."""
        return self.consumed - (self.base or 0) + self.refused

    @property
    def in_flight(self) -> int:
        return self.received - self.acked

    def _flow(self) -> dict[str, int]:
        """The flow-control members of a message: ``acked``, ``in_flight`` and ``window``."""
        return {"acked": self.acked, "in_flight": max(self.in_flight, 0), "window": self.window}

    async def send(self, message: dict[str, Any]) -> None:
        with contextlib.suppress(Exception):
            await self.ws.send_text(json.dumps(message, separators=(",", ":")))

    async def fatal(self, code: str, detail: str, *, fail_job: bool) -> None:
        problem = problem_document(code, detail)
        # The job fails before the client hears of it: a client told `worker-lost` may read the job at once.
        if fail_job:
            await run_in_threadpool(self.ctx.store.fail_stream_job, self.stream.job_id, problem)
        await self.send({"type": "error", "fatal": True, "frame": None, "problem": problem})
        if fail_job:
            with contextlib.suppress(Exception):
                await self.transport.acleanup(self.sid)
        self.done.set()

    async def run(self) -> None:
        cursor = await self.transport.last_cursor(self.sid)
        await self.transport.push(self.sid, control={"type": "_attach", "relay": self.relay_id})
        status, cursor = await self._await_attach(cursor)
        if status is None:
            return
        # The worker's silence is counted from its answer: the wait for a free worker is not silence.
        self.last_worker = time.monotonic()
        self.base = self.consumed = int(status.get("messages", 0))
        await self.send(
            {
                "type": "ready",
                "stream_id": self.sid,
                "job_id": self.stream.job_id,
                "window": self.window,
                "next_frame": int(status.get("next_frame", 0)),
                "messages": self.base,
                "resumed": self.resumed,
            }
        )
        self.ctx.metrics.stream_sessions.inc()
        try:
            await self._relay(cursor)
        finally:
            self.ctx.metrics.stream_sessions.dec()

    async def _relay(self, cursor: str) -> None:
        downstream = asyncio.create_task(self._downstream(cursor))
        upstream = asyncio.create_task(self._upstream())
        finished, _ = await asyncio.wait({downstream, upstream}, return_when=asyncio.FIRST_COMPLETED)
        if upstream in finished and not self.done.is_set():
            # The client left (or broke the protocol): the worker waits for a resume, then ends the stream.
            await self.transport.push(self.sid, control={"type": "_detach", "relay": self.relay_id})
        for task in (downstream, upstream):
            task.cancel()
        for task in (downstream, upstream):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    async def _await_attach(self, cursor: str) -> tuple[dict[str, Any] | None, str]:
        """Wait for the worker's answer to this connection's ``_attach``."""
        deadline = time.monotonic() + self.settings.stream_start_timeout_s
        while time.monotonic() < deadline:
            messages, cursor = await self.transport.receive(self.sid, cursor, 0.25)
            for m in messages:
                if m.get("type") == "_status" and m.get("relay") == self.relay_id:
                    return m, cursor
                if m.get("type") in ("result", "error") and m.get("fatal", True):
                    await self.send(m)
                    self.done.set()
                    return None, cursor
        await self.fatal(
            "no-worker",
            f"no worker took the stream up within {self.settings.stream_start_timeout_s:g} s; start "
            "`eigenscope worker` processes (or more of them) and open a new stream",
            fail_job=True,
        )
        return None, cursor

    async def _downstream(self, cursor: str) -> None:
        timeout = self.settings.stream_worker_timeout_s
        while not self.done.is_set():
            messages, cursor = await self.transport.receive(self.sid, cursor, 0.25)
            now = time.monotonic()
            if messages:
                self.last_worker = now
            elif now - self.last_worker > timeout:
                await self.fatal(
                    "worker-lost",
                    f"the worker running this stream has been silent for {timeout:g} s (it crashed or was "
                    "stopped); the stream's job is failed: open a new stream",
                    fail_job=True,
                )
                return
            for m in messages:
                kind = m.get("type", "")
                if "messages" in m:
                    self.consumed = max(self.consumed, int(m["messages"]))
                if kind.startswith("_"):
                    continue
                if kind in ("accepted", "error"):
                    m.update(self._flow())
                if kind == "result" and self.ended_at is not None:
                    self.ctx.metrics.stream_latency.observe(time.monotonic() - self.ended_at)
                await self.send(m)
                if kind == "result" or (kind == "error" and m.get("fatal")):
                    self.done.set()
                    with contextlib.suppress(Exception):
                        await self.transport.acleanup(self.sid)
                    return
            if self.slowed and self.in_flight <= self.window // 2:
                self.slowed = False

    async def _upstream(self) -> None:
        max_bytes = self.settings.stream_max_frame_mb * 1024 * 1024
        while not self.done.is_set():
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                raise WebSocketDisconnect(message.get("code", 1000))
            data = message.get("bytes")
            if data is not None:
                await self._frame(data, max_bytes)
                continue
            doc = text_message(message.get("text") or "", max_depth=self.settings.stream_max_json_depth)
            if doc is not None and doc.get("type") == "end":
                self.ended_at = time.monotonic()
                await self.transport.push(self.sid, control={"type": "end"})
                continue
            await self.send(
                {
                    "type": "error",
                    "fatal": False,
                    "frame": None,
                    "problem": problem_document(
                        "invalid-message",
                        'text messages must be {"type": "end"}; frames are binary messages (see the AsyncAPI '
                        "document)",
                    ),
                }
            )

    async def _frame(self, data: bytes, max_bytes: int) -> None:
        frame, kind = frame_index(data, max_depth=self.settings.stream_max_json_depth)
        self.received += 1
        self.ctx.metrics.stream_frames.inc()
        if len(data) > max_bytes:
            await self._refuse("too_large")
            await self.send(
                {
                    "type": "error",
                    "fatal": False,
                    "frame": frame,
                    **self._flow(),
                    "problem": problem_document(
                        "frame-too-large",
                        f"frame {frame}: a frame message of {len(data)} bytes exceeds "
                        f"{max_bytes // (1024 * 1024)} MiB (EIGENSCOPE_STREAM_MAX_FRAME_MB)",
                        frame=frame,
                    ),
                }
            )
            return
        in_flight = self.in_flight - 1  # those before this one: the count it arrived to
        # The depth of a frame whose colour was refused goes the same way (it would have no colour); the
        # depth of one whose colour went on follows it whatever the window (the worker holds that colour
        # until its depth comes: dropping the depth would leave the frame, and the client waiting for its
        # acknowledgement, hanging).
        completes = kind == "depth" and frame is not None and frame == self.colour_sent
        if (in_flight >= self.window and not completes) or (kind == "depth" and frame in self.dropped):
            if frame is not None:
                self.dropped.add(frame)
            await self._refuse("window")
            await self.send(
                {
                    "type": "backpressure",
                    "action": "dropped",
                    "frame": frame,
                    "kind": kind,
                    **self._flow(),
                }
            )
            return
        if not self.slowed and in_flight >= (3 * self.window) // 4:
            self.slowed = True
            await self.send(
                {
                    "type": "backpressure",
                    "action": "slow_down",
                    "frame": frame,
                    "kind": kind,
                    **self._flow(),
                }
            )
        if kind == "color":
            self.colour_sent = frame
        await self.transport.push(self.sid, frame=data)

    async def _refuse(self, reason: str) -> None:
        """Count a frame message refused here: it is acknowledged at once (it is no longer in flight)."""
        self.refused += 1
        self.ctx.metrics.stream_dropped.labels(reason).inc()


async def serve_websocket(ctx: ServiceContext, ws: WebSocket, stream_id: str) -> None:
    """Authenticate, find the stream (tenant-scoped), check the resume token and relay."""
    await ws.accept()
    try:
        tenant = authenticate(ctx.keys, ctx.auth_limiter, client_address(ws), ws.headers.get("authorization"))
        stream = await run_in_threadpool(ctx.store.get_stream, stream_id, tenant)
    except ServiceError as exc:
        await ws.send_text(
            json.dumps(
                {
                    "type": "error",
                    "fatal": True,
                    "frame": None,
                    "problem": exc.problem(f"/v1/streams/{stream_id}"),
                }
            )
        )
        await ws.close(code=4000 + exc.status)
        return
    token = ws.query_params.get("resume_token")
    resumed = False
    problem: dict[str, Any] | None = None
    if stream.status not in ("waiting", "streaming"):
        problem = problem_document(
            "stream-ended",
            f"stream {stream_id} is {stream.status}; see its job {stream.job_id}",
        )
    elif token is not None:
        if not hmac.compare_digest(token_digest(token), stream.token_digest):
            problem = problem_document(
                "invalid-resume-token",
                "the resume_token does not belong to this stream",
            )
        resumed = True
    elif not await run_in_threadpool(_first_connection, ctx, stream_id):
        problem = problem_document(
            "stream-connected",
            f"stream {stream_id} already had a connection; reconnect with ?resume_token=",
        )
    if problem is not None:
        await ws.send_text(json.dumps({"type": "error", "fatal": True, "frame": None, "problem": problem}))
        await ws.close(code=4000 + int(problem["status"]))
        return
    relay = Relay(ctx, ws, stream, resumed=resumed)
    try:
        await relay.run()
    except Exception:
        log.exception("stream %s: relay failed", stream_id)
    with contextlib.suppress(Exception):
        await ws.close(code=1000)


def _first_connection(ctx: ServiceContext, stream_id: str) -> bool:
    return ctx.store.update_stream(stream_id, only_active=False, status="streaming", expect_status="waiting")
