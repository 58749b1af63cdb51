"""What an operator sees: metrics that add up across two API processes and include the worker's, workers on
their own exposing their own, request ids, job ids on worker lines, JSON logs, and quiet start-up."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import service_harness as h
from eigenscope_client import Client, StepRelease

pytestmark = [
    pytest.mark.integration,
    pytest.mark.xdist_group("shared-redis"),  # uses the Redis test database, which the harness flushes
    pytest.mark.slow,
    pytest.mark.timeout(300),
]


def metric(text: str, name: str, **labels: str) -> float | None:
    """The value of one sample in Prometheus text, or None when absent."""
    for line in text.splitlines():
        if line.startswith("#") or not line.startswith(name):
            continue
        series, _, value = line.rpartition(" ")
        head, _, rest = series.partition("{")
        if head != name:
            continue
        found = dict(re.findall(r'(\w+)="([^"]*)"', rest))
        if all(found.get(k) == v for k, v in labels.items()):
            return float(value)
    return None


@pytest.fixture(scope="module")
def two_apis(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    """``eigenscope serve --api-workers 2`` with one analysis worker."""
    service = h.start_embedded(tmp_path_factory.mktemp("ops"), api_workers=2)
    yield service
    service.stop()


def test_every_metric_family_is_there_from_the_start(two_apis: h.LiveService) -> None:
    """Before any job, upload or stream: every family the API and its worker declare is in the scrape."""
    from backend.metrics import WORKER_FAMILIES
    from service.metrics import API_FAMILIES

    text = httpx.get(f"{two_apis.base_url}/metrics").text
    declared = {
        line.split()[2].removesuffix("_total") for line in text.splitlines() if line.startswith("# TYPE ")
    }
    missing = {f.name for f in API_FAMILIES + WORKER_FAMILIES} - declared
    assert not missing, missing
    assert metric(text, "eigenscope_jobs_created_total") == 0
    assert metric(text, "eigenscope_stream_result_latency_seconds_count") == 0


def test_counters_add_up_across_two_api_processes(two_apis: h.LiveService) -> None:
    url = two_apis.base_url
    processes = h.children_of(two_apis.procs[0].pid)
    uvicorn = [p for p in processes if h.children_of(p)]  # the API parent; its children serve
    assert any(len(h.children_of(p)) >= 2 for p in uvicorn), "two API processes expected"
    before = metric(httpx.get(f"{url}/metrics").text, "eigenscope_http_requests_total", route="/healthz") or 0
    for _ in range(20):
        assert httpx.get(f"{url}/healthz", headers={"Connection": "close"}).status_code == 200
    seen = set()
    for _ in range(8):  # a new connection each: the scrapes land on either process
        text = httpx.get(f"{url}/metrics", headers={"Connection": "close"}).text
        seen.add(metric(text, "eigenscope_http_requests_total", route="/healthz", status="200"))
    assert seen == {before + 20}


def test_job_metrics_and_logs(two_apis: h.LiveService, truth_clip: tuple[Path, Any]) -> None:
    with Client(two_apis.base_url) as client:
        clip = client.upload_clip(truth_clip[0])
        ok = client.wait(client.create_job(clip.id, excitation=StepRelease(force_n=5.0)), timeout=180)
        assert ok.status == "succeeded"
        gone = client.upload_clip(truth_clip[0])
        for file in (two_apis.data_dir / "clips" / gone.id).iterdir():
            file.unlink()
        failed = client.wait(client.create_job(gone.id), timeout=120)
        assert failed.status == "failed"
        text = client.metrics()
    assert metric(text, "eigenscope_job_duration_seconds_count", outcome="succeeded") == 1
    assert metric(text, "eigenscope_job_duration_seconds_count", outcome="failed") == 1
    assert metric(text, "eigenscope_job_queue_wait_seconds_count") == 2
    assert metric(text, "eigenscope_job_failures_total", type="clip-gone") == 1
    assert metric(text, "eigenscope_job_retries_total") == 0
    for stage in ok.result.timings_s if ok.result else ():
        assert metric(text, "eigenscope_analysis_stage_seconds_count", stage=stage) == 1, stage
    assert metric(text, "eigenscope_worker_processes") == 1
    assert metric(text, "eigenscope_worker_busy") == 0
    assert metric(text, "eigenscope_jobs", status="succeeded") == 1
    assert metric(text, "eigenscope_build_info", component="api") == 1
    # The worker's lines name the job; the API's carry the request id.
    log = "\n".join(p.log_path.read_text(errors="replace") for p in two_apis.procs)
    assert re.search(rf"job {ok.id}: attempt 1 started .*\[job_id={ok.id}\]", log)
    assert re.search(rf"job {ok.id}: attempt 1 succeeded in .*\[job_id={ok.id}\]", log)
    assert re.search(rf"Task eigenscope\.run_job\[{ok.id}-\w+\] received", log)
    assert re.search(rf"job {failed.id}: attempt 1 failed \(clip-gone\)", log)


def test_streams_are_counted_like_jobs_and_have_metrics_of_their_own(two_apis: h.LiveService) -> None:
    """A stream is a job in the worker metrics (its duration, queue wait, stages; a failed one in the
    failures), and the relay counts sessions, frame messages in and dropped, and the latency to the result."""
    from eigenscope_client import StreamError, StreamSession
    from stream_helpers import scene_frames, send_scene, session_kwargs

    url = two_apis.base_url
    before = httpx.get(f"{url}/metrics").text
    done = metric(before, "eigenscope_job_duration_seconds_count", outcome="succeeded") or 0
    failed = metric(before, "eigenscope_job_failures_total", type="analysis-failed") or 0
    scene = scene_frames(frames=40)
    with StreamSession(url, **session_kwargs(scene)) as session:
        send_scene(session, scene)
        session.finish(timeout_s=120)
    with StreamSession(url, **session_kwargs(scene)) as empty, pytest.raises(StreamError):
        empty.finish(timeout_s=60)  # no frame at all: the analysis fails
    with Client(url) as client:
        client.wait(client.get_job(session.job_id), timeout=60)
        client.wait(client.get_job(empty.job_id), timeout=60)
    text = httpx.get(f"{url}/metrics").text
    assert metric(text, "eigenscope_job_duration_seconds_count", outcome="succeeded") == done + 1
    assert metric(text, "eigenscope_job_failures_total", type="analysis-failed") == failed + 1
    assert metric(text, "eigenscope_analysis_stage_seconds_count", stage="spectrum")
    assert metric(text, "eigenscope_stream_frames_received_total") == 2 * len(scene.frames)
    assert metric(text, "eigenscope_stream_sessions") == 0
    assert metric(text, "eigenscope_stream_result_latency_seconds_count") == 1


def test_request_ids(two_apis: h.LiveService, truth_clip: tuple[Path, Any]) -> None:
    url = two_apis.base_url
    with truth_clip[0].open("rb") as fh:
        upload = httpx.post(
            f"{url}/v1/clips", files={"file": ("c.npz", fh)}, headers={"X-Request-ID": "robot-7.upload-42"}
        )
    assert upload.status_code == 201
    assert upload.headers["x-request-id"] == "robot-7.upload-42"
    made_up = httpx.get(f"{url}/v1/jobs/nope", headers={"X-Request-ID": "bad id; DROP"})
    assert made_up.status_code == 404
    assert re.fullmatch(r"[0-9a-f]{32}", made_up.headers["x-request-id"])
    clip_id = upload.json()["id"]
    deadline = time.monotonic() + 10
    while True:
        log = two_apis.procs[0].log_path.read_text(errors="replace")
        if f"clip {clip_id}" in log:
            break
        assert time.monotonic() < deadline, log[-3000:]
        time.sleep(0.1)
    line = next(x for x in log.splitlines() if f"clip {clip_id}" in x)
    assert "INFO service.clips" in line  # the app's own INFO lines are shown
    assert line.endswith("[request_id=robot-7.upload-42]")
    assert re.search(r"POST /v1/clips 201 .*\[request_id=robot-7\.upload-42\]", log)


def test_start_up_shows_no_banner_and_no_library_warning(two_apis: h.LiveService) -> None:
    log = two_apis.procs[0].log_path.read_text(errors="replace")
    assert "eigenscope serving on" in log
    assert "eigenscope API ready" in log
    for noise in ("-------------- celery@", "[config]", "SecurityWarning", "superuser", "Uvicorn running on"):
        assert noise not in log, noise


def test_split_deployment_json_logs_and_worker_metrics(tmp_path: Path, truth_clip: tuple[Path, Any]) -> None:
    """API and worker started apart (Redis broker), JSON logs; the worker serves its own metrics."""
    port = h.free_port()
    service = h.start_split(
        tmp_path, redis_url=h.redis_url(), log_format="json", worker_metrics_port=str(port)
    )
    try:
        with Client(service.base_url) as client:
            job = client.analyze(truth_clip[0], excitation=StepRelease(force_n=5.0), timeout=180)
        assert job.status == "succeeded"
        worker_metrics = httpx.get(f"http://127.0.0.1:{port}/metrics").text
        assert metric(worker_metrics, "eigenscope_job_duration_seconds_count", outcome="succeeded") == 1
        assert metric(worker_metrics, "eigenscope_worker_processes") == 1
        assert metric(worker_metrics, "eigenscope_build_info", component="worker") == 1
        api_metrics = httpx.get(f"{service.base_url}/metrics").text
        assert metric(api_metrics, "eigenscope_job_duration_seconds_count", outcome="succeeded") is None
        time.sleep(0.5)  # the last lines reach the files
        records = []
        for proc in service.procs:
            for line in proc.log_path.read_text(errors="replace").splitlines():
                if line.strip():
                    records.append(json.loads(line))  # every line is one JSON object
        assert all({"time", "level", "logger", "message"} <= set(r) for r in records)
        mine = [r for r in records if r.get("job_id") == job.id]
        assert any(r["message"].startswith(f"job {job.id}: attempt 1 succeeded") for r in mine)
        assert any(r["logger"] == "service.access" and r.get("request_id") for r in records)
    finally:
        service.stop()


def test_json_logs_are_json_on_every_line_and_carry_the_trace(
    tmp_path: Path, truth_clip: tuple[Path, Any]
) -> None:
    """``eigenscope serve`` in JSON mode: every line it and its children write is one JSON object (the
    start-up line and Celery's shutdown too); the access log is fields; a job carries the W3C trace of the
    request that created it to the worker's lines."""
    trace_id, parent = "4bf92f3577b34da6a3ce929d0e0e4736", "00f067aa0ba902b7"
    service = h.start_embedded(tmp_path, log_format="json")
    try:
        with truth_clip[0].open("rb") as fh:
            clip = httpx.post(f"{service.base_url}/v1/clips", files={"file": ("c.npz", fh)}).json()
        created = httpx.post(
            f"{service.base_url}/v1/jobs",
            json={"clip_id": clip["id"], "excitation": {"type": "step_release", "force_n": 5.0}},
            headers={"traceparent": f"00-{trace_id}-{parent}-01"},
        )
        assert created.status_code == 202
        job = created.json()
        with Client(service.base_url) as client:
            assert client.wait(client.get_job(job["id"]), timeout=180).status == "succeeded"
    finally:
        # A graceful stop, not the harness's kill: the shutdown lines are part of what is checked.
        for proc in reversed(service.procs):
            proc.stop(grace_s=15)
        service.stop()
    records = []
    for proc in service.procs:
        for line in proc.log_path.read_text(errors="replace").splitlines():
            if line.strip():
                records.append(json.loads(line))  # every line is one JSON object
    messages = [r["message"] for r in records]
    assert any(m.startswith("eigenscope serving on") for m in messages)
    assert any("shutdown" in m.lower() for m in messages), "Celery's shutdown line, as JSON"
    access = [r for r in records if r["logger"] == "service.access" and r.get("path") == "/v1/jobs"]
    assert access, "the access log of POST /v1/jobs"
    assert {"method", "path", "route", "status", "duration_ms"} <= set(access[0])
    assert (access[0]["method"], access[0]["route"], access[0]["status"]) == ("POST", "/v1/jobs", 202)
    assert access[0]["trace_id"] == trace_id
    worker = [r for r in records if r.get("job_id") == job["id"] and r["logger"].startswith("workers")]
    assert worker, "the worker's lines about the job"
    assert {r.get("trace_id") for r in worker} == {trace_id}
