"""Error codes, their HTTP status and title (:data:`PROBLEM_TYPES`, the one table), and the service's errors.

Every problem document Eigenscope writes -- an API error, a failed job, a live stream's error message --
has type ``PROBLEM_BASE + code`` and takes its ``status`` and ``title`` from :data:`PROBLEM_TYPES`. Routes
and service functions raise :class:`ServiceError` and its subclasses; one handler in
:mod:`service.problems` turns them into ``application/problem+json``. Workers build their documents with
:func:`problem_document`. This module imports no web framework, so the workers can use it too; the OpenAPI
document lists the table (``x-problem-types`` of the ``Problem`` schema).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, ClassVar, NamedTuple

#: Problem types are ``PROBLEM_BASE + code``; the page need not exist (RFC 9457 allows opaque URIs).
PROBLEM_BASE = "https://eigenscope.dev/problems/"

#: An absolute file path of two or more components, not inside a word, URL or media type.
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~:/\\-])/((?:[^\s'\"`/:;,()\[\]{}<>|]+/)+)([^\s'\"`/:;,()\[\]{}<>|]*)")
#: First components of the API's own URL paths, which messages quote and which are not server paths.
_URL_ROOTS = frozenset({"v1", "docs", "docs-assets", "static", "openapi.json"})


def redact_paths(text: str) -> str:
    """``text`` with every absolute server path cut to its last component.

    ``/srv/eigenscope/var/tmp/upload-1/clip.npz`` becomes ``clip.npz`` (a folder keeps its own name):
    problem details name files, never where the server keeps them. The API's URL paths (``/v1/...``)
    are left alone.
    """

    def short(match: re.Match[str]) -> str:
        folders, last = match.group(1), match.group(2)
        if folders.split("/", 1)[0] in _URL_ROOTS:
            return match.group(0)
        return last or folders.rstrip("/").rsplit("/", 1)[-1]

    return _ABSOLUTE_PATH.sub(short, text)


class ProblemType(NamedTuple):
    """The HTTP status and the title of every problem with one code."""

    status: int
    title: str


#: Every error code Eigenscope reports, mapped to its HTTP status and title. Nothing else assigns either.
#: One naming scheme: a 404 is ``<resource>-not-found``; a 422 about a value is ``invalid-<what>`` or, for a
#: reference to something that does not exist, ``unknown-<what>``. Renamed codes are in :data:`RENAMED`.
PROBLEM_TYPES: Mapping[str, ProblemType] = {
    # Requests
    "invalid-request": ProblemType(422, "Unprocessable content"),
    "invalid-parameter": ProblemType(422, "Invalid parameter"),
    "invalid-force": ProblemType(422, "Invalid force recording"),
    "invalid-form": ProblemType(422, "Invalid form"),
    "invalid-cursor": ProblemType(422, "Invalid cursor"),
    "idempotency-key-reused": ProblemType(422, "Idempotency key reused"),
    "callbacks-disabled": ProblemType(422, "Callbacks disabled"),
    "invalid-callback-url": ProblemType(422, "Invalid callback URL"),
    "callback-host-not-allowed": ProblemType(422, "Callback host not allowed"),
    "unknown-clip": ProblemType(422, "Unknown clip"),
    "request-timeout": ProblemType(408, "Request timeout"),
    "body-too-large": ProblemType(413, "Payload too large"),
    "upload-too-large": ProblemType(413, "Upload too large"),
    "unsupported-media-type": ProblemType(415, "Unsupported media type"),
    # Authentication and quotas
    "unauthorized": ProblemType(401, "Unauthorized"),
    "missing-api-key": ProblemType(401, "Unauthorized"),
    "invalid-authorization": ProblemType(401, "Unauthorized"),
    "invalid-api-key": ProblemType(401, "Unauthorized"),
    "metrics-token-required": ProblemType(401, "Unauthorized"),
    "invalid-token": ProblemType(401, "Unauthorized"),
    "quota-exceeded": ProblemType(429, "Too many requests"),
    "too-many-failed-authentications": ProblemType(429, "Too many requests"),
    "too-many-jobs": ProblemType(429, "Too many requests"),
    "storage-quota-exceeded": ProblemType(429, "Too many requests"),
    # Resources
    "not-found": ProblemType(404, "Not found"),
    "clip-not-found": ProblemType(404, "Not found"),
    "job-not-found": ProblemType(404, "Not found"),
    "stream-not-found": ProblemType(404, "Not found"),
    "artifact-not-found": ProblemType(404, "Not found"),
    "result-not-found": ProblemType(404, "Not found"),
    "conflict": ProblemType(409, "Conflict"),
    "clip-in-use": ProblemType(409, "Conflict"),
    "job-finished": ProblemType(409, "Conflict"),
    "job-busy": ProblemType(409, "Conflict"),
    # Clips (the codes of workers.pipeline.errors and of the upload probe)
    "invalid-clip": ProblemType(422, "Invalid clip"),
    "unsupported-format": ProblemType(415, "Unsupported clip format"),
    "clip-too-large": ProblemType(413, "Clip too large"),
    "probe-timeout": ProblemType(422, "Invalid clip"),
    "probe-failed": ProblemType(500, "Clip validation failed"),
    # Jobs
    "eigenscope-error": ProblemType(422, "Analysis failed"),
    "analysis-failed": ProblemType(422, "Analysis failed"),
    "clip-gone": ProblemType(410, "Clip gone"),
    "time-limit": ProblemType(500, "Time limit exceeded"),
    "resources-exhausted": ProblemType(413, "Resources exhausted"),
    "analysis-crashed": ProblemType(500, "Analysis crashed"),
    "worker-lost": ProblemType(500, "Worker lost"),
    # Live streams
    "invalid-message": ProblemType(422, "Invalid message"),
    "invalid-frame": ProblemType(422, "Invalid frame"),
    "timestamp-backwards": ProblemType(422, "Invalid frame"),
    "undecodable-frame": ProblemType(422, "Invalid frame"),
    "depth-without-color": ProblemType(422, "Invalid frame"),
    "wrong-size": ProblemType(422, "Invalid frame"),
    "frame-too-large": ProblemType(413, "Frame too large"),
    "invalid-resume-token": ProblemType(403, "Invalid resume token"),
    "stream-connected": ProblemType(409, "Stream already connected"),
    "stream-ended": ProblemType(409, "Stream ended"),
    "stream-aborted": ProblemType(409, "Stream aborted"),
    "max-duration": ProblemType(413, "Stream too long"),
    "client-timeout": ProblemType(408, "Client silent"),
    "no-worker": ProblemType(503, "No stream worker"),
    # The server
    "internal-error": ProblemType(500, "Internal error"),
    "insufficient-storage": ProblemType(507, "Insufficient storage"),
    "unavailable": ProblemType(503, "Service unavailable"),
    "too-many-uploads": ProblemType(503, "Service unavailable"),
    "too-many-large-requests": ProblemType(503, "Service unavailable"),
    "not-ready": ProblemType(503, "Service unavailable"),
    "database-unavailable": ProblemType(503, "Service unavailable"),
    "storage-unavailable": ProblemType(503, "Service unavailable"),
}


#: Codes an earlier version reported, and the one reporting the same problem now (``docs/problems.md``).
RENAMED: Mapping[str, str] = {
    "no-such-clip": "clip-not-found",  # 404 of GET or DELETE /v1/clips/{clip_id}
    "clip-not-found": "unknown-clip",  # 422 of a job or stream naming a clip that does not exist
}


def problem_type(code: str) -> ProblemType:
    """The status and title of ``code``; a code missing from :data:`PROBLEM_TYPES` is a bug of ours."""
    try:
        return PROBLEM_TYPES[code]
    except KeyError:
        raise KeyError(f"error code {code!r} is not in backend.errors.PROBLEM_TYPES; add it there") from None


def problem_document(code: str, detail: str, **extra: Any) -> dict[str, Any]:
    """The RFC 9457 document of a failed job or stream: type, title and status of ``code`` (from the
    table), ``detail`` with server paths cut, and ``code`` itself, plus any ``extra`` members."""
    kind = problem_type(code)
    return {
        "type": PROBLEM_BASE + code,
        "title": kind.title,
        "status": kind.status,
        "detail": redact_paths(detail),
        "code": code,
        **extra,
    }


class ServiceError(Exception):
    """Base of every error the API reports as a problem document."""

    #: The default code of the class; an instance may carry another (``code=``). Status and title follow
    #: the code, from :data:`PROBLEM_TYPES`.
    code: ClassVar[str] = "internal-error"
    #: Seconds a client should wait before trying again (sent as ``Retry-After``), if any.
    retry_after_s: int | None = None

    def __init__(
        self, detail: str, *, code: str | None = None, retry_after_s: int | None = None, **extra: Any
    ) -> None:
        super().__init__(detail)
        self.detail = detail
        if code is not None:
            self.code = code  # type: ignore[misc]
        if retry_after_s is not None:
            self.retry_after_s = retry_after_s
        self.extra = extra

    @property
    def status(self) -> int:
        return problem_type(self.code).status

    @property
    def title(self) -> str:
        return problem_type(self.code).title

    def headers(self) -> dict[str, str]:
        """HTTP headers that go with the problem document."""
        return {"Retry-After": str(self.retry_after_s)} if self.retry_after_s is not None else {}

    @property
    def type_uri(self) -> str:
        return PROBLEM_BASE + self.code

    def problem(self, instance: str | None = None) -> dict[str, Any]:
        """The RFC 9457 document of this error."""
        doc: dict[str, Any] = {
            "type": self.type_uri,
            "title": self.title,
            "status": self.status,
            "detail": redact_paths(self.detail),
        }
        if instance is not None:
            doc["instance"] = instance
        doc.update(self.extra)
        return doc


class UnauthorizedError(ServiceError):
    code = "unauthorized"

    def headers(self) -> dict[str, str]:
        return {**super().headers(), "WWW-Authenticate": 'Bearer realm="eigenscope"'}


class NotFoundError(ServiceError):
    code = "not-found"


class RequestTimeoutError(ServiceError):
    """The request body stalled (sent nothing for the idle timeout): 408, and the connection closes."""

    code = "request-timeout"

    def headers(self) -> dict[str, str]:
        return {**super().headers(), "Connection": "close"}


class ConflictError(ServiceError):
    code = "conflict"


class PayloadTooLargeError(ServiceError):
    code = "clip-too-large"


class UnsupportedMediaError(ServiceError):
    code = "unsupported-format"


class InvalidInputError(ServiceError):
    code = "invalid-request"


class InvalidClipError(InvalidInputError):
    code = "invalid-clip"


class QuotaExceededError(ServiceError):
    """A per-key limit (active jobs, stored bytes) is reached: 429 with ``Retry-After``."""

    code = "quota-exceeded"
    retry_after_s = 30


class InsufficientStorageError(ServiceError):
    code = "insufficient-storage"


class UnavailableError(ServiceError):
    code = "unavailable"
    retry_after_s = 5


class DatabaseUnavailableError(UnavailableError):
    code = "database-unavailable"


class StorageUnavailableError(UnavailableError):
    code = "storage-unavailable"


#: Codes of :mod:`workers.pipeline.errors` (and the probe) an upload's verdict may carry.
CLIP_CODES = frozenset({"invalid-clip", "unsupported-format", "clip-too-large", "invalid-parameter"})


def clip_error(code: str, detail: str) -> ServiceError:
    """The API error for a clip loader failure with machine code ``code`` (``invalid-clip`` if unknown)."""
    return ServiceError(detail, code=code if code in CLIP_CODES else "invalid-clip")
