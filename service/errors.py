"""Domain errors of the service, each with its HTTP status and RFC 9457 problem type.

Routes and service functions raise these; one handler in :mod:`service.problems` turns them into
``application/problem+json``. This module imports no web framework, so the workers can use it too.
"""

from __future__ import annotations

import re
from typing import Any, ClassVar

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


class ServiceError(Exception):
    """Base of every error the API reports as a problem document."""

    status: ClassVar[int] = 500
    title: ClassVar[str] = "Internal error"
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
    status = 401
    title = "Unauthorized"
    code = "unauthorized"

    def headers(self) -> dict[str, str]:
        return {**super().headers(), "WWW-Authenticate": 'Bearer realm="eigenscope"'}


class NotFoundError(ServiceError):
    status = 404
    title = "Not found"
    code = "not-found"


class RequestTimeoutError(ServiceError):
    """The request body stalled (sent nothing for the idle timeout): 408, and the connection closes."""

    status = 408
    title = "Request timeout"
    code = "request-timeout"

    def headers(self) -> dict[str, str]:
        return {**super().headers(), "Connection": "close"}


class ConflictError(ServiceError):
    status = 409
    title = "Conflict"
    code = "conflict"


class PayloadTooLargeError(ServiceError):
    status = 413
    title = "Payload too large"
    code = "clip-too-large"


class UnsupportedMediaError(ServiceError):
    status = 415
    title = "Unsupported media type"
    code = "unsupported-format"


class InvalidInputError(ServiceError):
    status = 422
    title = "Unprocessable content"
    code = "invalid-request"


class InvalidClipError(InvalidInputError):
    title = "Invalid clip"
    code = "invalid-clip"


class QuotaExceededError(ServiceError):
    """A per-key limit (active jobs, stored bytes) is reached: 429 with ``Retry-After``."""

    status = 429
    title = "Too many requests"
    code = "quota-exceeded"
    retry_after_s = 30


class InsufficientStorageError(ServiceError):
    status = 507
    title = "Insufficient storage"
    code = "insufficient-storage"


class UnavailableError(ServiceError):
    status = 503
    title = "Service unavailable"
    code = "unavailable"
    retry_after_s = 5


class DatabaseUnavailableError(UnavailableError):
    code = "database-unavailable"


class StorageUnavailableError(UnavailableError):
    code = "storage-unavailable"


#: Codes of :mod:`workers.pipeline.errors` (and the probe) mapped to API errors.
CLIP_ERROR_TYPES: dict[str, type[ServiceError]] = {
    "invalid-clip": InvalidClipError,
    "unsupported-format": UnsupportedMediaError,
    "clip-too-large": PayloadTooLargeError,
    "invalid-parameter": InvalidInputError,
}


def clip_error(code: str, detail: str) -> ServiceError:
    """The API error for a clip loader failure with machine code ``code``."""
    cls = CLIP_ERROR_TYPES.get(code, InvalidClipError)
    return cls(detail, code=code if code in CLIP_ERROR_TYPES else "invalid-clip")
