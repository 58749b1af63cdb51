"""The HTTP API in-process (TestClient) with a recording queue instead of a broker."""

from __future__ import annotations

import io
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.settings import Settings
from tests.unit.service.helpers import RecordingQueue, finish, make_client
from tests.unit.service.helpers import upload as upload_response


@pytest.fixture
def queue() -> RecordingQueue:
    return RecordingQueue()


@pytest.fixture
def client(settings: Settings, queue: RecordingQueue) -> Iterator[TestClient]:
    with make_client(settings, queue) as c:
        yield c


def upload(client: TestClient, path: Path) -> dict:
    response = upload_response(client, path)
    assert response.status_code == 201, response.text
    return response.json()


def test_upload_describes_the_clip(client: TestClient, small_clip: Path) -> None:
    with small_clip.open("rb") as fh:
        response = client.post("/v1/clips", files={"file": ("small.npz", fh)})
    assert response.status_code == 201
    clip = response.json()
    assert response.headers["location"] == f"/v1/clips/{clip['id']}"
    assert (clip["format"], clip["frames"], clip["width"], clip["height"], clip["fps"]) == (
        "npz",
        16,
        48,
        32,
        25.0,
    )
    assert clip["intrinsics"] == {"fx": 40.0, "fy": 40.0, "cx": 24.0, "cy": 16.0}
    assert clip["has_depth"] is False
    assert clip["size_bytes"] == small_clip.stat().st_size
    assert clip["duration_s"] == pytest.approx(16 / 25)
    assert client.get(f"/v1/clips/{clip['id']}").json() == clip


def test_job_create_publishes_and_rewrites_artifacts(
    client: TestClient, small_clip: Path, queue: RecordingQueue
) -> None:
    clip = upload(client, small_clip)
    response = client.post("/v1/jobs", json={"clip_id": clip["id"], "excitation": None})
    assert response.status_code == 202
    job = response.json()
    assert queue.published == [job["id"]]
    assert response.headers["retry-after"] == "1"
    assert job["status"] == "queued"
    assert job["attempts"] == 0
    assert job["progress"] == 0
    # Finish it by hand and check how the API serves the result.
    finish(client, job["id"])
    done = client.get(f"/v1/jobs/{job['id']}")
    assert "retry-after" not in done.headers
    url = done.json()["result"]["artifacts"]["mask"]
    assert url == f"/v1/jobs/{job['id']}/artifacts/mask.png"
    mask = client.get(url)
    assert mask.status_code == 200
    assert mask.headers["content-type"] == "image/png"


def test_publish_failure_leaves_the_job_for_the_sweeper(
    client: TestClient, small_clip: Path, queue: RecordingQueue
) -> None:
    clip = upload(client, small_clip)
    queue.fail = True
    response = client.post("/v1/jobs", json={"clip_id": clip["id"]})
    assert response.status_code == 202
    assert client.get("/readyz").status_code == 503
    queue.fail = False
    ctx = client.app.state.ctx  # type: ignore[attr-defined]
    assert ctx.sweep() == [response.json()["id"]]


def test_fps_is_required_when_the_clip_has_none(client: TestClient, tmp_path: Path) -> None:
    import numpy as np

    path = tmp_path / "nofps.npz"
    np.savez(path, rgb=np.zeros((16, 32, 32, 3), dtype=np.uint8))
    clip = upload(client, path)
    assert clip["fps"] is None
    missing = client.post("/v1/jobs", json={"clip_id": clip["id"]})
    assert missing.status_code == 422
    assert missing.json()["errors"][0]["loc"] == ["body", "parameters", "fps"]
    ok = client.post("/v1/jobs", json={"clip_id": clip["id"], "parameters": {"fps": 30}})
    assert ok.status_code == 202


def test_a_window_shorter_than_the_pipeline_analyses_is_refused_at_the_request(
    client: TestClient, small_clip: Path
) -> None:
    """The request's least window is the pipeline's: 10 frames are refused with the field and the bound
    (they were accepted from 8, and the job failed inside the worker); 16 are taken."""
    from api_schemas.parameters import MIN_WINDOW_FRAMES
    from workers.pipeline.clipio.types import MIN_FRAMES

    assert MIN_WINDOW_FRAMES == MIN_FRAMES
    clip = upload(client, small_clip)
    short = client.post("/v1/jobs", json={"clip_id": clip["id"], "parameters": {"frames": MIN_FRAMES - 1}})
    assert short.status_code == 422
    error = short.json()["errors"][0]
    assert error["loc"] == ["body", "parameters", "frames"]
    assert str(MIN_FRAMES) in error["msg"]
    ok = client.post("/v1/jobs", json={"clip_id": clip["id"], "parameters": {"frames": MIN_FRAMES}})
    assert ok.status_code == 202


def test_an_empty_band_is_refused_by_the_request_schema_for_jobs_and_streams(
    client: TestClient, small_clip: Path
) -> None:
    """The band has one check (AnalysisParameters): a job and a stream both answer 422 on the field."""
    clip = upload(client, small_clip)
    band = {"fps": 30, "min_frequency_hz": 5, "max_frequency_hz": 5}
    job = client.post("/v1/jobs", json={"clip_id": clip["id"], "parameters": band})
    stream = client.post("/v1/streams", json={"parameters": band})
    for response in (job, stream):
        assert response.status_code == 422, response.text
        error = response.json()["errors"][0]
        assert error["loc"][-1] == "max_frequency_hz"
        assert "must exceed min_frequency_hz=5" in error["msg"]
    ok = client.post("/v1/jobs", json={"clip_id": clip["id"], "parameters": {**band, "max_frequency_hz": 6}})
    assert ok.status_code == 202


def test_errors_are_problem_json(client: TestClient) -> None:
    for response, status in (
        (client.get("/v1/jobs/x"), 404),
        (client.post("/v1/jobs", json={"clip_id": ""}), 422),
        (client.post("/v1/clips", content=b"x", headers={"content-type": "text/plain"}), 415),
        (client.post("/v1/clips", files={"file": ("a.bin", io.BytesIO(b"\0" * (2 << 20)))}), 413),
        (client.patch("/v1/jobs"), 405),
    ):
        assert response.status_code == status
        assert response.headers["content-type"] == "application/problem+json"
        assert response.json()["status"] == status


def test_settings_defaults_and_validation(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("EIGENSCOPE_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("EIGENSCOPE_REDIS_URL", "")
    s = Settings()
    assert s.embedded
    assert s.max_upload_mb == 2048
    assert s.effective_database_url == f"sqlite:///{tmp_path / 'eigenscope.db'}"
    assert s.effective_visibility_timeout_s > s.task_hard_time_limit_s
    monkeypatch.setenv("EIGENSCOPE_REDIS_URL", "redis://h:6379/1")
    assert not Settings().embedded
    with pytest.raises(ValueError, match="must exceed"):
        Settings(task_soft_time_limit_s=100, task_hard_time_limit_s=50)
    with pytest.raises(ValueError, match="delivered twice"):
        Settings(visibility_timeout_s=10)
