"""``/docs``: Swagger UI served from the installed ``swagger-ui-bundle`` package, not from a CDN, so the
API explorer works on machines without internet access."""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

ASSETS = "/docs-assets"


def install_docs(app: FastAPI) -> None:
    """Serve Swagger UI at ``/docs`` with its scripts and styles from this server."""
    from swagger_ui_bundle import swagger_ui_path

    app.mount(ASSETS, StaticFiles(directory=swagger_ui_path), name="docs-assets")

    @app.get("/asyncapi.json", include_in_schema=False)
    def asyncapi(request: Request) -> JSONResponse:
        """The live streams' WebSocket protocol (AsyncAPI 3), naming this server (as the OpenAPI
        document's server, ``/``, does)."""
        from service.asyncapi import asyncapi_document

        host = request.url.netloc or None
        return JSONResponse(
            asyncapi_document(version=app.version, host=host, secure=request.url.scheme == "https")
        )

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title} API",
            swagger_js_url=f"{ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{ASSETS}/favicon-32x32.png",
        )
