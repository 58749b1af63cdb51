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
  leave out; a discriminator (``type`` of an excitation) keeps its one value as its default, so that
  generated clients fill it in;
- declares optional parameters as absent rather than nullable (``wait``, ``cursor``, ``If-None-Match``
  ...): a generated client would otherwise send ``None``;
- declares what every response carries: ``Retry-After`` on each 429 and 503, a 405 with ``Allow`` on
  every operation (``HEAD`` is answered wherever ``GET`` is, see :mod:`service.methods`), the types of
  problem documents as an enumeration of ``Problem.type``;
- adds the job callbacks as OpenAPI 3.1 ``webhooks`` (``jobEnded``: the ``JobEvent`` body, its signature
  headers and the scheme), and describes the upload's file part as binary (``contentMediaType``).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from api_schemas import Problem
from backend.errors import PROBLEM_BASE, PROBLEM_TYPES

PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}

#: The ``ETag`` response header of jobs and artifacts.
ETAG_HEADER: dict[str, Any] = {
    "description": "Entity tag of the representation; send it back in `If-None-Match`",
    "schema": {"type": "string"},
}
#: ``Retry-After`` in seconds (the server never sends an HTTP date).
RETRY_AFTER_HEADER: dict[str, Any] = {
    "description": "Seconds to wait before trying again",
    "schema": {"type": "integer", "minimum": 0},
}
#: Statuses whose problem documents always come with ``Retry-After``.
THROTTLED = ("429", "503")
#: Routes any client may call without a key.
PUBLIC_PATHS = ("/healthz", "/readyz", "/metrics")
#: The key is optional: a server with no keys configured runs open.
OPTIONAL_KEY: list[dict[str, list[str]]] = [{}, {"ApiKey": []}]
SERVERS = [{"url": "/", "description": "The server this document is served by"}]
HTTP_METHODS = frozenset({"get", "put", "post", "delete", "options", "head", "patch", "trace"})
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
            "contentMediaType": "application/octet-stream",
            "description": "The clip's bytes (a file part, with its file name): an .npz bundle or any other "
            "format `eigenscope probe` reads.",
        }
    },
}

UPLOAD_REQUEST_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {"$ref": "#/components/schemas/ClipUpload"},
                "encoding": {"file": {"contentType": "application/octet-stream"}},
            }
        },
    }
}


