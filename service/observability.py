"""The ASGI middleware around every request: its id, its trace, its metrics and its access-log line.

The request id is the incoming ``X-Request-ID`` when it is a sane token (letters, digits and ``._:-``, at
most 128 characters), else a new one; it is returned in ``X-Request-ID``, set in
:data:`backend.logs.request_id_var` for every log record of the request, and logged with the method,
route, status and duration at INFO (logger ``service.access``; in JSON logs as fields of their own). The
W3C ``traceparent`` of the request (or a new trace) is the request's span (:data:`backend.logs.trace_var`):
every record of the request names it, and a job the request creates carries it to its worker.
"""

from __future__ import annotations

import logging
import re
import time
import uuid
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from backend.logs import continue_trace, request_id_var, trace_var
from service.methods import ORIGINAL_METHOD, route_of
from service.metrics import Metrics

access_log = logging.getLogger("service.access")

_REQUEST_ID = re.compile(r"^[A-Za-z0-9._:-]{1,128}$")


def _header(headers: list[tuple[bytes, bytes]], name: bytes) -> str | None:
    for key, value in headers:
        if key == name:
            return value.decode("latin-1")
    return None


def request_id_of(headers: list[tuple[bytes, bytes]]) -> str:
    """The request's own id, if it sent a usable one, else a new one."""
    for name, value in headers:
        if name == b"x-request-id":
            text = value.decode("latin-1").strip()
            if _REQUEST_ID.match(text):
                return text
            break
    return uuid.uuid4().hex


def route_template(scope: Scope, request: Scope) -> str:
    """The path template of the route that answered (``/v1/jobs/{job_id}``), ``unmatched`` when none did.

    FastAPI's own routes record themselves in the scope; Starlette routes and mounts (``/openapi.json``,
    ``/static``) are looked up among the app's routes with the request as it came (``request``: a mount
    changes the scope's ``root_path``)."""
    route: Any = scope.get("route")
    if route is None:
        router = getattr(scope.get("app"), "router", None)
        if router is not None:
            route = route_of(router.routes, request)
    return getattr(route, "path", None) or "unmatched"


class RequestMiddleware:
    """Request id, metrics and access log of each HTTP request (see the module docstring)."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = scope.get("headers", [])
        request_id = request_id_of(headers)
        arrived = {k: scope.get(k) for k in ("type", "path", "root_path", "method")}
        token = request_id_var.set(request_id)
        trace = trace_var.set(continue_trace(_header(headers, b"traceparent")))
        start = time.perf_counter()
        status = 500
        header = (b"x-request-id", request_id.encode())

        async def send_with_id(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
                message = {**message, "headers": [*message.get("headers", []), header]}
            await send(message)

        try:
            await self.app(scope, receive, send_with_id)
        finally:
            elapsed = time.perf_counter() - start
            template = route_template(scope, arrived)
            method = scope.get(ORIGINAL_METHOD) or scope.get("method", "")
            self.metrics.requests.labels(method, template, str(status)).inc()
            self.metrics.latency.labels(method, template).observe(elapsed)
            path = scope.get("path", "")
            fields = {
                "method": method,
                "path": path,
                "route": template,
                "status": status,
                "duration_ms": round(elapsed * 1000, 1),
                "client": (scope.get("client") or ("",))[0],
            }
            access_log.info(
                "%s %s %d %.1f ms", method, path, status, elapsed * 1000, extra={"fields": fields}
            )
            trace_var.reset(trace)
            request_id_var.reset(token)
