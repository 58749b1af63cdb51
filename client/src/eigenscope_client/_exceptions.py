"""The client's exceptions: one tree rooted at :class:`EigenscopeError`."""

from __future__ import annotations

from typing import Any


class EigenscopeError(Exception):
    """Base of every error this client raises."""


class ApiError(EigenscopeError):
    """The server answered with an RFC 9457 problem (``problem`` holds the document)."""

    def __init__(
        self, message: str, *, problem: dict[str, Any] | None = None, status: int | None = None
    ) -> None:
        super().__init__(message)
        self.problem = problem or {}
        self.status = status


class StreamError(ApiError):
    """A live stream failed: a fatal ``error`` message, a closed connection or a timeout."""


class TransportError(EigenscopeError):
    """The server could not be reached."""
