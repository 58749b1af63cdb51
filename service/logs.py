"""Logging of the API and worker processes: one handler on stderr, text or JSON, with request and job ids.

- ``EIGENSCOPE_LOG_FORMAT=text`` (default): ``2026-01-02 10:11:12,345 INFO service.jobs: job 1f..: queued
  [request_id=ab12..]``; ``json``: one object a line with ``time``, ``level``, ``logger``, ``message`` and,
  when known, ``request_id``, ``job_id`` and ``exception``.
- The request id (an incoming ``X-Request-ID``, or a new one) and the job id a worker runs are kept in
  context variables and added to every record logged meanwhile.
- Uvicorn's and Celery's loggers go through the same handler (uvicorn's access log is replaced by the
  API's own, which carries the request id); Python warnings from libraries are not shown unless the level
  is DEBUG.
"""

from __future__ import annotations

import json
import logging
import sys
import warnings
from contextvars import ContextVar
from datetime import UTC, datetime
from typing import Any, TextIO

#: The request being served (API) and the job being run (worker), added to each log record.
request_id_var: ContextVar[str | None] = ContextVar("eigenscope_request_id", default=None)
job_id_var: ContextVar[str | None] = ContextVar("eigenscope_job_id", default=None)

_HANDLER_MARK = "_eigenscope_handler"
#: Loggers of the servers we run: their records go through our handler, not their own.
_SERVER_LOGGERS = ("uvicorn", "uvicorn.error", "celery", "kombu", "amqp")


class ContextFilter(logging.Filter):
    """Adds ``request_id`` and ``job_id`` (None when unknown) to every record."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not hasattr(record, "request_id"):
            record.request_id = request_id_var.get()
        if not hasattr(record, "job_id"):
            record.job_id = job_id_var.get()
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
        for key in ("request_id", "job_id"):
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
