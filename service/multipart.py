"""Stream one file field of a ``multipart/form-data`` request straight into storage.

Starlette's form parser spools every upload to a temporary file before the route runs, which doubles
disk traffic and enforces no size cap until the end. This reader parses the body as it arrives and
writes the chosen field's bytes to an :class:`~backend.storage.UploadSink`, which stops at the cap.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request

from backend.errors import InvalidInputError, PayloadTooLargeError, QuotaExceededError, UnsupportedMediaError
from backend.storage import UploadSink

#: Bytes of other (non-file) form fields we accept in total.
_MAX_OTHER_BYTES = 64 * 1024
#: After a too-large upload, read (and drop) at most this much more so the client sees the 413.
_DRAIN_BYTES = 64 * 1024 * 1024


@dataclass
class _PartState:
    headers: dict[str, str] = field(default_factory=dict)
    raw_headers: dict[str, bytes] = field(default_factory=dict)
    header_field: bytearray = field(default_factory=bytearray)
    header_value: bytearray = field(default_factory=bytearray)
    is_target: bool = False
    filename: str | None = None
    content_type: str | None = None


@dataclass
class ReceivedFile:
    """The file part of an upload, already written to ``sink``."""

    sink: UploadSink
    filename: str | None
    content_type: str | None
    fields: dict[str, str]


class _Receiver:
    def __init__(self, sink: UploadSink, field_name: str) -> None:
        self.sink = sink
        self.field_name = field_name
        self.part = _PartState()
        self.found = False
        self.ended = False
        self.filename: str | None = None
        self.content_type: str | None = None
        self.fields: dict[str, str] = {}
        self._value = bytearray()
        self._other_bytes = 0

    def callbacks(self) -> dict[str, Any]:
        return {
            "on_part_begin": self.on_part_begin,
            "on_header_field": self.on_header_field,
            "on_header_value": self.on_header_value,
            "on_header_end": self.on_header_end,
            "on_headers_finished": self.on_headers_finished,
            "on_part_data": self.on_part_data,
            "on_part_end": self.on_part_end,
            "on_end": self.on_end,
        }

    def on_part_begin(self) -> None:
        self.part = _PartState()
        self._value.clear()

    def on_header_field(self, data: bytes, start: int, end: int) -> None:
        self.part.header_field += data[start:end]

    def on_header_value(self, data: bytes, start: int, end: int) -> None:
        self.part.header_value += data[start:end]

    def on_header_end(self) -> None:
        name = self.part.header_field.decode("latin-1").strip().lower()
        self.part.raw_headers[name] = bytes(self.part.header_value).strip()
        self.part.headers[name] = self.part.header_value.decode("utf-8", errors="replace").strip()
        self.part.header_field.clear()
        self.part.header_value.clear()

    def on_headers_finished(self) -> None:
        # Raw bytes: the parser would encode a str as latin-1, which fails on UTF-8 file names.
        disposition, params = parse_options_header(self.part.raw_headers.get("content-disposition", b""))
        name = params.get(b"name", b"").decode("utf-8", errors="replace")
        if disposition == b"form-data" and name == self.field_name and not self.found:
            self.part.is_target = True
            self.found = True
            raw = params.get(b"filename")
            self.filename = raw.decode("utf-8", errors="replace") if raw is not None else None
            self.content_type = self.part.headers.get("content-type")
        self.part.filename = name

    def on_part_data(self, data: bytes, start: int, end: int) -> None:
        if self.part.is_target:
            self.sink.write(data[start:end])
            return
        self._other_bytes += end - start
        if self._other_bytes > _MAX_OTHER_BYTES:
            raise InvalidInputError(
                f"form fields other than {self.field_name!r} are limited to {_MAX_OTHER_BYTES} bytes",
                code="invalid-form",
            )
        self._value += data[start:end]

    def on_part_end(self) -> None:
        if not self.part.is_target and self.part.filename:
            self.fields[self.part.filename] = self._value.decode("utf-8", errors="replace")

    def on_end(self) -> None:
        self.ended = True


async def _drain(request: Request, budget: int) -> None:
    try:
        async for chunk in request.stream():
            budget -= len(chunk)
            if budget < 0:
                return
    except Exception:  # the client went away: nothing to tell it
        return


async def receive_file(request: Request, sink: UploadSink, *, field_name: str = "file") -> ReceivedFile:
    """Parse the request body and write field ``field_name`` into ``sink``.

    Raises
    ------
    UnsupportedMediaError
        The body is not ``multipart/form-data``.
    PayloadTooLargeError
        The file exceeds the sink's limit (checked against Content-Length first, then while streaming).
    InvalidInputError
        The body is malformed or truncated, or has no field ``field_name``.
    """
    ctype, params = parse_options_header(request.headers.get("content-type", ""))
    if ctype != b"multipart/form-data" or b"boundary" not in params:
        raise UnsupportedMediaError(
            f"send the clip as multipart/form-data with the file in a field named {field_name!r} "
            f"(got Content-Type {request.headers.get('content-type') or 'none'!r})",
            code="unsupported-media-type",
        )
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > sink.limit_bytes + 1024 * 1024:
        await _drain(request, _DRAIN_BYTES)
        raise PayloadTooLargeError(
            f"the upload of {int(declared)} bytes exceeds the limit of "
            f"{sink.limit_bytes // (1024 * 1024)} MiB (EIGENSCOPE_MAX_UPLOAD_MB); "
            "trim the clip or raise the limit",
            code="upload-too-large",
            max_bytes=sink.limit_bytes,
        )
    receiver = _Receiver(sink, field_name)
    parser = MultipartParser(params[b"boundary"], receiver.callbacks())  # type: ignore[arg-type]
    try:
        async for chunk in request.stream():
            if chunk:
                await run_in_threadpool(parser.write, chunk)
        parser.finalize()
    except (PayloadTooLargeError, QuotaExceededError):
        await _drain(request, _DRAIN_BYTES)  # so that the client reads the answer
        raise
    except (InvalidInputError, UnsupportedMediaError):
        raise
    except Exception as exc:
        if type(exc).__module__.startswith("python_multipart") or isinstance(exc, UnicodeError):
            raise InvalidInputError(f"malformed multipart body: {exc}", code="invalid-form") from exc
        raise
    if not receiver.ended:
        raise InvalidInputError("the multipart body is truncated (no closing boundary)", code="invalid-form")
    if not receiver.found:
        raise InvalidInputError(
            f"the form has no field {field_name!r}; send the clip file in a field named {field_name!r}",
            code="invalid-form",
            errors=[{"loc": ["body", field_name], "msg": "Field required", "type": "missing"}],
        )
    return ReceivedFile(sink, receiver.filename, receiver.content_type, receiver.fields)
