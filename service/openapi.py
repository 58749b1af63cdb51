"""The OpenAPI document: problem+json error responses, the streamed upload body, clean names, and what
client generators need.

FastAPI documents error models under ``application/json`` and adds its own ``HTTPValidationError``;
:func:`finalize_openapi` rewrites every 4xx/5xx response to ``application/problem+json`` with the
``Problem`` schema, so generated clients parse errors into one type. It also:

- makes the bearer key optional for the whole document (``security: [{}, {"ApiKey": []}]``), since a server
  may run open, and sets ``security: []`` on the health and metrics routes, so generated clients need no
  key where none is asked for;
- sets ``servers`` (the server the document is fetched from), the licence and a contact;
- drops ``default`` from the properties of request schemas (the default moves into the description):
  generators such as openapi-typescript make a property with a default required, which a request may
  leave out.
"""

from __future__ import annotations

import json
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from api_schemas import Problem
from service.errors import PROBLEM_BASE, PROBLEM_TYPES

PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}

#: The ``ETag`` response header of jobs and artifacts.
ETAG_HEADER: dict[str, Any] = {
    "description": "Entity tag of the representation; send it back in `If-None-Match`",
    "schema": {"type": "string"},
}
#: Routes any client may call without a key.
PUBLIC_PATHS = ("/healthz", "/readyz", "/metrics")
#: The key is optional: a server with no keys configured runs open.
OPTIONAL_KEY: list[dict[str, list[str]]] = [{}, {"ApiKey": []}]
SERVERS = [{"url": "/", "description": "The server this document is served by"}]
LICENSE = {"name": "MIT", "identifier": "MIT"}
CONTACT = {"name": "Eigenscope", "url": "https://eigenscope.dev"}

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
    _problem_types(schemas)
    schemas.pop("HTTPValidationError", None)
    schemas.pop("ValidationError", None)
    _security(spec)
    spec["servers"] = SERVERS
    spec.setdefault("info", {}).update({"license": LICENSE, "contact": CONTACT})
    spec = _rename_to_titles(spec)
    _request_defaults_optional(spec)
    return spec


def problem_types_extension() -> dict[str, dict[str, Any]]:
    """Every problem type the server reports, with its status and title (from
    :data:`service.errors.PROBLEM_TYPES`)."""
    return {
        PROBLEM_BASE + code: {"status": kind.status, "title": kind.title}
        for code, kind in sorted(PROBLEM_TYPES.items())
    }


def _problem_types(schemas: dict[str, Any]) -> None:
    """List the problem types on the ``Problem`` schema (``x-problem-types``): clients can switch on them."""
    problem = schemas.get("Problem")
    if problem is None:
        return
    problem["x-problem-types"] = problem_types_extension()
    member = problem.get("properties", {}).get("type")
    if member is not None:
        member["description"] = (
            "URI identifying the problem type: one of `x-problem-types` (its last segment is the error "
            "code), or `about:blank` for a plain HTTP error."
        )


def _security(spec: dict[str, Any]) -> None:
    """The optional key once for the document; the public routes ask for none. (Per-operation requirements
    would make generators such as openapi-python-client demand an authenticated client for each call.)"""
    spec["security"] = OPTIONAL_KEY
    for path, item in spec.get("paths", {}).items():
        for operation in item.values():
            if not isinstance(operation, dict):
                continue
            if path in PUBLIC_PATHS:
                operation["security"] = []
            else:
                operation.pop("security", None)


def _refs(node: Any) -> set[str]:
    prefix = "#/components/schemas/"
    found: set[str] = set()
    if isinstance(node, dict):
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith(prefix):
            found.add(ref[len(prefix) :])
        for value in node.values():
            found |= _refs(value)
    elif isinstance(node, list):
        for value in node:
            found |= _refs(value)
    return found


def request_schemas(spec: dict[str, Any]) -> set[str]:
    """Names of the component schemas a request body uses, directly or through others."""
    schemas = spec["components"]["schemas"]
    todo: set[str] = set()
    for item in spec.get("paths", {}).values():
        for operation in item.values():
            if isinstance(operation, dict) and "requestBody" in operation:
                todo |= _refs(operation["requestBody"])
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        if name in seen or name not in schemas:
            continue
        seen.add(name)
        todo |= _refs(schemas[name])
    return seen


def _request_defaults_optional(spec: dict[str, Any]) -> None:
    schemas = spec["components"]["schemas"]
    for name in request_schemas(spec):
        for prop in schemas[name].get("properties", {}).values():
            if "default" not in prop:
                continue
            default = prop.pop("default")
            if default is not None:
                text = f"Default: `{json.dumps(default)}`."
                prop["description"] = f"{prop['description']} {text}" if prop.get("description") else text


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
