"""``openapi/openapi.json`` is the app's spec, with clean operation ids, named schemas and declared errors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from eigenscope.commands.export_openapi import render_spec

SPEC_PATH = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"

OPERATIONS = {
    ("post", "/v1/clips"): "create_clip",
    ("get", "/v1/clips"): "list_clips",
    ("get", "/v1/clips/{clip_id}"): "get_clip",
    ("delete", "/v1/clips/{clip_id}"): "delete_clip",
    ("post", "/v1/jobs"): "create_job",
    ("get", "/v1/jobs"): "list_jobs",
    ("get", "/v1/jobs/{job_id}"): "get_job",
    ("delete", "/v1/jobs/{job_id}"): "delete_job",
    ("post", "/v1/jobs/{job_id}/cancel"): "cancel_job",
    ("get", "/v1/jobs/{job_id}/artifacts/{name}"): "get_job_artifact",
    ("post", "/v1/streams"): "create_stream",
    ("get", "/v1/streams"): "list_streams",
    ("get", "/v1/streams/{stream_id}"): "get_stream",
    ("get", "/healthz"): "healthz",
    ("get", "/readyz"): "readyz",
    ("get", "/metrics"): "metrics",
}


@pytest.fixture(scope="module")
def spec() -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(SPEC_PATH.read_text())
    return doc


def test_committed_spec_equals_the_apps() -> None:
    assert SPEC_PATH.read_text() == render_spec(), "run `eigenscope export-openapi` and commit the result"


def test_operation_ids(spec: dict[str, Any]) -> None:
    found = {(m, p): op["operationId"] for p, item in spec["paths"].items() for m, op in item.items()}
    assert found == OPERATIONS


def test_errors_are_declared_as_problem_json(spec: dict[str, Any]) -> None:
    for path, item in spec["paths"].items():
        for method, op in item.items():
            for status, response in op["responses"].items():
                if status[0] in "45":
                    assert list(response["content"]) == ["application/problem+json"], (method, path, status)
                    assert response["content"]["application/problem+json"]["schema"] == {
                        "$ref": "#/components/schemas/Problem"
                    }
    expected = {
        ("post", "/v1/clips"): {"413", "415", "422"},
        ("get", "/v1/jobs/{job_id}"): {"404"},
        ("post", "/v1/jobs/{job_id}/cancel"): {"404", "409"},
        ("post", "/v1/jobs"): {"422"},
    }
    for (method, path), statuses in expected.items():
        assert statuses <= set(spec["paths"][path][method]["responses"]), (method, path)


def test_named_schemas(spec: dict[str, Any]) -> None:
    schemas = spec["components"]["schemas"]
    for name in (
        "Clip",
        "Job",
        "JobCreate",
        "JobList",
        "JobStatus",
        "Problem",
        "AnalysisResult",
        "ClipUpload",
    ):
        assert name in schemas
    assert not any(n.startswith(("Body_", "HTTPValidation")) or n.endswith("Model") for n in schemas), list(
        schemas
    )
    upload = spec["paths"]["/v1/clips"]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]
    assert upload == {"$ref": "#/components/schemas/ClipUpload"}
    job_post = spec["paths"]["/v1/jobs"]["post"]
    assert {"Location", "Retry-After"} <= set(job_post["responses"]["202"]["headers"])


def test_generators_need_no_key_where_the_server_asks_none(spec: dict[str, Any]) -> None:
    """A server may run open: the document takes the key optionally (every /v1 operation inherits it);
    health and metrics take none."""
    assert spec["security"] == [{}, {"ApiKey": []}]
    for path, item in spec["paths"].items():
        for method, op in item.items():
            if path in ("/healthz", "/readyz", "/metrics"):
                assert op["security"] == [], (method, path)
            else:
                assert "security" not in op, (method, path)
    assert spec["components"]["securitySchemes"]["ApiKey"] == {
        "type": "http",
        "description": "`Authorization: Bearer <API key>`, when the server is configured with keys.",
        "scheme": "bearer",
    }


def test_servers_licence_and_contact(spec: dict[str, Any]) -> None:
    assert spec["servers"] == [{"url": "/", "description": "The server this document is served by"}]
    assert spec["info"]["license"] == {"name": "MIT", "identifier": "MIT"}
    assert spec["info"]["contact"]["url"].startswith("https://")


def test_request_schemas_keep_defaulted_fields_optional(spec: dict[str, Any]) -> None:
    """No property of a request schema has a ``default`` (generators would make it required); the default
    is in its description instead, and ``required`` lists only what a request must send."""
    from service.openapi import request_schemas

    schemas = spec["components"]["schemas"]
    names = request_schemas(spec)
    assert {"JobCreate", "StepReleaseExcitation", "ImpulseExcitation", "AnalysisParameters"} <= names
    for name in names:
        for prop_name, prop in schemas[name].get("properties", {}).items():
            assert "default" not in prop, (name, prop_name)
    assert schemas["JobCreate"]["required"] == ["clip_id"]
    assert schemas["StepReleaseExcitation"]["required"] == ["type", "force_n"]
    assert (
        "Default: `0.0`."
        in schemas["StepReleaseExcitation"]["properties"]["force_uncertainty_n"]["description"]
    )
    assert 'Default: `"default"`.' in schemas["AnalysisParameters"]["properties"]["method"]["description"]


def test_every_response_declares_its_media_type(spec: dict[str, Any]) -> None:
    """Responses with a body name its media type; 204 and 304 have none."""
    for path, item in spec["paths"].items():
        for method, op in item.items():
            for status, response in op["responses"].items():
                if status in ("204", "304"):
                    assert "content" not in response, (method, path, status)
                else:
                    assert response.get("content"), (method, path, status)
    artifact = spec["paths"]["/v1/jobs/{job_id}/artifacts/{name}"]["get"]["responses"]
    assert {"image/png", "application/json"} <= set(artifact["200"]["content"])
    assert "ETag" in artifact["200"]["headers"]
    assert "304" in spec["paths"]["/v1/jobs/{job_id}"]["get"]["responses"]
    wait = next(p for p in spec["paths"]["/v1/jobs/{job_id}"]["get"]["parameters"] if p["name"] == "wait")
    assert wait["in"] == "query"
