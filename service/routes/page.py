"""The web page at ``/`` (and ``/jobs/{id}``, one job's own URL) and its static files under ``/static``,
kept out of the OpenAPI document.

The page is plain HTML, CSS and JavaScript shipped inside the package (``service/static``): nothing is built,
installed or downloaded to serve it, and it talks to the API of the same origin only, which its Content
Security Policy enforces. Its links are relative (the service may sit under a path prefix) to its
``<base href="./">``; a job's page is the same document with ``<base href="../">``, so they resolve from
the same place, also after the page moves from one job's URL to another's.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, FastAPI
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"

#: Same-origin only: scripts, styles, requests and images (blob: for images fetched with the API key).
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'self'; form-action 'self'; frame-ancestors 'none'"
)
HEADERS = {
    "Cache-Control": "no-cache",
    "Content-Security-Policy": CONTENT_SECURITY_POLICY,
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
}

router = APIRouter(include_in_schema=False)


@router.api_route("/", methods=["GET", "HEAD"], name="page")
def page() -> FileResponse:
    """The single-page web interface."""
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html; charset=utf-8", headers=HEADERS)


@cache
def _job_page() -> str:
    html = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
    # The document's links are relative to its base: fixed where it is served, so that links still
    # resolve after the page changes its URL (history.pushState) to a job's.
    if '<base href="./">' not in html:  # pragma: no cover - index.html and this function go together
        raise RuntimeError("index.html lost its <base href> element")
    return html.replace('<base href="./">', '<base href="../">', 1)


@router.api_route("/jobs/{job_id}", methods=["GET", "HEAD"], name="job_page")
def job_page(job_id: Annotated[str, PathParam(min_length=1, max_length=64)]) -> HTMLResponse:
    """The page showing one job: a URL to bookmark or share (the page checks the job exists)."""
    return HTMLResponse(_job_page(), headers=HEADERS)


def install_page(app: FastAPI) -> None:
    """Serve the page at ``/`` and its assets at ``/static/...`` on ``app``."""
    app.include_router(router)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
