"""A force log sent with a job request (issue 31): taken with the job and stored apart from its record,
shown as a summary (never its samples), refused at the request with a problem naming the field when it
cannot work, and a job request's body limit that lets a realistic log through."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from api_schemas import ForceLog, JobCreate
from api_schemas.parameters import MAX_FORCE_NUMBER_BYTES, MAX_FORCE_SAMPLES
from backend.settings import Settings
from tests.unit.service.helpers import RecordingQueue, make_client, upload

RATE_HZ = 500.0


def push_log(seconds: float = 0.6, *, start_s: float = -0.1, components: bool = True) -> dict[str, Any]:
    """A push held at 6 N and let go half-way, sampled at 500 Hz, as JSON columns."""
    n = round(seconds * RATE_HZ)
    times = [start_s + i / RATE_HZ for i in range(n)]
    force = [6.0 if i < n // 2 else 0.0 for i in range(n)]
    if not components:
        return {"time_s": times, "force_n": force, "name": "push.csv"}
    return {"time_s": times, "fx": force, "fy": [0.1] * n, "fz": [-0.2] * n, "name": "push.csv"}


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with make_client(settings, RecordingQueue()) as c:
        yield c


@pytest.fixture
def clip_id(client: TestClient, small_clip: Path) -> str:
    """A clip of 16 frames at 25 fps: its frames span 0 s to 0.6 s."""
    response = upload(client, small_clip)
    assert response.status_code == 201, response.text
    return str(response.json()["id"])


def post(client: TestClient, body: dict[str, Any] | str, **headers: str) -> Any:
    content = body if isinstance(body, str) else json.dumps(body)
    return client.post("/v1/jobs", content=content, headers={"content-type": "application/json", **headers})


def refusal(response: Any) -> dict[str, Any]:
    """The one field error of a 422 problem document."""
    assert response.status_code == 422, response.text
    assert response.headers["content-type"] == "application/problem+json"
    doc: dict[str, Any] = response.json()
    assert doc["status"] == 422
    assert doc["errors"], doc
    error: dict[str, Any] = doc["errors"][0]
    assert error["msg"] in doc["detail"]
    return error


def test_a_job_takes_a_force_log_and_shows_its_summary(client: TestClient, clip_id: str) -> None:
    log = push_log()
    created = post(client, {"clip_id": clip_id, "force_log": {**log, "offset_s": 0.05, "frame_id": "ft"}})
    assert created.status_code == 202, created.text
    job = created.json()
    summary = {
        "name": "push.csv",
        "samples": 300,
        "start_s": pytest.approx(-0.05),
        "end_s": pytest.approx(-0.1 + 299 / RATE_HZ + 0.05),
        "columns": ["fx", "fy", "fz"],
        "frame_id": "ft",
    }
    assert job["force_log"] == summary
    assert job["excitation"] is None
    # Polls and lists show the summary, never the samples.
    polled = client.get(f"/v1/jobs/{job['id']}")
    assert polled.json()["force_log"] == summary
    assert len(polled.content) < 2000
    assert client.get("/v1/jobs").json()["items"][0]["force_log"] == summary
    # The log itself is stored whole, apart from the record, for the worker.
    store = client.app.state.ctx.store  # type: ignore[attr-defined]
    stored = store.job_force_log(job["id"])
    assert ForceLog.model_validate(stored) == ForceLog.model_validate(
        {**log, "offset_s": 0.05, "frame_id": "ft"}
    )
    # A job without one has none.
    plain = post(client, {"clip_id": clip_id})
    assert plain.json()["force_log"] is None
    assert store.job_force_log(plain.json()["id"]) is None


def test_the_idempotency_key_covers_the_force_log(client: TestClient, clip_id: str) -> None:
    body = {"clip_id": clip_id, "force_log": push_log(components=False)}
    first = post(client, body, **{"Idempotency-Key": "k1"})
    again = post(client, body, **{"Idempotency-Key": "k1"})
    assert first.status_code == again.status_code == 202
    assert again.headers["idempotent-replayed"] == "true"
    assert again.json()["id"] == first.json()["id"]
    other = {**body, "force_log": {**body["force_log"], "offset_s": 0.01}}
    reused = post(client, other, **{"Idempotency-Key": "k1"})
    assert reused.status_code == 422
    assert reused.json()["type"].endswith("/idempotency-key-reused")


@pytest.mark.parametrize(
    ("change", "loc", "words"),
    [
        (lambda log: log["time_s"].__setitem__(7, log["time_s"][5]), ["time_s"], ["time_s[7]", "sort"]),
        (lambda log: log["time_s"].__setitem__(9, log["time_s"][8]), ["time_s"], ["repeats", "drop"]),
        (lambda log: log["fy"].pop(), ["fy"], ["fy has 299 values but time_s has 300"]),
        (lambda log: log.update(force_n=log["fx"]), [], ["not both"]),
        (lambda log: log.pop("fz"), [], ["all three of fx, fy and fz"]),
        (
            lambda log: log.update(time_s=log["time_s"][:5], fx=[1] * 5, fy=[1] * 5, fz=[1] * 5),
            ["time_s"],
            [],
        ),
        (lambda log: log.update(speed=[1.0]), ["speed"], ["not a field"]),
        (lambda log: log.update(offset_s=-1e9), ["offset_s"], ["offset_s to minus the log's time"]),
        (lambda log: log.update(time_s=[t + 1.7e9 for t in log["time_s"]]), ["offset_s"], ["clock"]),
    ],
    ids=[
        "backwards",
        "repeated",
        "a-short-column",
        "both-forms",
        "two-components",
        "too-few",
        "unknown",
        "offset-off-the-clip",
        "another-clock",
    ],
)
def test_a_log_that_cannot_work_is_refused_at_the_request(
    client: TestClient, clip_id: str, change: Any, loc: list[str], words: list[str]
) -> None:
    log = push_log()
    change(log)
    error = refusal(post(client, {"clip_id": clip_id, "force_log": log}))
    assert error["loc"] == ["body", "force_log", *loc]
    for word in words:
        assert word in error["msg"]
    assert client.get("/v1/jobs").json()["items"] == []


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e400"])
def test_a_non_finite_value_is_refused_naming_its_sample(
    client: TestClient, clip_id: str, token: str
) -> None:
    log = push_log()
    log["fy"][3] = "__NOT_A_NUMBER__"
    text = json.dumps({"clip_id": clip_id, "force_log": log}).replace('"__NOT_A_NUMBER__"', token)
    response = post(client, text)
    error = refusal(response)
    assert error["loc"] == ["body", "force_log", "fy", 3]
    assert "finite" in error["msg"]
    assert response.json()["detail"].startswith("force_log.fy[3]: ")


def test_too_many_samples_are_refused_and_so_is_a_body_over_the_jobs_cap(
    tmp_path: Path, small_clip: Path
) -> None:
    settings = Settings(data_dir=tmp_path / "data", max_job_body_kb=8 * 1024)
    with make_client(settings) as client:
        clip = upload(client, small_clip).json()["id"]
        n = MAX_FORCE_SAMPLES + 1
        log = {"time_s": list(range(n)), "force_n": [0] * n}
        error = refusal(post(client, {"clip_id": clip, "force_log": log}))
        assert error["loc"] == ["body", "force_log", "time_s"]
        assert f"at most {MAX_FORCE_SAMPLES}" in error["msg"]
        # Past the job request's own cap: 413, as a problem, before the body is parsed.
        big = json.dumps({"clip_id": clip, "force_log": {"time_s": [0.123456789] * (1 << 20)}})
        response = post(client, big)
        assert response.status_code == 413
        assert response.headers["content-type"] == "application/problem+json"
        assert response.json()["type"].endswith("/body-too-large")
        assert "EIGENSCOPE_MAX_JOB_BODY_KB" in response.json()["detail"]


def test_the_default_job_cap_takes_the_largest_log_at_full_precision() -> None:
    """200,000 samples of time and three components, every number as long as a float's text gets (and
    separated by ", " as Python's json.dumps does) fit the default cap of a job request; the cap of the
    other routes stays 1 MiB."""
    settings = Settings(data_dir=Path("/nonexistent"))
    widest = json.dumps(-2.2250738585072014e-308)  # as long as a float's text gets: 24 characters
    assert len(widest) == 24
    assert len(widest + ", ") <= MAX_FORCE_NUMBER_BYTES
    column = MAX_FORCE_SAMPLES * MAX_FORCE_NUMBER_BYTES
    rest = len(json.dumps({"clip_id": "c" * 64, "force_log": {"time_s": [], "fx": [], "fy": [], "fz": []}}))
    assert 4 * column + rest + 64 * 1024 <= settings.max_job_body_bytes
    assert settings.max_json_body_bytes == 1024 * 1024


def test_a_realistic_log_goes_through(client: TestClient, settings: Settings, small_clip: Path) -> None:
    """500 Hz for a minute, three components at full precision (2 MB of JSON, past the cap of the other
    routes): taken."""
    clip = upload(client, small_clip).json()["id"]
    n = round(60 * RATE_HZ)
    log = {
        "time_s": [i / RATE_HZ - 0.5 for i in range(n)],
        **{
            k: [math.sin(i * (j + 1) * 0.01) * 3.3 for i in range(n)]
            for j, k in enumerate(("fx", "fy", "fz"))
        },
    }
    body = json.dumps({"clip_id": clip, "force_log": log})
    assert len(body) > 1.5 * settings.max_json_body_bytes
    started = time.monotonic()
    response = post(client, body)
    assert response.status_code == 202, response.text[:500]
    assert response.json()["force_log"]["samples"] == n
    print(f"\nFORCE LOG {len(body) / 2**20:.1f} MiB taken in {time.monotonic() - started:.2f} s")


def test_a_log_of_many_bad_values_is_refused_with_a_bounded_problem(client: TestClient, clip_id: str) -> None:
    """Every value wrong: one error per field up to a bound, and a detail that says there are more."""
    n = 20_000
    error_doc = post(client, {"clip_id": clip_id, "force_log": {"time_s": ["x"] * n, "force_n": [0] * n}})
    assert error_doc.status_code == 422
    doc = error_doc.json()
    assert 1 <= len(doc["errors"]) <= 50
    assert doc["errors"][0]["loc"] == ["body", "force_log", "time_s", 0]
    assert "more)" in doc["detail"]


def test_the_request_model_refuses_what_the_api_does() -> None:
    """The same checks for every caller of the model (the command line's analyze builds one too)."""
    log = push_log()
    assert JobCreate.model_validate({"clip_id": "c", "force_log": log}).force_log is not None
    log["time_s"][3] = float("nan")
    with pytest.raises(ValueError, match="finite"):
        ForceLog.model_validate(log)
