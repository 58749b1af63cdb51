"""Live streams for robot code: send frames while recording, get estimates and the result at once.

Example::

    from eigenscope_client import StreamSession

    with StreamSession("http://eigenscope:8000", api_key=KEY, fps=30, fx=615, fy=615,
                       excitation={"type": "step_release", "force_n": 5.0}) as s:
        for color_jpeg, depth_u16, t in camera:          # encoded colour, raw uint16 depth, seconds
            s.send_frame(color_jpeg, timestamp_s=t, depth=depth_u16, width=640, height=480)
            if s.converged:                              # the estimate is good enough: stop recording
                break
        result = s.finish()                              # the AnalysisResult, a fraction of a second later
    print(result["eigenfrequency_hz"], s.estimate)

Only ``httpx`` and ``websockets`` are needed. Frames go as binary messages (a 4-byte big-endian header
length, a JSON header, the image bytes); the server's JSON messages are ``ready``, ``accepted``,
``backpressure``, ``estimate``, ``converged``, ``result`` and ``error`` (see the server's AsyncAPI
document). Flow control, the protocol's one rule: a frame message is in flight from when it is sent until
the server acknowledges it (``acked`` in ``accepted``, ``backpressure`` and ``error`` counts the
connection's acknowledged frame messages); :meth:`StreamSession.send_frame` keeps fewer than the server's
``window`` in flight. By default it waits for room; with ``realtime=True`` it never waits (a camera cannot)
and the server tells which frames it had to drop. :attr:`StreamSession.stalls` counts the waits.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import struct
import time
from collections.abc import Callable
from typing import Any

from eigenscope_client._errors import StreamError, TransportError, error_for

Message = dict[str, Any]


def frame_message(
    data: bytes | bytearray | memoryview,
    *,
    frame: int,
    kind: str,
    timestamp_s: float,
    encoding: str,
    width: int | None = None,
    height: int | None = None,
) -> bytes:
    """One binary frame message: header length, JSON header, image bytes.

    ``kind`` is ``color`` (``jpeg`` or ``png`` encoding) or ``depth`` (16-bit ``png``, or ``raw``
    little-endian uint16 with ``width`` and ``height``).
    """
    header: dict[str, Any] = {"frame": frame, "kind": kind, "timestamp_s": timestamp_s, "encoding": encoding}
    if width is not None:
        header["width"] = width
    if height is not None:
        header["height"] = height
    head = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack(">I", len(head)) + head + bytes(data)


def _frame_messages(
    index: int,
    timestamp_s: float,
    color: bytes | bytearray | memoryview,
    depth: bytes | bytearray | memoryview | None,
    color_encoding: str,
    depth_encoding: str,
    width: int | None,
    height: int | None,
) -> list[bytes]:
    """The colour message of a frame and, with depth, its depth message."""
    messages = [
        frame_message(color, frame=index, kind="color", timestamp_s=timestamp_s, encoding=color_encoding)
    ]
    if depth is not None:
        messages.append(
            frame_message(
                depth,
                frame=index,
                kind="depth",
                timestamp_s=timestamp_s,
                encoding=depth_encoding,
                width=width,
                height=height,
            )
        )
    return messages


def connect_websocket(url: str, **options: Any) -> Any:
    """A blocking WebSocket connection (``websockets.sync``) across the library's versions."""
    import inspect

    try:
        from websockets.sync.client import connect
    except ImportError as exc:  # the client's optional extra
        raise TransportError(
            "live streams need the websockets package: pip install 'eigenscope-client[streams]'"
        ) from exc

    if "legacy" in inspect.signature(connect).parameters:
        options["legacy"] = True  # a connection object, not a context manager to enter
    return connect(url, **options)


def _problem_text(problem: dict[str, Any]) -> str:
    return f"{problem.get('title', 'error')}: {problem.get('detail', '')}".strip()


def _create_body(
    excitation: dict[str, Any] | list[dict[str, Any]] | None,
    parameters: dict[str, Any],
    target_relative_uncertainty: float,
    max_duration_s: float,
    width: int | None,
    height: int | None,
) -> dict[str, Any]:
    body: dict[str, Any] = {
        "parameters": {k: v for k, v in parameters.items() if v is not None},
        "target_relative_uncertainty": target_relative_uncertainty,
        "max_duration_s": max_duration_s,
    }
    if excitation is not None:
        body["excitation"] = excitation
    if width is not None:
        body["width"] = width
    if height is not None:
        body["height"] = height
    return body


