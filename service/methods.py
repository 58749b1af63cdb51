"""HTTP method semantics the routes do not give by themselves (RFC 9110, section 9).

- **HEAD wherever GET.** A ``HEAD`` request is routed as the ``GET`` of its path and answered with that
  response's status and headers (``Content-Length``, ``ETag``, ``Retry-After`` ...) and no body.
- **``Allow`` names every method of the path.** Starlette's 405 lists the methods of the first route that
  matches the path, and each method of ``/v1/jobs`` is a route of its own: a 405 names all the methods the
  OpenAPI document gives the path (with ``HEAD`` where there is ``GET``).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from typing import Any

from starlette.routing import BaseRoute, Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: The request's method as the client sent it (``scope["method"]`` is ``GET`` for a ``HEAD``).
ORIGINAL_METHOD = "eigenscope.method"
_METHODS = ("get", "put", "post", "delete", "patch", "options", "trace")


def route_of(routes: Iterable[BaseRoute], scope: Scope) -> BaseRoute | None:
    """The route that answers ``scope``'s path (whatever its method), or None."""
    partial = None
    for route in routes:
        match, _child = route.matches(scope)
        if match is Match.FULL:
            return route
        if match is Match.PARTIAL and partial is None:
            partial = route
    return partial


class PathMethods:
    """The methods of each path of an OpenAPI document (``spec()`` is called once, when first needed)."""

    def __init__(self, spec: Callable[[], dict[str, Any]]) -> None:
        self._spec = spec
        self._table: list[tuple[re.Pattern[str], list[str]]] | None = None

    def __call__(self, path: str) -> list[str] | None:
        if self._table is None:
            self._table = []
            for template, item in self._spec().get("paths", {}).items():
                regex = re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(template))
                self._table.append((re.compile(f"^{regex}$"), [m.upper() for m in item if m in _METHODS]))
        for compiled, methods in self._table:
            if compiled.match(path):
                return methods
        return None


def with_head(methods: Iterable[str]) -> list[str]:
    found = {m.strip().upper() for m in methods if m.strip()}
    if "GET" in found:
        found.add("HEAD")
    return sorted(found)


class MethodSemantics:
    """``HEAD`` as ``GET`` without a body, and a 405's ``Allow`` with all of the path's methods."""

    def __init__(self, app: ASGIApp, methods_of: Callable[[str], list[str] | None]) -> None:
        self.app = app
        self.methods_of = methods_of

    def _allow(self, scope: Scope, headers: list[tuple[bytes, bytes]]) -> list[tuple[bytes, bytes]]:
        given = [v.decode("latin-1") for k, v in headers if k.lower() == b"allow"]
        methods = self.methods_of(scope.get("path", "")) or ",".join(given).split(",")
        kept = [(k, v) for k, v in headers if k.lower() != b"allow"]
        return [*kept, (b"allow", ", ".join(with_head(methods)).encode())]

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        head = scope["method"] == "HEAD"
        if head:  # in place: the middleware outside reads the route the router records in the scope
            scope["method"], scope[ORIGINAL_METHOD] = "GET", "HEAD"

        async def send_fixed(message: Message) -> None:
            if message["type"] == "http.response.start" and message["status"] == 405:
                message = {**message, "headers": self._allow(scope, list(message.get("headers", [])))}
            elif head and message["type"] == "http.response.body":
                if message.get("more_body", False):
                    return  # the GET's body is not sent; its last (empty) part ends the response
                message = {**message, "body": b""}
            await send(message)

        await self.app(scope, receive, send_fixed)
