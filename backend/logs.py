"""Logging of the API and worker processes: one handler on stderr, text or JSON, with request and job ids.

- ``EIGENSCOPE_LOG_FORMAT=text`` (default): ``2026-01-02 10:11:12,345 INFO service.jobs: job 1f..: queued
  [request_id=ab12..]``; ``json``: one object a line with ``time``, ``level``, ``logger``, ``message`` and,
  when known, ``request_id``, ``job_id``, ``trace_id``, ``span_id``, ``exception`` and the record's own
  fields (the access log's ``method``, ``path``, ``route``, ``status``, ``duration_ms`` ...). Every line a
  process writes is one of these: the supervisor's and Celery's own messages (``console``) too.
- The request id (an incoming ``X-Request-ID``, or a new one), the W3C trace context (an incoming
  ``traceparent``, or a new trace; carried with a job to the worker that runs it) and the job id a worker
  runs are kept in context variables and added to every record logged meanwhile.
- Uvicorn's, Celery's and billiard's loggers go through the same handler (uvicorn's access log is replaced
  by the API's own, which carries the request id); Python warnings from libraries are not shown unless the
  level is DEBUG.
"""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, TextIO


@dataclass(frozen=True)
class TraceContext:
    """A W3C trace context: the trace, this process's span in it, and the trace flags."""

    trace_id: str
    span_id: str
    flags: str = "01"

    @property
    def traceparent(self) -> str:
        """The ``traceparent`` header naming this span as the parent of the next hop."""
        return f"00-{self.trace_id}-{self.span_id}-{self.flags}"


#: The request being served (API) and the job being run (worker), added to each log record.
request_id_var: ContextVar[str | None] = ContextVar("eigenscope_request_id", default=None)
job_id_var: ContextVar[str | None] = ContextVar("eigenscope_job_id", default=None)
trace_var: ContextVar[TraceContext | None] = ContextVar("eigenscope_trace", default=None)

_HANDLER_MARK = "_eigenscope_handler"
#: Loggers of the servers we run: their records go through our handler, not their own.
_SERVER_LOGGERS = ("uvicorn", "uvicorn.error", "celery", "kombu", "amqp")
#: billiard (Celery's pool) logs through a logger of its own that does not propagate.
_OWN_HANDLER_LOGGERS = ("multiprocessing",)
_TRACEPARENT = re.compile(r"^([0-9a-f]{2})-([0-9a-f]{32})-([0-9a-f]{16})-([0-9a-f]{2})(-.*)?$")


def parse_traceparent(value: str | None) -> tuple[str, str, str] | None:
    """``(trace_id, parent_id, flags)`` of a W3C ``traceparent`` header, or None when it is not one."""
    match = _TRACEPARENT.match((value or "").strip().lower())
    if match is None:
        return None
    version, trace_id, parent_id, flags, rest = match.groups()
    if version == "ff" or (version == "00" and rest) or set(trace_id) == {"0"} or set(parent_id) == {"0"}:
        return None
    return trace_id, parent_id, flags


def continue_trace(traceparent: str | None) -> TraceContext:
    """This process's span of the trace ``traceparent`` names (a new trace when it names none)."""
    parsed = parse_traceparent(traceparent)
    if parsed is None:
        return TraceContext(secrets.token_hex(16), secrets.token_hex(8))
    trace_id, _parent, flags = parsed
    return TraceContext(trace_id, secrets.token_hex(8), flags)


@contextmanager
def traced(traceparent: str | None) -> Iterator[TraceContext]:
    """Log (and pass on) everything inside as a span of ``traceparent``'s trace."""
    context = continue_trace(traceparent)
    token = trace_var.set(context)
    try:
        yield context
    finally:
        trace_var.reset(token)


def current_traceparent() -> str | None:
    """The ``traceparent`` to send with work handed on from here (a job to its worker), if any."""
    context = trace_var.get()
    return context.traceparent if context is not None else None


