"""Reliability with real processes: a worker killed mid-job, cancelling a running job, clean shutdown,
and the API process never loading the pipeline."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import service_harness as h

pytestmark = [pytest.mark.integration, pytest.mark.slow]

#: Farnebäck flow on 128 frames of 320x240 takes a few seconds (2.6 s for `eigenscope analyze` here): long
#: enough to kill or cancel the job while it runs (the tests wait for its first stage, polling every 20 ms).
SLOW_PARAMETERS = {"flow": "farneback"}


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    svc = h.start_embedded(tmp_path_factory.mktemp("reliability"), lease_s="6")
    yield svc
    svc.stop()


@pytest.fixture(scope="module")
def slow_clip_id(service: h.LiveService, tmp_path_factory: pytest.TempPathFactory) -> str:
    path = tmp_path_factory.mktemp("slow") / "slow.npz"
    h.synth_clip(path, frames=128, width=320, height=240, frequency_hz=5.0, seed=3)
    response = service.upload(path)
    assert response.status_code == 201, response.text
    clip_id: str = response.json()["id"]
    return clip_id


def descendants(pid: int) -> list[int]:
    found, todo = [], [pid]
    while todo:
        for child in h.children_of(todo.pop()):
            found.append(child)
            todo.append(child)
    return found


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def wait_running(service: h.LiveService, job_id: str, timeout_s: float = 30.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job: dict[str, Any] = service.client.get(f"/v1/jobs/{job_id}").json()
        if job["status"] == "running" and job["stage"] not in ("starting", None):
            return job
        assert job["status"] in ("queued", "running"), job
        time.sleep(0.02)
    raise AssertionError(f"job {job_id} did not start running:\n{service.logs()}")


def test_job_whose_worker_dies_is_run_again(service: h.LiveService, slow_clip_id: str) -> None:
    job_id = service.client.post(
        "/v1/jobs", json={"clip_id": slow_clip_id, "parameters": SLOW_PARAMETERS}
    ).json()["id"]
    wait_running(service, job_id)
    serve_pid = service.procs[0].pid
    workers = [p for p in h.children_of(serve_pid) if "eigenscope worker" in cmdline(p)]
    assert len(workers) == 1, [cmdline(p) for p in h.children_of(serve_pid)]
    pool = h.children_of(workers[0])
    assert pool, "the Celery worker has no pool process"
    for pid in pool:
        os.kill(pid, signal.SIGKILL)  # the process running the analysis dies without a word
    job = service.wait_job(job_id, timeout_s=120)
    assert job["status"] == "succeeded", (job, service.logs())
    assert job["attempts"] == 2
    assert job["result"]["eigenfrequency_hz"] == pytest.approx(5.0, rel=0.02)


def test_cancel_running_job(service: h.LiveService, slow_clip_id: str, truth_clip: tuple[Path, Any]) -> None:
    job_id = service.client.post(
        "/v1/jobs", json={"clip_id": slow_clip_id, "parameters": SLOW_PARAMETERS}
    ).json()["id"]
    wait_running(service, job_id)
    cancelled = service.client.post(f"/v1/jobs/{job_id}/cancel")
    assert cancelled.status_code == 200
    assert cancelled.json()["status"] == "cancelled"
    assert cancelled.json()["finished_at"] is not None
    # Cancelling again is harmless; the record stays cancelled after the worker notices.
    assert service.client.post(f"/v1/jobs/{job_id}/cancel").json()["status"] == "cancelled"
    # The worker is freed: a new small job gets done.
    clip_id = service.upload(truth_clip[0]).json()["id"]
    follow_up = service.client.post("/v1/jobs", json={"clip_id": clip_id}).json()["id"]
    assert service.wait_job(follow_up, timeout_s=60)["status"] == "succeeded"
    job = service.client.get(f"/v1/jobs/{job_id}").json()
    assert job["status"] == "cancelled"
    assert job["result"] is None
    assert service.client.get(f"/v1/jobs/{job_id}/artifacts/mask.png").status_code == 404


def test_serve_stops_all_children_on_sigterm(tmp_path: Path) -> None:
    svc = h.start_embedded(tmp_path)
    try:
        serve = svc.procs[0]
        deadline = time.monotonic() + 30
        while len(family := descendants(serve.pid)) < 3 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(family) >= 3, family  # uvicorn, celery main, celery pool
        serve.popen.send_signal(signal.SIGTERM)
        assert serve.popen.wait(timeout=30) == 0
        time.sleep(0.5)
        alive = [p for p in family if Path(f"/proc/{p}").exists() and "zombie" not in _state(p)]
        assert alive == [], [cmdline(p) for p in alive]
    finally:
        svc.stop()


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/status").read_text().split("State:")[1].split("\n")[0].lower()
    except (OSError, IndexError):
        return "zombie"


def test_api_process_never_imports_the_pipeline(tmp_path: Path, truth_clip: tuple[Path, Any]) -> None:
    script = textwrap.dedent(
        """
        import json, sys
        from fastapi.testclient import TestClient
        from service.app import create_app
        from backend.settings import Settings

        app = create_app(Settings(data_dir=sys.argv[1]))
        with TestClient(app) as client:
            with open(sys.argv[2], "rb") as fh:
                clip = client.post("/v1/clips", files={"file": ("c.npz", fh)})
            assert clip.status_code == 201, clip.text
            job = client.post("/v1/jobs", json={"clip_id": clip.json()["id"]})
            assert job.status_code == 202, job.text
            assert client.get("/v1/jobs/" + job.json()["id"]).status_code == 200
            assert client.get("/readyz").status_code == 200
        heavy = ["cv2", "pyfftw", "workers.pipeline", "workers.runner", "workers.tasks", "matplotlib"]
        print(json.dumps({m: m in sys.modules for m in heavy}))
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path / "data"), str(truth_clip[0])],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert not any(loaded.values()), loaded