class _State:
    """What the server has said so far (shared by the sync and async sessions)."""

    def __init__(self, on_message: Callable[[Message], None] | None) -> None:
        self.on_message = on_message
        self.window = 1
        self.sent = 0  # frame messages sent on this connection
        self.acked = 0  # ... of which the server is done with (the latest `acked`)
        self.legacy = False  # a server older than `acked`: count by `messages` and drops instead
        self.base = 0
        self.consumed = 0
        self.stalls = 0
        self.next_frame = 0
        self.estimate: Message | None = None
        self.converged: Message | None = None
        self.result: Message | None = None
        self.errors: list[Message] = []
        self.dropped: list[Message] = []
        self.fatal: Message | None = None
        self.job_id: str | None = None

    @property
    def in_flight(self) -> int:
        """Frame messages sent on this connection that the server has not acknowledged yet."""
        if self.legacy:
            return self.sent - (self.consumed - self.base) - self.acked
        return self.sent - self.acked

    @property
    def has_room(self) -> bool:
        """Whether one more frame message may be sent (the flow-control rule)."""
        return self.in_flight < self.window

    def _count(self, message: Message) -> None:
        """Take the flow-control members of a message (see the module docstring)."""
        if "acked" in message and message["acked"] is not None:
            self.acked = max(self.acked, int(message["acked"]))
        elif message.get("type") in ("accepted", "backpressure"):
            self.legacy = True
        if "messages" in message and message["messages"] is not None:
            self.consumed = max(self.consumed, int(message["messages"]))
        if self.legacy and message.get("type") == "backpressure" and message.get("action") == "dropped":
            self.acked += 1  # an older server's drop, acknowledged by its arrival

    def take(self, text: str | bytes) -> Message:
        message: Message = json.loads(text)
        kind = message.get("type")
        if kind != "ready":
            self._count(message)
        if kind == "ready":
            self.window = int(message["window"])
            self.base = self.consumed = int(message.get("messages", 0))
            self.sent = self.acked = 0
            self.next_frame = int(message.get("next_frame", 0))
            self.job_id = message.get("job_id")
        elif kind == "estimate":
            self.estimate = message["estimate"]
        elif kind == "converged":
            self.converged = message
            self.estimate = message["estimate"]
        elif kind == "result":
            self.result = message
        elif kind == "backpressure" and message.get("action") == "dropped":
            self.dropped.append(message)
        elif kind == "error":
            self.errors.append(message)
            if message.get("fatal"):
                self.fatal = message
        if self.on_message is not None:
            self.on_message(message)
        return message

    def raise_if_fatal(self) -> None:
        if self.fatal is not None:
            problem = self.fatal.get("problem") or {}
            raise StreamError(_problem_text(problem), problem=problem)


