"""``openapi/openapi.json`` is the app's spec, with clean operation ids, named schemas and declared errors."""

from __future__ import annotations

import json
import re
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
    ("get", "/v1/jobs/{job_id}/result"): "get_job_result",
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
            # A required discriminator keeps its one value as default (generators fill it in): required
            # it is anyway, so the default makes nothing required that a request may leave out.
            discriminator = prop.get("const") == prop.get("default") and prop_name in schemas[name].get(
                "required", []
            )
            assert "default" not in prop or discriminator, (name, prop_name)
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


def _operations(spec: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    return [(p, m, op) for p, item in spec["paths"].items() for m, op in item.items()]


def test_optional_parameters_are_absent_rather_than_nullable(spec: dict[str, Any]) -> None:
    """A generated client must not be able to send None for a parameter it may leave out."""
    found = []
    for path, method, op in _operations(spec):
        for parameter in op.get("parameters", []):
            text = json.dumps(parameter["schema"])
            if not parameter.get("required") and '"null"' in text:
                found.append((method, path, parameter["name"]))
    assert found == []


def test_retry_after_is_declared_wherever_it_is_sent(spec: dict[str, Any]) -> None:
    """Every 429 and 503 (quotas, failed keys, an unavailable store or broker) carries Retry-After, as do
    the 202 of a job and a poll of a job not yet ended (200 and 304)."""
    for path, method, op in _operations(spec):
        for status, response in op["responses"].items():
            if status in ("429", "503"):
                assert "Retry-After" in response.get("headers", {}), (method, path, status)
    job = spec["paths"]["/v1/jobs/{job_id}"]["get"]["responses"]
    assert "Retry-After" in job["200"]["headers"]
    assert "Retry-After" in job["304"]["headers"]
    assert "Retry-After" in spec["paths"]["/v1/jobs"]["post"]["responses"]["202"]["headers"]


def test_the_202_carries_the_jobs_etag_and_304_and_405_are_declared(spec: dict[str, Any]) -> None:
    assert "ETag" in spec["paths"]["/v1/jobs"]["post"]["responses"]["202"]["headers"]
    for path in ("/v1/jobs/{job_id}", "/v1/jobs/{job_id}/result", "/v1/jobs/{job_id}/artifacts/{name}"):
        assert "304" in spec["paths"][path]["get"]["responses"], path
    for path, method, op in _operations(spec):
        allow = op["responses"]["405"]["headers"]["Allow"]["description"]
        methods = {m.upper() for m in spec["paths"][path]} | (
            {"HEAD"} if "get" in spec["paths"][path] else set()
        )
        assert set(re.findall(r"[A-Z]+", allow.split("`")[1])) == methods, (method, path)


def test_webhooks_describe_the_job_callbacks_and_their_signature(spec: dict[str, Any]) -> None:
    hook = spec["webhooks"]["jobEnded"]["post"]
    headers = {p["name"]: p for p in hook["parameters"] if p["in"] == "header"}
    assert set(headers) == {"webhook-id", "webhook-timestamp", "webhook-signature"}
    assert all(p["required"] for p in headers.values())
    assert hook["requestBody"]["content"]["application/json"]["schema"] == {
        "$ref": "#/components/schemas/JobEvent"
    }
    event = spec["components"]["schemas"]["JobEvent"]
    assert event["properties"]["data"] == {**event["properties"]["data"], "$ref": "#/components/schemas/Job"}
    assert set(event["properties"]["type"]["enum"]) == {"job.succeeded", "job.failed", "job.cancelled"}
    for words in ("HMAC-SHA256", "{webhook-id}.{webhook-timestamp}.{body}", "whsec_", "Retry-After"):
        assert words in hook["description"], words


def test_results_are_typed_and_artifacts_named(spec: dict[str, Any]) -> None:
    from api_schemas import ARTIFACT_NAMES

    schemas = spec["components"]["schemas"]
    result = spec["paths"]["/v1/jobs/{job_id}/result"]["get"]["responses"]["200"]["content"]
    assert result["application/json"]["schema"] == {"$ref": "#/components/schemas/AnalysisResult"}
    assert (
        schemas["AnalysisResult"]["properties"]["parameters"]["$ref"] == "#/components/schemas/ParametersUsed"
    )
    overrides = schemas["ParametersUsed"]["properties"]["overrides"]
    assert overrides["$ref"] == "#/components/schemas/AnalysisParameters"
    artifact = spec["paths"]["/v1/jobs/{job_id}/artifacts/{name}"]["get"]
    name = next(p for p in artifact["parameters"] if p["name"] == "name")
    assert name["schema"]["enum"] == list(ARTIFACT_NAMES)
    files = {p["default"] for p in schemas["Artifacts"]["properties"].values() if p.get("default")}
    assert "result.json" in files
    assert files <= set(ARTIFACT_NAMES)
    listed = schemas["JobList"]["properties"]["items"]["items"]
    assert listed == {"$ref": "#/components/schemas/JobSummary"}
    assert "result" not in schemas["JobSummary"]["properties"]
    assert {"summary", "result_url", "url"} <= set(schemas["JobSummary"]["properties"])


def test_enumerations_where_the_values_are_known(spec: dict[str, Any]) -> None:
    from service.openapi import problem_types_extension

    schemas = spec["components"]["schemas"]

    def values(schema: dict[str, Any]) -> set[str]:
        for branch in schema.get("anyOf", [schema]):
            if "enum" in branch:
                return set(branch["enum"])
        raise AssertionError(f"no enumeration in {schema}")

    assert "possibly_aliased" in values(schemas["QualityFlag"]["properties"]["code"])
    assert values(schemas["QualityFlag"]["properties"]["severity"]) == {"info", "warning", "error"}
    assert "harmonic" in values(schemas["RejectedPeak"]["properties"]["evidence"])
    assert {"flow", "rendering", "done"} <= values(schemas["Job"]["properties"]["stage"])
    assert {"npz", "ros2-bag"} <= values(schemas["Clip"]["properties"]["format"])
    assert "container" in values(schemas["Clip"]["properties"]["fps_source"])
    assert "container" in values(schemas["AnalysisResult"]["properties"]["fps_source"])
    problem = schemas["Problem"]["properties"]
    assert values(problem["type"]) == {*problem_types_extension(), "about:blank"}
    assert problem["errors"]["anyOf"][0]["items"] == {"$ref": "#/components/schemas/FieldError"}


def test_discriminators_are_filled_in_and_uploads_are_binary(spec: dict[str, Any]) -> None:
    schemas = spec["components"]["schemas"]
    for name, value in (("StepReleaseExcitation", "step_release"), ("ImpulseExcitation", "impulse")):
        kind = schemas[name]["properties"]["type"]
        assert (kind["const"], kind["default"]) == (value, value)
        assert "type" in schemas[name]["required"]
    upload = spec["paths"]["/v1/clips"]["post"]["requestBody"]["content"]["multipart/form-data"]
    assert upload["encoding"]["file"]["contentType"] == "application/octet-stream"
    file = schemas["ClipUpload"]["properties"]["file"]
    assert (file["format"], file["contentMediaType"]) == ("binary", "application/octet-stream")


def test_members_a_response_always_sends_are_required(spec: dict[str, Any]) -> None:
    """Generated clients then have no 'unset' for them (a default is still sent)."""
    schemas = spec["components"]["schemas"]
    for name in ("Job", "JobSummary", "AnalysisResult", "ObjectResult", "QualityFlag", "Clip", "Stream"):
        assert set(schemas[name]["required"]) == set(schemas[name]["properties"]), name
