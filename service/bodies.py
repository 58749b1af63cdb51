"""Request bodies: bounded, finite and never held open without progress (an ASGI middleware).

Every route but the streamed clip upload gets its body read here first, under three rules:

- a cap (``EIGENSCOPE_MAX_JSON_BODY_KB``; a route may have its own: ``POST /v1/jobs``, whose request may
  carry a force log, has ``EIGENSCOPE_MAX_JOB_BODY_KB``): a body declared or found larger is answered 413
  before it is parsed, and never held in memory beyond the cap;
- a bound on large bodies read at once (``EIGENSCOPE_MAX_LARGE_BODIES_IN_FLIGHT``): a body over the
  general cap that a route's own cap allows (a job request with a force log, up to about 20 MiB, which
  takes several times that while it is parsed and checked) holds one of a few slots from its first byte
  over the general cap until its route has answered; with none free it is answered 503 with
  ``Retry-After``, so that a burst of them cannot run the API out of memory;
- an idle timeout (``EIGENSCOPE_BODY_IDLE_TIMEOUT_S``): a body that sends nothing for that long is
  answered 408 and its connection closed;
- finite numbers: a JSON body holding ``NaN``, ``Infinity`` or a number that overflows (``1e309``, an
  integer beyond 64 bits) is answered 422, whatever field holds it, before any model sees it; the error
  names the field (``["body", "force_log", "fx", 12]``).

The upload route streams its body itself (:mod:`service.multipart`); it gets the idle timeout only, as a
:class:`~backend.errors.RequestTimeoutError` raised from ``receive`` that the upload turns into a 408 after
removing its temporary file.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable, Mapping, MutableMapping
from dataclasses import dataclass
from typing import Any

from backend.errors import (
    InvalidInputError,
    PayloadTooLargeError,
    RequestTimeoutError,
    ServiceError,
    UnavailableError,
)
from backend.strict_json import NonFiniteNumberError, non_finite_path, strict_json_loads

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

#: Routes whose bodies their handler streams itself (method, path).
STREAMED_BODIES = frozenset({("POST", "/v1/clips")})
#: After a body over the cap, read (and drop) at most this much more, so the client gets to read the 413.
_DRAIN_BYTES = 128 * 1024 * 1024


@dataclass(frozen=True, slots=True)
class BodyCap:
    """A limit of request bodies, bytes, and the setting that sets it (named in the 413)."""

    max_bytes: int
    setting: str = "EIGENSCOPE_MAX_JSON_BODY_KB"


def _is_json(scope: Scope) -> bool:
    for name, value in scope.get("headers", ()):
        if name == b"content-type":
            media = bytes(value).split(b";", 1)[0].strip().lower()
            return media == b"application/json" or (
                media.startswith(b"application/") and media.endswith(b"+json")
            )
    return True  # FastAPI parses a body without a content type as JSON


def _has_body(scope: Scope) -> bool:
    return any(name in (b"content-length", b"transfer-encoding") for name, _ in scope.get("headers", ()))


def _declared_length(scope: Scope) -> int | None:
    for name, value in scope.get("headers", ()):
        if name == b"content-length":
            return int(value) if value.isdigit() else None
    return None


class BodyLimits:
    """The ASGI middleware (see the module docstring)."""

    def __init__(
        self,
        app: ASGIApp,
        *,
        max_body_bytes: int,
        idle_timeout_s: float,
        streamed: frozenset[tuple[str, str]] = STREAMED_BODIES,
        route_caps: Mapping[tuple[str, str], BodyCap] | None = None,
        max_large_bodies: int | None = None,
    ) -> None:
        self.app = app
        self.max_body_bytes = max_body_bytes
        self.idle_timeout_s = idle_timeout_s
        self.streamed = streamed
        #: Routes (method, path) with caps of their own; every other route has ``max_body_bytes``.
        self.route_caps = dict(route_caps or {})
        self._default_cap = BodyCap(max_body_bytes)
        #: Bodies over ``max_body_bytes`` being read or handled at once, and how many may be (None: any).
        self.max_large_bodies = max_large_bodies
        self.large_in_flight = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        route = (scope["method"], scope["path"])
        if route in self.streamed:
            await self.app(scope, self._idle_timed(receive), send)
            return
        if not _has_body(scope):  # no Content-Length, no Transfer-Encoding: HTTP/1.1 sends no body
            await self.app(scope, receive, send)
            return
        slot = _Slot(self)
        try:
            await self._handle(scope, receive, send, slot)
        finally:
            slot.release()

    async def _handle(self, scope: Scope, receive: Receive, send: Send, slot: _Slot) -> None:
        """Read the body (holding ``slot`` once it passes the general cap), check it, run the route."""
        route = (scope["method"], scope["path"])
        try:
            body = await self._read(scope, receive, self.route_caps.get(route, self._default_cap), slot)
        except ServiceError as exc:
            await _problem(scope, receive, send, exc.problem(instance=scope["path"]), exc.headers())
            return
        if body is None:  # the client went away
            return
        if body and _is_json(scope):
            try:
                strict_json_loads(body)
            except NonFiniteNumberError as exc:
                await _problem(scope, receive, send, _non_finite(scope, body, str(exc)), {})
                return
            except (ValueError, RecursionError):
                pass  # malformed JSON: the route answers it as it always does (422)
        await self.app(scope, _replay(body, receive), send)

    def _idle_timed(self, receive: Receive) -> Receive:
        """``receive`` that raises :class:`RequestTimeoutError` when the body stalls."""
        done = False

        async def timed() -> Message:
            nonlocal done
            if done:
                return await receive()
            message = await self._next(receive)
            if message["type"] != "http.request" or not message.get("more_body", False):
                done = True
            return message

        return timed

    async def _next(self, receive: Receive) -> Message:
        try:
            return await asyncio.wait_for(receive(), self.idle_timeout_s)
        except TimeoutError:
            raise RequestTimeoutError(
                f"the request body sent nothing for {self.idle_timeout_s:g} s "
                "(EIGENSCOPE_BODY_IDLE_TIMEOUT_S); the connection is closed -- send the body without pauses"
            ) from None

    async def _read(self, scope: Scope, receive: Receive, cap: BodyCap, slot: _Slot) -> bytes | None:
        """The whole body (None if the client disconnected); 413 over the cap, 408 when it stalls, 503 when
        it passes the general cap with every large body's slot taken."""
        declared = _declared_length(scope)
        if declared is not None and declared > cap.max_bytes:
            await self._drain(receive, declared)
            raise self._too_large(declared, cap)
        if declared is not None and declared > self.max_body_bytes and not slot.take():
            await self._drain(receive, declared)
            raise self._busy()
        chunks: list[bytes] = []
        size = 0
        more = True
        while more:
            message = await self._next(receive)
            if message["type"] == "http.disconnect":
                return None
            chunk = message.get("body", b"")
            size += len(chunk)
            more = bool(message.get("more_body", False))
            if size > cap.max_bytes:
                if more:
                    await self._drain(receive, _DRAIN_BYTES)
                raise self._too_large(None, cap)
            if size > self.max_body_bytes and not slot.take():
                if more:
                    await self._drain(receive, _DRAIN_BYTES)
                raise self._busy()
            chunks.append(chunk)
        return b"".join(chunks)

    async def _drain(self, receive: Receive, declared: int) -> None:
        """Read and drop the rest of a refused body, up to a bound, so the client can read the answer."""
        if declared > _DRAIN_BYTES:
            return
        budget = _DRAIN_BYTES
        while budget > 0:
            try:
                message = await asyncio.wait_for(receive(), self.idle_timeout_s)
            except TimeoutError:
                return
            if message["type"] != "http.request":
                return
            budget -= len(message.get("body", b""))
            if not message.get("more_body", False):
                return

    def _busy(self) -> UnavailableError:
        return UnavailableError(
            f"{self.large_in_flight} requests over {self.max_body_bytes} bytes (job requests carrying a "
            "force log) are being read at once, the most this server takes together "
            "(EIGENSCOPE_MAX_LARGE_BODIES_IN_FLIGHT); try again shortly",
            code="too-many-large-requests",
            retry_after_s=1,
        )

    @staticmethod
    def _too_large(declared: int | None, cap: BodyCap) -> PayloadTooLargeError:
        size = f"of {declared} bytes " if declared is not None else ""
        return PayloadTooLargeError(
            f"the request body {size}exceeds the limit of {cap.max_bytes} bytes ({cap.setting}); clips go "
            "to POST /v1/clips as multipart/form-data",
            code="body-too-large",
            max_bytes=cap.max_bytes,
        )