class ContextFilter(logging.Filter):
    """Adds ``request_id``, ``job_id``, ``trace_id`` and ``span_id`` (None when unknown) to every record."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not hasattr(record, "request_id"):
            record.request_id = request_id_var.get()
        if not hasattr(record, "job_id"):
            record.job_id = job_id_var.get()
        trace = trace_var.get()
        if not hasattr(record, "trace_id"):
            record.trace_id = trace.trace_id if trace is not None else None
        if not hasattr(record, "span_id"):
            record.span_id = trace.span_id if trace is not None else None
        return True


class TextFormatter(logging.Formatter):
    """One readable line; the ids in brackets at its end."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s: %(message)s")

    def format(self, record: logging.LogRecord) -> str:
        line = super().format(record)
        ids = [f"{key}={value}" for key in ("job_id", "request_id") if (value := getattr(record, key, None))]
        if not ids:
            return line
        first, newline, rest = line.partition("\n")
        return f"{first} [{' '.join(ids)}]{newline}{rest}"


class JsonFormatter(logging.Formatter):
    """One JSON object a line."""

    def format(self, record: logging.LogRecord) -> str:
        doc: dict[str, Any] = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        fields = getattr(record, "fields", None)
        if isinstance(fields, dict):
            doc.update({k: v for k, v in fields.items() if k not in doc})
        for key in ("request_id", "job_id", "trace_id", "span_id"):
            value = getattr(record, key, None)
            if value:
                doc[key] = value
        if record.exc_info:
            doc["exception"] = self.formatException(record.exc_info)
        return json.dumps(doc, ensure_ascii=False, default=str)


def make_handler(fmt: str, stream: TextIO | None = None) -> logging.Handler:
    handler = logging.StreamHandler(stream if stream is not None else sys.stderr)
    handler.setFormatter(JsonFormatter() if fmt == "json" else TextFormatter())
    handler.addFilter(ContextFilter())
    setattr(handler, _HANDLER_MARK, True)
    return handler


def configure_logging(level: str = "INFO", fmt: str = "text", *, stream: TextIO | None = None) -> None:
    """Send every record at ``level`` and above to stderr in format ``fmt`` (``text`` or ``json``).

    Safe to call again (the handler is replaced, not added twice).
    """
    numeric = logging.getLevelName(level.upper())
    if not isinstance(numeric, int):
        numeric = logging.INFO
    root = logging.getLogger()
    for handler in list(root.handlers):
        if getattr(handler, _HANDLER_MARK, False):
            root.removeHandler(handler)
    root.addHandler(make_handler(fmt, stream))
    root.setLevel(numeric)
    for name in _SERVER_LOGGERS:
        server = logging.getLogger(name)
        server.handlers.clear()
        server.propagate = True
    for name in _OWN_HANDLER_LOGGERS:
        own = logging.getLogger(name)
        own.handlers[:] = [h for h in own.handlers if not getattr(h, _HANDLER_MARK, False)]
        own.addHandler(make_handler(fmt, stream))
    # The API logs each request itself, with its id (see service.observability).
    access = logging.getLogger("uvicorn.access")
    access.handlers.clear()
    access.propagate = False
    access.disabled = True
    logging.captureWarnings(True)
    logging.getLogger("py.warnings").setLevel(logging.DEBUG if numeric <= logging.DEBUG else logging.ERROR)
    if numeric > logging.DEBUG:
        warnings.filterwarnings("ignore", module="celery")
        warnings.filterwarnings("ignore", module="kombu")


def console(message: str, *, fmt: str | None = None, level: str = "INFO", logger: str = "eigenscope") -> None:
    """Write one line to stderr as the process's log lines are (``fmt``, default
    ``EIGENSCOPE_LOG_FORMAT``): a JSON object in ``json`` mode, the bare message otherwise. For what a
    process says before or beside its logging (the supervisor's start-up line, Celery's shutdown)."""
    fmt = fmt or os.environ.get("EIGENSCOPE_LOG_FORMAT", "text")
    if fmt == "json":
        doc = {
            "time": datetime.now(UTC).isoformat(timespec="milliseconds"),
            "level": level,
            "logger": logger,
            "message": message,
        }
        line = json.dumps(doc, ensure_ascii=False)
    else:
        line = message
    print(line, file=sys.stderr, flush=True)
