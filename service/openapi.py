"""The OpenAPI document: problem+json error responses, the streamed upload body, clean names.

FastAPI documents error models under ``application/json`` and adds its own ``HTTPValidationError``;
:func:`finalize_openapi` rewrites every 4xx/5xx response to ``application/problem+json`` with the
``Problem`` schema, so generated clients parse errors into one type.
"""

from __future__ import annotations

from http import HTTPStatus
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from api_schemas import Problem

PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}

#: Schema of the multipart upload body (the route reads the stream itself, so it is declared here).
CLIP_UPLOAD_SCHEMA: dict[str, Any] = {
    "title": "ClipUpload",
    "type": "object",
    "required": ["file"],
    "properties": {
        "file": {
            "type": "string",
            "format": "binary",
            "description": "The clip: an .npz bundle or any other format `eigenscope probe` reads.",
        }
    },
}

UPLOAD_REQUEST_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {"multipart/form-data": {"schema": {"$ref": "#/components/schemas/ClipUpload"}}},
    }
}


def problem_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` entries declaring problem+json errors with these statuses."""
    return {s: {"model": Problem, "description": HTTPStatus(s).phrase} for s in statuses}


def finalize_openapi(spec: dict[str, Any]) -> dict[str, Any]:
    """Post-process FastAPI's document (see the module docstring)."""
    schemas = spec.setdefault("components", {}).setdefault("schemas", {})
    schemas["ClipUpload"] = CLIP_UPLOAD_SCHEMA
    for item in spec.get("paths", {}).values():
        for operation in item.values():
            if not isinstance(operation, dict):
                continue
            for status, response in operation.get("responses", {}).items():
                if str(status)[0] not in "45":
                    continue
                response["content"] = {"application/problem+json": {"schema": PROBLEM_REF}}
                if str(status) == "422":
                    response["description"] = "Unprocessable Content"
    schemas.pop("HTTPValidationError", None)
    schemas.pop("ValidationError", None)
    return _rename_to_titles(spec)


def _rename_to_titles(spec: dict[str, Any]) -> dict[str, Any]:
    """Name component schemas after their model titles (``JobModel`` -> ``Job``) and fix the refs."""
    schemas: dict[str, Any] = spec["components"]["schemas"]
    renames = {
        name: schema["title"]
        for name, schema in schemas.items()
        if isinstance(schema.get("title"), str)
        and schema["title"] != name
        and schema["title"].isidentifier()
        and schema["title"] not in schemas
    }
    if not renames:
        return spec
    spec["components"]["schemas"] = dict(sorted((renames.get(k, k), v) for k, v in schemas.items()))
    prefix = "#/components/schemas/"

    def fix(node: Any) -> Any:
        if isinstance(node, dict):
            out = {}
            for key, value in node.items():
                if key == "$ref" and isinstance(value, str) and value.startswith(prefix):
                    value = prefix + renames.get(value[len(prefix) :], value[len(prefix) :])
                out[key] = fix(value)
            return out
        if isinstance(node, list):
            return [fix(v) for v in node]
        return node

    fixed: dict[str, Any] = fix(spec)
    return fixed


def install_openapi(app: FastAPI, *, version: str, description: str) -> None:
    """Replace ``app.openapi`` with the finalized, cached document."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            spec = get_openapi(
                title=app.title,
                version=version,
                description=description,
                routes=app.routes,
            )
            app.openapi_schema = finalize_openapi(spec)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
