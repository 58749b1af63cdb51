"""The web page at ``/`` and its static files under ``/static`` (kept out of the OpenAPI document).

The page is plain HTML, CSS and JavaScript shipped inside the package (``service/static``): nothing is built,
installed or downloaded to serve it, and it talks to the API of the same origin only, which its Content
Security Policy enforces.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"

#: Same-origin only: scripts, styles, requests and images (blob: for images fetched with the API key).
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
)

router = APIRouter(include_in_schema=False)


@router.api_route("/", methods=["GET", "HEAD"], name="page")
def page() -> FileResponse:
    """The single-page web interface."""
    return FileResponse(
        STATIC_DIR / "index.html",
        media_type="text/html; charset=utf-8",
        headers={
            "Cache-Control": "no-cache",
            "Content-Security-Policy": CONTENT_SECURITY_POLICY,
            "X-Content-Type-Options": "nosniff",
            "Referrer-Policy": "same-origin",
        },
    )


def install_page(app: FastAPI) -> None:
    """Serve the page at ``/`` and its assets at ``/static/...`` on ``app``."""
    app.include_router(router)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
