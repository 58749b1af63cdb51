"""One exception tree: every error the client raises is an :class:`EigenscopeError`.

Problem documents (RFC 9457 ``application/problem+json``) become :class:`APIError` subclasses chosen by
the HTTP status, carrying the document's ``type``, ``title``, ``status``, ``detail``, ``instance`` and
field ``errors``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from eigenscope_client._models import Job, Problem


class EigenscopeError(Exception):
    """Base of every error this client raises."""


class TransportError(EigenscopeError):
    """The server could not be reached, or the connection broke (after the retries allowed)."""


class StreamError(EigenscopeError):
    """A live stream failed: the server sent a fatal ``error`` (its problem document in ``problem``), the
    connection closed, or an answer did not come in time."""

    def __init__(self, message: str, *, problem: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.problem: dict[str, Any] = problem or {}
        self.status: int | None = self.problem.get("status")


class ForceLogError(EigenscopeError, ValueError):
    """A force log the server would refuse (:class:`~eigenscope_client.ForceLog`): a file that is not a
    force log, a column not one value per time, times that do not increase, values that are not finite.
    The message says what to fix."""


class WaitTimeoutError(EigenscopeError, TimeoutError):
    """A job did not end within the time given to :meth:`Client.wait`; ``job`` is its last state."""

    def __init__(self, message: str, job: Job) -> None:
        super().__init__(message)
        self.job = job


class JobFailedError(EigenscopeError):
    """A job ended ``failed`` or ``cancelled`` (raised by :meth:`Job.raise_for_status`)."""

    def __init__(self, job: Job) -> None:
        self.job = job
        self.problem: Problem | None = job.error
        why = f": {job.error.title}: {job.error.detail}" if job.error is not None else ""
        super().__init__(f"job {job.id} {job.status}{why}")


class APIError(EigenscopeError):
    """The server answered with an error (a problem document).

    Attributes
    ----------
    type, title, status, detail, instance : the problem document's members
    errors : list of dict or None
        Field-level errors (``loc``, ``msg``) of a 422.
    problem : dict
        The whole document, extension members included.
    request_id : str or None
        The ``X-Request-ID`` of the request, to find it in the server's log.
    """

    def __init__(self, problem: dict[str, Any], *, status: int, request_id: str | None = None) -> None:
        self.problem = problem
        self.status = int(problem.get("status") or status)
        self.type = str(problem.get("type") or "about:blank")
        self.title = str(problem.get("title") or "Error")
        self.detail: str | None = problem.get("detail")
        self.instance: str | None = problem.get("instance")
        errors = problem.get("errors")
        self.errors: list[dict[str, Any]] | None = errors if isinstance(errors, list) else None
        self.request_id = request_id
        message = f"{self.status} {self.title}"
        if self.detail:
            message += f": {self.detail}"
        super().__init__(message)

    @property
    def code(self) -> str:
        """The last segment of ``type`` (``job-not-found``), the stable machine-readable reason."""
        return self.type.rstrip("/").rsplit("/", 1)[-1]


class BadRequestError(APIError):
    """400."""


class AuthenticationError(APIError):
    """401: no API key, or not a valid one."""


class PermissionDeniedError(APIError):
    """403."""


class NotFoundError(APIError):
    """404: no such clip, job or artifact (or not this key's)."""


class ConflictError(APIError):
    """409: the resource is in a state that forbids the request (e.g. cancelling a finished job)."""


class PayloadTooLargeError(APIError):
    """413: the clip is over the server's size cap."""


class UnsupportedMediaTypeError(APIError):
    """415: a clip format the server does not read."""


class InvalidRequestError(APIError):
    """422: a parameter, body or clip the server cannot use; ``errors`` says which field."""


class RateLimitError(APIError):
    """429: a per-key quota is reached; ``retry_after`` seconds is when to try again."""

    retry_after: float | None = None


class ServerError(APIError):
    """5xx."""


class ServiceUnavailableError(ServerError):
    """503: the database, broker or storage is unreachable for now."""


class InsufficientStorageError(ServerError):
    """507: the server's storage is full."""


_BY_STATUS: dict[int, type[APIError]] = {
    400: BadRequestError,
    401: AuthenticationError,
    403: PermissionDeniedError,
    404: NotFoundError,
    409: ConflictError,
    413: PayloadTooLargeError,
    415: UnsupportedMediaTypeError,
    422: InvalidRequestError,
    429: RateLimitError,
    503: ServiceUnavailableError,
    507: InsufficientStorageError,
}


def error_for(
    status: int, problem: dict[str, Any], *, request_id: str | None, retry_after: float | None
) -> APIError:
    """The exception for an error response of ``status`` carrying ``problem``."""
    cls = _BY_STATUS.get(status) or (ServerError if status >= 500 else APIError)
    error = cls(problem, status=status, request_id=request_id)
    if isinstance(error, RateLimitError):
        error.retry_after = retry_after
    return error
