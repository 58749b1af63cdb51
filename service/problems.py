"""One place that turns every error into RFC 9457 ``application/problem+json``."""

from __future__ import annotations

import logging
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from backend.errors import PROBLEM_BASE, ServiceError, problem_type
from service.methods import ORIGINAL_METHOD
from service.validation import MAX_FIELD_ERRORS, MAX_READ_ERRORS, field_errors, summary

log = logging.getLogger(__name__)

PROBLEM_MEDIA_TYPE = "application/problem+json"


class ProblemResponse(JSONResponse):
    media_type = PROBLEM_MEDIA_TYPE


def _phrase(status: int) -> str:
    try:
        return HTTPStatus(status).phrase
    except ValueError:
        return "Error"


def _head(code: str) -> dict[str, Any]:
    """``type``, ``title`` and ``status`` of ``code`` (from :data:`backend.errors.PROBLEM_TYPES`)."""
    kind = problem_type(code)
    return {"type": PROBLEM_BASE + code, "title": kind.title, "status": kind.status}


def problem_response(doc: dict[str, Any], headers: dict[str, str] | None = None) -> ProblemResponse:
    return ProblemResponse(doc, status_code=int(doc["status"]), headers=headers)


def _validation_errors(exc: RequestValidationError) -> tuple[list[dict[str, Any]], bool]:
    """The field errors (of the first :data:`~service.validation.MAX_READ_ERRORS`), and whether there
    were more."""
    raw = exc.errors()
    return field_errors(raw), len(raw) > MAX_READ_ERRORS


async def _service_error(request: Request, exc: Exception) -> ProblemResponse:
    assert isinstance(exc, ServiceError)
    if exc.status >= 500:
        log.error("%s %s: %s", request.method, request.url.path, exc.detail)
    return problem_response(exc.problem(instance=request.url.path), exc.headers() or None)


async def _validation_error(request: Request, exc: Exception) -> ProblemResponse:
    assert isinstance(exc, RequestValidationError)
    errors, truncated = _validation_errors(exc)
    doc = {
        **_head("invalid-request"),
        "detail": summary(errors, truncated=truncated) or "the request is not valid",
        "instance": request.url.path,
        "errors": errors[:MAX_FIELD_ERRORS],
    }
    return problem_response(doc)


async def _http_error(request: Request, exc: Exception) -> ProblemResponse:
    assert isinstance(exc, StarletteHTTPException)
    detail = exc.detail if isinstance(exc.detail, str) else None
    if exc.status_code == 400 and detail == "There was an error parsing the body":
        # FastAPI's answer to a body that is not UTF-8: the same 422 as any other malformed JSON body.
        return problem_response(
            {
                **_head("invalid-request"),
                "detail": "the request body cannot be parsed: send UTF-8 JSON",
                "instance": request.url.path,
                "errors": [{"loc": ["body"], "msg": "JSON decode error", "type": "json_invalid"}],
            }
        )
    if exc.status_code == 404 and detail == "Not Found":
        detail = f"no such resource: {request.method} {request.url.path}"
    if exc.status_code == 405:
        method = request.scope.get(ORIGINAL_METHOD) or request.method
        detail = f"{method} is not allowed on {request.url.path}; the allowed methods are in `Allow`"
    doc = {
        "type": "about:blank",
        "title": _phrase(exc.status_code),
        "status": exc.status_code,
        "detail": detail,
        "instance": request.url.path,
    }
    return problem_response(doc, dict(exc.headers) if exc.headers else None)


async def _unexpected_error(request: Request, exc: Exception) -> ProblemResponse:
    log.exception("%s %s failed", request.method, request.url.path, exc_info=exc)
    doc = {
        **_head("internal-error"),
        "detail": "the server failed to handle this request; the error is in the server log",
        "instance": request.url.path,
    }
    return problem_response(doc)


def install_problem_handlers(app: FastAPI) -> None:
    """Register the handlers: domain errors, validation errors, HTTP errors and anything unexpected."""
    app.add_exception_handler(ServiceError, _service_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_exception_handler(Exception, _unexpected_error)