def problem_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` entries declaring problem+json errors with these statuses."""
    return {s: {"model": Problem, "description": HTTPStatus(s).phrase} for s in statuses}


def operations(spec: dict[str, Any]) -> Iterator[tuple[str, str, dict[str, Any]]]:
    """``(path, method, operation)`` of every operation of the document."""
    for path, item in spec.get("paths", {}).items():
        for method, operation in item.items():
            if isinstance(operation, dict) and method in HTTP_METHODS:
                yield path, method, operation


def finalize_openapi(spec: dict[str, Any]) -> dict[str, Any]:
    """Post-process FastAPI's document (see the module docstring)."""
    schemas = spec.setdefault("components", {}).setdefault("schemas", {})
    schemas["ClipUpload"] = CLIP_UPLOAD_SCHEMA
    _declare_405(spec)
    for _path, _method, operation in operations(spec):
        for status, response in operation.get("responses", {}).items():
            if str(status)[0] not in "45":
                continue
            response["content"] = {"application/problem+json": {"schema": PROBLEM_REF}}
            if str(status) == "422":
                response["description"] = "Unprocessable Content"
            if str(status) in THROTTLED:
                response.setdefault("headers", {})["Retry-After"] = RETRY_AFTER_HEADER
        _parameters_not_nullable(operation)
    _problem_types(schemas)
    schemas.pop("HTTPValidationError", None)
    schemas.pop("ValidationError", None)
    _security(spec)
    spec["servers"] = SERVERS
    spec.setdefault("info", {}).update({"license": LICENSE, "contact": CONTACT})
    add_webhooks(spec)
    spec = rename_to_titles(spec)
    _request_defaults_optional(spec)
    _discriminator_defaults(spec["components"]["schemas"])
    return spec


def _declare_405(spec: dict[str, Any]) -> None:
    """Every operation may be answered 405 (a method its path does not have), with the path's methods
    in ``Allow``."""
    for path, item in spec.get("paths", {}).items():
        methods = sorted(m.upper() for m in item if m in HTTP_METHODS)
        if "GET" in methods:
            methods = sorted({*methods, "HEAD"})
        for _p, _m, operation in operations({"paths": {path: item}}):
            operation.setdefault("responses", {})["405"] = {
                "description": "Method Not Allowed",
                "headers": {
                    "Allow": {
                        "description": f"The methods of this path: `{', '.join(methods)}`",
                        "schema": {"type": "string"},
                    }
                },
            }


def _non_null(schema: dict[str, Any]) -> dict[str, Any]:
    """``schema`` without its ``null`` alternative (``anyOf: [X, {type: null}]`` becomes ``X``)."""
    branches = schema.get("anyOf")
    if not isinstance(branches, list):
        return schema
    kept = [b for b in branches if b != {"type": "null"}]
    if len(kept) == len(branches):
        return schema
    rest = {k: v for k, v in schema.items() if k != "anyOf"}
    return {**kept[0], **rest} if len(kept) == 1 else {**rest, "anyOf": kept}


def _parameters_not_nullable(operation: dict[str, Any]) -> None:
    """An optional query or header parameter is left out, never sent empty: its schema takes no null."""
    for parameter in operation.get("parameters", []):
        if not parameter.get("required") and isinstance(parameter.get("schema"), dict):
            parameter["schema"] = _non_null(parameter["schema"])


def problem_types_extension() -> dict[str, dict[str, Any]]:
    """Every problem type the server reports, with its status and title (from
    :data:`backend.errors.PROBLEM_TYPES`)."""
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
        member["enum"] = [*problem_types_extension(), "about:blank"]
        member["description"] = (
            "URI identifying the problem type: one of the enumeration (its last segment is the error "
            "code; `x-problem-types` gives each one's status and title), or `about:blank` for a plain "
            "HTTP error."
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


def _discriminator_defaults(schemas: dict[str, Any]) -> None:
    """The discriminator of each tagged union (``type`` of an excitation) stays required and gets its one
    value as its default: generated clients fill it in (openapi-python-client's ``StepReleaseExcitation``
    needs no ``type_``) and still send it."""
    for schema in list(schemas.values()):
        for node in _walk(schema):
            discriminator = node.get("discriminator")
            if not isinstance(discriminator, dict):
                continue
            name = discriminator.get("propertyName")
            for value, ref in (discriminator.get("mapping") or {}).items():
                target = schemas.get(str(ref).rsplit("/", 1)[-1], {})
                prop = target.get("properties", {}).get(name)
                if isinstance(prop, dict) and prop.get("const") == value:
                    prop["default"] = value
                    required = target.setdefault("required", [])
                    if name not in required:
                        required.insert(0, name)


def _walk(node: Any) -> Iterator[dict[str, Any]]:
    if isinstance(node, dict):
        yield node
        for value in node.values():
            yield from _walk(value)
    elif isinstance(node, list):
        for value in node:
            yield from _walk(value)


def rename_to_titles(spec: dict[str, Any]) -> dict[str, Any]:
    """Name component schemas after their model titles (``JobModel`` -> ``Job``) and fix the refs (the
    OpenAPI and the AsyncAPI documents name each model the same)."""
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


WEBHOOK_DESCRIPTION = (
    "Sent to a job's `callback_url` (a host on the operator's allow-list, `EIGENSCOPE_CALLBACK_HOSTS`) once "
    "the job has ended: a `POST` of a `JobEvent`, signed by the Standard Webhooks scheme. To check it, "
    'compute `base64(HMAC-SHA256(key, "{webhook-id}.{webhook-timestamp}.{body}"))` over the raw body '
    "bytes, the key being the server's `EIGENSCOPE_CALLBACK_SECRET` (a `whsec_<base64>` secret "
    "base64-decoded, any other as its UTF-8 bytes), and compare it in constant time with each "
    "space-separated `v1,<signature>` of `webhook-signature`; refuse a `webhook-timestamp` more than five "
    "minutes from your clock. A delivery not answered 2xx within `EIGENSCOPE_CALLBACK_TIMEOUT_S` is "
    "retried with exponential backoff (or after the receiver's `Retry-After`) with the same `webhook-id`, "
    "up to `EIGENSCOPE_CALLBACK_MAX_ATTEMPTS` times; the job's `callback` shows the delivery's state. "
    "Redirects are not followed."
)


def _header(name: str, description: str) -> dict[str, Any]:
    return {
        "name": name,
        "in": "header",
        "required": True,
        "description": description,
        "schema": {"type": "string"},
    }


def add_webhooks(spec: dict[str, Any]) -> None:
    """The job callbacks as the document's ``webhooks`` (OpenAPI 3.1), with the ``JobEvent`` schema."""
    from pydantic.json_schema import models_json_schema

    from api_schemas import JobEvent

    schemas = spec["components"]["schemas"]
    refs, top = models_json_schema([(JobEvent, "serialization")], ref_template="#/components/schemas/{model}")
    ref = refs[(JobEvent, "serialization")]
    for name, schema in top.get("$defs", {}).items():
        schemas.setdefault(name, schema)
    spec["webhooks"] = {
        "jobEnded": {
            "post": {
                "operationId": "job_ended",
                "summary": "A job ended: its callback",
                "description": WEBHOOK_DESCRIPTION,
                "tags": ["jobs"],
                "security": [],
                "parameters": [
                    _header("webhook-id", "The event's id, `{job_id}.{status}`: the same on every retry."),
                    _header("webhook-timestamp", "When this attempt was signed, Unix seconds."),
                    _header(
                        "webhook-signature",
                        '`v1,<base64 HMAC-SHA256 of "{webhook-id}.{webhook-timestamp}.{body}">` '
                        "(one or more, space-separated).",
                    ),
                ],
                "requestBody": {
                    "required": True,
                    "content": {"application/json": {"schema": {"$ref": ref["$ref"]}}},
                },
                "responses": {
                    "2XX": {"description": "Delivered: the server stops sending this event."},
                    "default": {
                        "description": "Not delivered: the server tries again later (after `Retry-After` "
                        "when the answer has one)."
                    },
                },
            }
        }
    }