class StreamSession:
    """A live stream: opens the session, sends frames with flow control, follows the estimates.

    Parameters
    ----------
    server : str
        Base URL of the API, e.g. ``http://127.0.0.1:8000``.
    api_key : str, optional
        Sent as ``Authorization: Bearer``.
    excitation : dict or list of dict, optional
        As for a job: ``{"type": "step_release", "force_n": F}`` or ``{"type": "impulse", "impulse_ns": J}``.
    fps, fx, fy, cx, cy, depth_scale : float, optional
        What is known about the camera (``depth_scale``: metres per depth unit, default 0.001).
    parameters : dict, optional
        Other analysis parameters (``frames``, ``min_frequency_hz``, ...).
    target_relative_uncertainty : float
        ``converged`` arrives when the frequency's relative standard uncertainty is at most this.
    realtime : bool
        Never wait for room in the window (a live camera); the server drops what does not fit and says so.
    on_message : callable, optional
        Called with every message the server sends.
    """

    def __init__(
        self,
        server: str,
        *,
        api_key: str | None = None,
        excitation: dict[str, Any] | list[dict[str, Any]] | None = None,
        fps: float | None = None,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        depth_scale: float | None = None,
        parameters: dict[str, Any] | None = None,
        target_relative_uncertainty: float = 0.01,
        max_duration_s: float = 60.0,
        width: int | None = None,
        height: int | None = None,
        realtime: bool = False,
        timeout_s: float = 60.0,
        on_message: Callable[[Message], None] | None = None,
    ) -> None:
        import httpx

        self.server = server.rstrip("/")
        self.realtime = realtime
        self.timeout_s = timeout_s
        self._headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self._state = _State(on_message)
        params = {"fps": fps, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "depth_scale": depth_scale}
        body = _create_body(
            excitation,
            {**params, **(parameters or {})},
            target_relative_uncertainty,
            max_duration_s,
            width,
            height,
        )
        try:
            response = httpx.post(
                f"{self.server}/v1/streams", json=body, headers=self._headers, timeout=timeout_s
            )
        except httpx.HTTPError as exc:
            raise TransportError(f"cannot reach {self.server}: {exc}") from exc
        if response.status_code != 201:
            try:
                problem = response.json()
            except ValueError:
                problem = {"title": response.reason_phrase, "detail": response.text[:200]}
            raise error_for(
                response.status_code,
                problem,
                request_id=response.headers.get("x-request-id"),
                retry_after=None,
            )
        self.info: dict[str, Any] = response.json()
        self.stream_id: str = self.info["id"]
        self.job_id: str = self.info["job_id"]
        self.resume_token: str = self.info["resume_token"]
        self._frame = 0
        self._ws: Any = None
        self._connect(resume=False)

    # Connection ------------------------------------------------------------------------------------

    def _connect(self, *, resume: bool) -> None:
        url = self.info["websocket_url"] + (f"?resume_token={self.resume_token}" if resume else "")
        try:
            self._ws = connect_websocket(
                url,
                additional_headers=self._headers,
                open_timeout=self.timeout_s,
                max_size=None,
                compression=None,  # images: deflating them costs both ends more CPU than it saves
            )
        except Exception as exc:
            raise TransportError(f"cannot open the stream's WebSocket {url}: {exc}") from exc
        self._wait(lambda: self._state.job_id is not None, self.timeout_s, "the server's ready message")
        if resume:
            self._frame = max(self._frame, self._state.next_frame)

    def resume(self) -> None:
        """Reconnect after a dropped connection (with the resume token); go on from the server's frame."""
        if self._ws is not None:
            with contextlib.suppress(Exception):
                self._ws.close()
        self._state.job_id = None
        self._connect(resume=True)

    def _recv(self, timeout: float) -> Message | None:
        from websockets.exceptions import ConnectionClosed

        try:
            text = self._ws.recv(timeout=timeout)
        except TimeoutError:
            return None
        except ConnectionClosed as exc:
            self._state.raise_if_fatal()
            if self._state.result is not None:
                return None
            raise StreamError(f"the stream's connection closed ({exc})") from exc
        return self._state.take(text)

    def _wait(self, done: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            self._state.raise_if_fatal()
            left = deadline - time.monotonic()
            if left <= 0:
                raise StreamError(f"no {what} within {timeout_s:g} s")
            self._recv(min(left, 0.5))
        self._state.raise_if_fatal()

    def poll(self) -> list[Message]:
        """The messages that have arrived (without waiting); :class:`StreamError` on a fatal one."""
        messages = []
        while (m := self._recv(0)) is not None:
            messages.append(m)
        self._state.raise_if_fatal()
        return messages

    # Frames ----------------------------------------------------------------------------------------

    def send_frame(
        self,
        color: bytes | bytearray | memoryview,
        *,
        timestamp_s: float,
        depth: bytes | bytearray | memoryview | None = None,
        color_encoding: str = "jpeg",
        depth_encoding: str = "raw",
        width: int | None = None,
        height: int | None = None,
        frame: int | None = None,
    ) -> int:
        """Send one frame (colour, then its depth); returns its index.

        ``color``: JPEG or PNG bytes. ``depth``: raw little-endian uint16 bytes (any buffer, e.g. a numpy
        array; give ``width`` and ``height``) or 16-bit PNG bytes (``depth_encoding="png"``).
        """
        index = self._frame if frame is None else frame
        messages = _frame_messages(
            index, timestamp_s, color, depth, color_encoding, depth_encoding, width, height
        )
        for data in messages:
            if not self.realtime:
                self._wait_for_room()
            self._ws.send(data)
            self._state.sent += 1
        self._frame = index + 1
        self.poll()
        return index

    def _wait_for_room(self) -> None:
        """Wait until fewer than ``window`` frame messages are in flight (a stall, when it has to)."""
        self.poll()
        if not self._state.has_room:
            self._state.stalls += 1
            self._wait(lambda: self._state.has_room, self.timeout_s, "room in the window")

    def finish(self, timeout_s: float | None = None) -> dict[str, Any]:
        """Say the capture has ended and wait for the final result (the job's ``AnalysisResult``)."""
        self._ws.send(json.dumps({"type": "end"}))
        self._wait(lambda: self._state.result is not None, timeout_s or self.timeout_s, "result")
        assert self._state.result is not None
        result: dict[str, Any] = self._state.result["result"]
        return result

    def close(self) -> None:
        if self._ws is not None:
            with contextlib.suppress(Exception):
                self._ws.close()

    def __enter__(self) -> StreamSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # What the server said --------------------------------------------------------------------------

    @property
    def estimate(self) -> dict[str, Any] | None:
        """The latest estimate (``eigenfrequency_hz``, its uncertainty, damping, k, m, ...)."""
        return self._state.estimate

    @property
    def converged(self) -> bool:
        """Whether the server has said the estimate reached the target uncertainty."""
        return self._state.converged is not None

    @property
    def errors(self) -> list[Message]:
        """Every ``error`` message so far (non-fatal ones name a frame that was skipped)."""
        return list(self._state.errors)

    @property
    def dropped(self) -> list[Message]:
        """``backpressure`` messages of frames the server refused because its window was full."""
        return list(self._state.dropped)

    @property
    def in_flight(self) -> int:
        """Frame messages sent that the server has not acknowledged yet (the flow-control count)."""
        return self._state.in_flight

    @property
    def stalls(self) -> int:
        """How many times :meth:`send_frame` had to wait for room in the window."""
        return self._state.stalls


class AsyncStreamSession:
    """The asyncio twin of :class:`StreamSession`: ``session = await AsyncStreamSession.open(...)``,
    then ``await session.send_frame(...)`` and ``await session.finish()``."""

    def __init__(
        self, state: _State, ws: Any, info: dict[str, Any], realtime: bool, timeout_s: float
    ) -> None:
        self._state, self._ws, self.info = state, ws, info
        self.stream_id, self.job_id = info["id"], info["job_id"]
        self.realtime, self.timeout_s = realtime, timeout_s
        self._frame = 0

    @classmethod
    async def open(
        cls,
        server: str,
        *,
        api_key: str | None = None,
        excitation: dict[str, Any] | list[dict[str, Any]] | None = None,
        parameters: dict[str, Any] | None = None,
        target_relative_uncertainty: float = 0.01,
        max_duration_s: float = 60.0,
        realtime: bool = False,
        timeout_s: float = 60.0,
        on_message: Callable[[Message], None] | None = None,
    ) -> AsyncStreamSession:
        import httpx

        try:
            from websockets.asyncio.client import connect
        except ImportError as exc:  # the client's optional extra
            raise TransportError(
                "live streams need the websockets package: pip install 'eigenscope-client[streams]'"
            ) from exc

        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        body = _create_body(
            excitation, parameters or {}, target_relative_uncertainty, max_duration_s, None, None
        )
        async with httpx.AsyncClient(timeout=timeout_s) as http:
            response = await http.post(f"{server.rstrip('/')}/v1/streams", json=body, headers=headers)
        if response.status_code != 201:
            try:
                problem = response.json()
            except ValueError:
                problem = {"title": response.reason_phrase, "detail": response.text[:200]}
            raise error_for(
                response.status_code,
                problem,
                request_id=response.headers.get("x-request-id"),
                retry_after=None,
            )
        info = response.json()
        ws = await connect(info["websocket_url"], additional_headers=headers, max_size=None, compression=None)
        session = cls(_State(on_message), ws, info, realtime, timeout_s)
        await session._wait(lambda: session._state.job_id is not None, "the server's ready message")
        return session

    async def _wait(self, done: Callable[[], bool], what: str) -> None:
        deadline = time.monotonic() + self.timeout_s
        while not done():
            self._state.raise_if_fatal()
            left = deadline - time.monotonic()
            if left <= 0:
                raise StreamError(f"no {what} within {self.timeout_s:g} s")
            try:
                text = await asyncio.wait_for(self._ws.recv(), timeout=min(left, 0.5))
            except TimeoutError:
                continue
            except Exception as exc:
                self._state.raise_if_fatal()
                raise StreamError(f"the stream's connection closed ({exc})") from exc
            self._state.take(text)
        self._state.raise_if_fatal()

    async def send_frame(
        self,
        color: bytes | bytearray | memoryview,
        *,
        timestamp_s: float,
        depth: bytes | bytearray | memoryview | None = None,
        color_encoding: str = "jpeg",
        depth_encoding: str = "raw",
        width: int | None = None,
        height: int | None = None,
    ) -> int:
        """As :meth:`StreamSession.send_frame`."""
        index = self._frame
        parts = _frame_messages(
            index, timestamp_s, color, depth, color_encoding, depth_encoding, width, height
        )
        for data in parts:
            if not self.realtime and not self._state.has_room:
                self._state.stalls += 1
                await self._wait(lambda: self._state.has_room, "room in the window")
            await self._ws.send(data)
            self._state.sent += 1
        self._frame = index + 1
        return index

    async def finish(self) -> dict[str, Any]:
        await self._ws.send(json.dumps({"type": "end"}))
        await self._wait(lambda: self._state.result is not None, "result")
        assert self._state.result is not None
        result: dict[str, Any] = self._state.result["result"]
        return result

    async def close(self) -> None:
        await self._ws.close()

    @property
    def estimate(self) -> dict[str, Any] | None:
        return self._state.estimate

    @property
    def converged(self) -> bool:
        return self._state.converged is not None
