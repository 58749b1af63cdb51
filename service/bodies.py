"""Request bodies: bounded, finite and never held open without progress (an ASGI middleware).

Every route but the streamed clip upload gets its body read here first, under three rules:

- a cap (``EIGENSCOPE_MAX_JSON_BODY_KB``): a body declared or found larger is answered 413 before it is
  parsed, and never held in memory beyond the cap;
- an idle timeout (``EIGENSCOPE_BODY_IDLE_TIMEOUT_S``): a body that sends nothing for that long is
  answered 408 and its connection closed;
- finite numbers: a JSON body holding ``NaN``, ``Infinity`` or a number that overflows (``1e309``, an
  integer beyond 64 bits) is answered 422, whatever field holds it, before any model sees it.

The upload route streams its body itself (:mod:`service.multipart`); it gets the idle timeout only, as a
:class:`~service.errors.RequestTimeoutError` raised from ``receive`` that the upload turns into a 408 after
removing its temporary file.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from service.errors import InvalidInputError, PayloadTooLargeError, RequestTimeoutError, ServiceError

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

#: Routes whose bodies their handler streams itself (method, path).
STREAMED_BODIES = frozenset({("POST", "/v1/clips")})
#: After a body over the cap, read (and drop) at most this much more, so the client gets to read the 413.
_DRAIN_BYTES = 128 * 1024 * 1024
_INT64 = 2**63


class NonFiniteNumberError(ValueError):
    """A JSON number that is not a finite float or a 64-bit integer."""


def _constant(name: str) -> Any:
    raise NonFiniteNumberError(f"{name} is not a number JSON can carry; send finite numbers")


def _float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise NonFiniteNumberError(f"{text} overflows a 64-bit float; send finite numbers")
    return value


def _int(text: str) -> int:
    value = int(text)
    if not -_INT64 <= value < _INT64:
        raise NonFiniteNumberError(f"{text[:40]} overflows a 64-bit integer")
    return value


def strict_json_loads(body: bytes | str) -> Any:
    """``json.loads`` that refuses ``NaN``, ``Infinity``, overflowing floats and integers beyond 64 bits.

    Raises
    ------
    NonFiniteNumberError
        For such a number (other malformed JSON raises what ``json.loads`` raises).
    """
    return json.loads(body, parse_constant=_constant, parse_float=_float, parse_int=_int)


def json_depth_error(text: str, max_depth: int) -> str | None:
    """Why ``text`` must not be parsed: nested deeper than ``max_depth`` arrays and objects (a parser
    would recurse that deep); None when it may be. Brackets inside strings do not count."""
    depth = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            if depth > max_depth:
                return f"JSON nested more than {max_depth} levels deep"
        elif char in "]}":
            depth -= 1
    return None


def loads_shallow(data: bytes | str, *, max_depth: int) -> Any:
    """``json.loads`` of a message that must be shallow: ``ValueError`` (never ``RecursionError``) for one
    nested deeper than ``max_depth``, or otherwise malformed."""
    text = data.decode("utf-8") if isinstance(data, bytes) else data  # UnicodeDecodeError is a ValueError
    why = json_depth_error(text, max_depth)
    if why is not None:
        raise ValueError(why)
    try:
        return json.loads(text)
    except RecursionError:  # pragma: no cover - the depth was checked
        raise ValueError("JSON nested too deep") from None


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
    ) -> None:
        self.app = app
        self.max_body_bytes = max_body_bytes
        self.idle_timeout_s = idle_timeout_s
        self.streamed = streamed

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if (scope["method"], scope["path"]) in self.streamed:
            await self.app(scope, self._idle_timed(receive), send)
            return
        if not _has_body(scope):  # no Content-Length, no Transfer-Encoding: HTTP/1.1 sends no body
            await self.app(scope, receive, send)
            return
        try:
            body = await self._read(scope, receive)
        except ServiceError as exc:
            await _problem(scope, receive, send, exc.problem(instance=scope["path"]), exc.headers())
            return
        if body is None:  # the client went away
            return
        if body and _is_json(scope):
            try:
                strict_json_loads(body)
            except NonFiniteNumberError as exc:
                await _problem(scope, receive, send, _non_finite(scope, str(exc)), {})
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

    async def _read(self, scope: Scope, receive: Receive) -> bytes | None:
        """The whole body (None if the client disconnected); 413 over the cap, 408 when it stalls."""
        declared = _declared_length(scope)
        if declared is not None and declared > self.max_body_bytes:
            await self._drain(receive, declared)
            raise self._too_large(declared)
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
            if size > self.max_body_bytes:
                if more:
                    await self._drain(receive, _DRAIN_BYTES)
                raise self._too_large(None)
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

    def _too_large(self, declared: int | None) -> PayloadTooLargeError:
        size = f"of {declared} bytes " if declared is not None else ""
        return PayloadTooLargeError(
            f"the request body {size}exceeds the limit of {self.max_body_bytes} bytes "
            "(EIGENSCOPE_MAX_JSON_BODY_KB); clips go to POST /v1/clips as multipart/form-data",
            code="body-too-large",
            max_bytes=self.max_body_bytes,
        )


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


def _non_finite(scope: Scope, message: str) -> dict[str, Any]:
    error = InvalidInputError(
        f"body: {message}", errors=[{"loc": ["body"], "msg": message, "type": "finite_number"}]
    )
    return error.problem(instance=scope["path"])


async def _problem(
    scope: Scope, receive: Receive, send: Send, doc: dict[str, Any], headers: dict[str, str]
) -> None:
    from service.problems import problem_response

    response = problem_response(doc, headers or None)
    await response(scope, receive, send)
