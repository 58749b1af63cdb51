"""Error paths over real HTTP against ``eigenscope serve``: each error is problem+json with its status."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import service_harness as h

pytestmark = [pytest.mark.integration, pytest.mark.slow]

PROBLEM = "application/problem+json"


def assert_problem(response: httpx.Response, status: int) -> dict[str, Any]:
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith(PROBLEM), response.headers
    doc: dict[str, Any] = response.json()
    assert doc["status"] == status
    assert doc["title"]
    assert doc["detail"]
    return doc


def upload_bytes(service: h.LiveService, name: str, data: bytes) -> httpx.Response:
    return service.client.post(
        "/v1/clips", files={"file": (name, io.BytesIO(data), "application/octet-stream")}
    )


def test_unknown_ids_are_404(embedded: h.LiveService) -> None:
    for path in ("/v1/jobs/nope", "/v1/clips/nope", "/v1/jobs/nope/artifacts/mask.png", "/v1/nothing"):
        assert_problem(embedded.client.get(path), 404)
    assert_problem(embedded.client.post("/v1/jobs/nope/cancel"), 404)
    assert_problem(embedded.client.delete("/v1/clips/nope"), 404)
    assert_problem(embedded.client.put("/v1/jobs"), 405)


def test_bad_clip_is_422_with_the_loaders_message(embedded: h.LiveService, tmp_path: Path) -> None:
    # An npz whose rgb has the wrong dtype: the loader's own message must come through.
    path = tmp_path / "bad.npz"
    np.savez(path, rgb=np.zeros((16, 32, 32, 3), dtype=np.float32), fps=np.float64(30))
    doc = assert_problem(embedded.upload(path), 422)
    assert "uint8" in doc["detail"]
    # A truncated archive.
    data = path.read_bytes()
    assert_problem(upload_bytes(embedded, "cut.npz", data[: len(data) // 2]), 422)
    # Too few frames.
    few = tmp_path / "few.npz"
    np.savez(few, rgb=np.zeros((3, 32, 32, 3), dtype=np.uint8), fps=np.float64(30))
    assert "frames" in assert_problem(embedded.upload(few), 422)["detail"]


def test_unknown_media_is_415(embedded: h.LiveService) -> None:
    assert_problem(upload_bytes(embedded, "notes.txt", b"this is not a clip\n" * 10), 415)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("readme.md", "no frames here")
    assert_problem(upload_bytes(embedded, "x.zip", buf.getvalue()), 415)
    # Not multipart at all.
    response = embedded.client.post("/v1/clips", content=b"raw", headers={"content-type": "application/json"})
    assert_problem(response, 415)


def test_oversize_upload_is_413(embedded: h.LiveService) -> None:
    # The fixture caps uploads at 8 MiB.
    doc = assert_problem(upload_bytes(embedded, "big.npz", b"\0" * (9 * 1024 * 1024)), 413)
    assert "8 MiB" in doc["detail"]
    leftovers = list((embedded.data_dir / "tmp").glob("upload-*"))
    assert leftovers == []


def test_missing_file_field_is_422(embedded: h.LiveService) -> None:
    response = embedded.client.post(
        "/v1/clips", files={"clip": ("a.npz", b"123", "application/octet-stream")}
    )
    doc = assert_problem(response, 422)
    assert doc["errors"][0]["loc"] == ["body", "file"]


def test_bad_job_json_and_values_are_422(embedded: h.LiveService, truth_clip: tuple[Path, Any]) -> None:
    clip_id = embedded.upload(truth_clip[0]).json()["id"]
    bad_json = embedded.client.post(
        "/v1/jobs", content=b"{not json", headers={"content-type": "application/json"}
    )
    assert_problem(bad_json, 422)
    cases = [
        {},
        {"clip_id": clip_id, "excitation": {"type": "step_release", "force_n": -1}},
        {"clip_id": clip_id, "excitation": {"type": "kick", "force_n": 1}},
        {"clip_id": clip_id, "parameters": {"frames": 4}},
        {"clip_id": clip_id, "parameters": {"method": "magic"}},
        {"clip_id": clip_id, "parameters": {"unknown_option": 1}},
        {"clip_id": clip_id, "parameters": {"frames": 1000}},
        {"clip_id": clip_id, "parameters": {"min_frequency_hz": 5, "max_frequency_hz": 2}},
    ]
    for body in cases:
        doc = assert_problem(embedded.client.post("/v1/jobs", json=body), 422)
        assert doc["errors"], body
    bad_status = embedded.client.get("/v1/jobs", params={"status": "sleeping"})
    assert_problem(bad_status, 422)
    assert_problem(embedded.client.get("/v1/jobs", params={"cursor": "garbage!"}), 422)


def test_job_on_deleted_clip_and_delete_rules(embedded: h.LiveService, truth_clip: tuple[Path, Any]) -> None:
    clip_id = embedded.upload(truth_clip[0]).json()["id"]
    assert embedded.client.get(f"/v1/clips/{clip_id}").status_code == 200
    assert embedded.client.delete(f"/v1/clips/{clip_id}").status_code == 204
    assert_problem(embedded.client.get(f"/v1/clips/{clip_id}"), 404)
    assert_problem(embedded.client.delete(f"/v1/clips/{clip_id}"), 404)
    doc = assert_problem(embedded.client.post("/v1/jobs", json={"clip_id": clip_id}), 422)
    assert "does not exist" in doc["detail"]


def test_cancel_finished_job_is_409(embedded: h.LiveService, truth_clip: tuple[Path, Any]) -> None:
    clip_id = embedded.upload(truth_clip[0]).json()["id"]
    job_id = embedded.client.post("/v1/jobs", json={"clip_id": clip_id}).json()["id"]
    job = embedded.wait_job(job_id)
    assert job["status"] == "succeeded", job
    doc = assert_problem(embedded.client.post(f"/v1/jobs/{job_id}/cancel"), 409)
    assert "succeeded" in doc["detail"]
    assert embedded.client.get(f"/v1/jobs/{job_id}").json()["status"] == "succeeded"
    assert_problem(embedded.client.get(f"/v1/jobs/{job_id}/artifacts/../result.json"), 404)
    assert_problem(embedded.client.get(f"/v1/jobs/{job_id}/artifacts/nope.png"), 404)
    # A finished job's clip may be deleted; the job keeps its result and artifacts.
    assert embedded.client.delete(f"/v1/clips/{clip_id}").status_code == 204
    assert embedded.client.get(f"/v1/jobs/{job_id}/artifacts/mask.png").status_code == 200


def test_idempotency_key(embedded: h.LiveService, truth_clip: tuple[Path, Any]) -> None:
    clip_id = embedded.upload(truth_clip[0]).json()["id"]
    body = {"clip_id": clip_id, "excitation": {"type": "impulse", "impulse_ns": 0.2}}
    headers = {"Idempotency-Key": "retry-me-1"}
    first = embedded.client.post("/v1/jobs", json=body, headers=headers)
    second = embedded.client.post("/v1/jobs", json=body, headers=headers)
    assert first.status_code == second.status_code == 202
    assert first.json()["id"] == second.json()["id"]
    other = dict(body, excitation={"type": "impulse", "impulse_ns": 0.3})
    assert (
        "Idempotency-Key"
        in assert_problem(embedded.client.post("/v1/jobs", json=other, headers=headers), 422)["detail"]
    )
    embedded.wait_job(first.json()["id"])


def test_listing_is_newest_first_with_cursor_and_filter(
    embedded: h.LiveService, truth_clip: tuple[Path, Any]
) -> None:
    clip_id = embedded.upload(truth_clip[0]).json()["id"]
    ids = [embedded.client.post("/v1/jobs", json={"clip_id": clip_id}).json()["id"] for _ in range(3)]
    for job_id in ids:
        embedded.wait_job(job_id)
    page1 = embedded.client.get("/v1/jobs", params={"limit": 2, "clip_id": clip_id}).json()
    assert [j["id"] for j in page1["items"]] == ids[::-1][:2]
    page2 = embedded.client.get(
        "/v1/jobs", params={"limit": 2, "clip_id": clip_id, "cursor": page1["next_cursor"]}
    )
    assert [j["id"] for j in page2.json()["items"]] == ids[:1]
    assert page2.json()["next_cursor"] is None
    done = embedded.client.get("/v1/jobs", params={"status": ["succeeded"], "clip_id": clip_id}).json()
    assert {j["id"] for j in done["items"]} == set(ids)
    assert (
        embedded.client.get("/v1/jobs", params={"status": "queued", "clip_id": clip_id}).json()["items"] == []
    )


def test_health_ready_metrics(embedded: h.LiveService) -> None:
    assert embedded.client.get("/healthz").json()["status"] == "ok"
    ready = embedded.client.get("/readyz").json()
    assert ready["checks"] == {"database": "ok", "broker": "ok", "storage": "ok"}
    metrics = embedded.client.get("/metrics")
    assert metrics.status_code == 200
    assert "eigenscope_http_requests_total" in metrics.text
    assert 'eigenscope_jobs{status="succeeded"}' in metrics.text