class _Slot:
    """One request's hold on a large body's place in :class:`BodyLimits` (one event loop: no other request
    runs between a check and its count)."""

    def __init__(self, limits: BodyLimits) -> None:
        self.limits = limits
        self.held = False

    def take(self) -> bool:
        """Hold a place (True), or say there is none free (False); True when held already."""
        limits = self.limits
        if self.held:
            return True
        if limits.max_large_bodies is not None and limits.large_in_flight >= limits.max_large_bodies:
            return False
        limits.large_in_flight += 1
        self.held = True
        return True

    def release(self) -> None:
        if self.held:
            self.limits.large_in_flight -= 1
            self.held = False


def _replay(body: bytes, receive: Receive) -> Receive:
    """``receive`` that hands the app the body read already, then passes on (disconnects)."""
    sent = False

    async def replay() -> Message:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay


def _non_finite(scope: Scope, body: bytes, message: str) -> dict[str, Any]:
    """The 422 of a body holding a number that is not finite, naming the field that holds it."""
    try:  # parsed again, accepting what was refused, to find where it is
        path = non_finite_path(json.loads(body))
    except (ValueError, RecursionError):
        path = None
    loc: list[str | int] = ["body", *(path or [])]
    where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc[1:]).lstrip(".") or "body"
    error = InvalidInputError(
        f"{where}: {message}", errors=[{"loc": loc, "msg": message, "type": "finite_number"}]
    )
    return error.problem(instance=scope["path"])


async def _problem(
    scope: Scope, receive: Receive, send: Send, doc: dict[str, Any], headers: dict[str, str]
) -> None:
    from service.problems import problem_response

    response = problem_response(doc, headers or None)
    await response(scope, receive, send)
