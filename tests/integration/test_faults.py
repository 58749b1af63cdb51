"""Faults with real processes on a real Redis: workers SIGKILLed, a job that kills every worker, Redis
killed and restarted, the API restarted, the database and the storage unreachable.

The machine's shared Redis has no persistence and must not be restarted, so this module runs its own
``redis-server`` with the persistence settings ``docker/compose.yaml`` ships (AOF, fsync always).
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import service_harness as h

from backend.store import Store
from workers.execution import KILL_WORKER_MARKER

pytestmark = [pytest.mark.integration, pytest.mark.slow]

MAX_ATTEMPTS = 3


@pytest.fixture(scope="module")
def redis_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.RedisServer]:
    server = h.RedisServer(tmp_path_factory.mktemp("redis"))
    server.start()
    yield server
    server.kill()


def fault_env(root: Path, redis_server: h.RedisServer, **settings: str) -> dict[str, str]:
    """The environment of a service over ``redis_server`` with short leases and sweeps."""
    return h.base_env(
        root / "data", redis_url=redis_server.url, lease_s="4", sweep_interval_s="0.5", **settings
    )


@pytest.fixture(scope="module")
def service(redis_server: h.RedisServer, tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    """uvicorn and two one-process workers over the private Redis, SQLite job store, test hooks on."""
    root = tmp_path_factory.mktemp("faults")
    port = h.free_port()
    env = fault_env(
        root, redis_server, max_attempts=str(MAX_ATTEMPTS), test_hooks="1", progress_interval_s="0.1"
    )
    svc = h.LiveService(f"http://127.0.0.1:{port}", root / "data", env)
    svc.env["FAULTS_PORT"] = str(port)
    try:
        h.start_api(svc, port=port)
        h.start_worker(svc, "worker0")
        h.start_worker(svc, "worker1")
        svc.wait_ready()
    except BaseException:
        svc.stop()
        raise
    yield svc
    svc.stop()


@pytest.fixture(scope="module")
def store(service: h.LiveService) -> Iterator[Store]:
    s = Store(f"sqlite:///{service.data_dir / 'eigenscope.db'}")
    yield s
    s.dispose()


@pytest.fixture(scope="module")
def small_clip_id(service: h.LiveService, truth_clip: tuple[Path, Any]) -> str:
    response = service.upload(truth_clip[0])
    assert response.status_code == 201, response.text
    clip_id: str = response.json()["id"]
    return clip_id


def workers(service: h.LiveService) -> list[h.Proc]:
    return [p for p in service.procs if p.name.startswith("worker") and p.alive()]


def replace_worker(service: h.LiveService, dead: h.Proc) -> None:
    dead.stop(grace_s=0.1)
    service.procs.remove(dead)
    h.start_worker(service, f"{dead.name}r")


wait_for = h.wait_for


def test_sigkilled_worker_job_runs_again_on_another_and_succeeds_once(
    service: h.LiveService, store: Store, tmp_path: Path
) -> None:
    path = tmp_path / "slow.npz"
    h.synth_clip(path, frames=128, width=320, height=240, frequency_hz=5.0, seed=4)  # seconds of Farnebäck
    clip_id = service.upload(path).json()["id"]
    job_id = service.client.post(
        "/v1/jobs", json={"clip_id": clip_id, "parameters": {"flow": "farneback"}}
    ).json()["id"]

    def running_owner() -> str | None:
        job = store.get_job(job_id)
        assert job.status in ("queued", "running"), job
        return job.lease_owner if job.status == "running" and job.stage not in ("starting", None) else None

    owner = wait_for(running_owner, 60, "the job to run", service)
    pid = int(owner.split("/")[1])
    victim = next(p for p in workers(service) if pid in h.children_of(p.pid))
    os.killpg(victim.pid, signal.SIGKILL)  # the worker and its pool process die without a word
    victim.popen.wait(timeout=10)

    job = service.wait_job(job_id, timeout_s=120)
    assert job["status"] == "succeeded", (job, service.logs())
    assert job["attempts"] == 2
    assert job["result"]["eigenfrequency_hz"] == pytest.approx(5.0, rel=0.03)
    record = store.get_job(job_id)
    survivor = next(p for p in workers(service) if p is not victim)
    # One result: one output folder, written by the surviving worker; no second completion later.
    assert (service.data_dir / "jobs" / job_id / "mask.png").is_file()
    assert len([d for d in (service.data_dir / "jobs").iterdir() if d.name == job_id]) == 1
    assert survivor.alive()
    # The killed attempt's temporary folders went when the job was claimed again (not two hours later).
    assert list((service.data_dir / "tmp").glob("job-*")) == []
    replace_worker(service, victim)
    time.sleep(1.0)
    again = store.get_job(job_id)
    assert (again.status, again.attempts, again.finished_at) == ("succeeded", 2, record.finished_at)
    print(f"\nFAULT worker SIGKILL mid-job: job re-run on the other worker, attempts={job['attempts']}")


def test_job_that_kills_every_worker_fails_after_max_attempts(
    service: h.LiveService, store: Store, truth_clip: tuple[Path, Any], small_clip_id: str
) -> None:
    with truth_clip[0].open("rb") as fh:
        up = service.client.post("/v1/clips", files={"file": (f"{KILL_WORKER_MARKER}.npz", fh)})
    assert up.status_code == 201, up.text
    job_id = service.client.post("/v1/jobs", json={"clip_id": up.json()["id"]}).json()["id"]
    job = service.wait_job(job_id, timeout_s=120)
    assert job["status"] == "failed", (job, service.logs())
    assert job["attempts"] == MAX_ATTEMPTS
    assert job["error"]["type"].endswith("/worker-lost")
    assert f"{MAX_ATTEMPTS} time(s)" in job["error"]["detail"]
    # The workers are still there (Celery replaced the killed pool processes) and do real work.
    assert len(workers(service)) == 2
    follow_up = service.client.post("/v1/jobs", json={"clip_id": small_clip_id}).json()["id"]
    assert service.wait_job(follow_up, timeout_s=60)["status"] == "succeeded"
    time.sleep(1.0)
    assert store.get_job(job_id).status == "failed"  # no further attempt sneaks in
    print(f"\nFAULT poison job: failed after {job['attempts']} attempts with {job['error']['type']}")


def test_api_restart_while_jobs_run(service: h.LiveService, small_clip_id: str) -> None:
    ids = [service.client.post("/v1/jobs", json={"clip_id": small_clip_id}).json()["id"] for _ in range(4)]
    api = next(p for p in service.procs if p.name.startswith("api"))
    api.stop(grace_s=5)  # SIGTERM, then SIGKILL of whatever is left
    service.procs.remove(api)
    h.start_api(service, port=int(service.env["FAULTS_PORT"]), name="api2")
    for job_id in ids:
        job = service.wait_job(job_id, timeout_s=90)
        assert job["status"] == "succeeded", (job, service.logs())
        assert job["attempts"] == 1
    listed = {j["id"] for j in service.client.get("/v1/jobs", params={"limit": 100}).json()["items"]}
    assert set(ids) <= listed
    print(f"\nFAULT API restart: {len(ids)} jobs finished and visible afterwards")


def test_redis_killed_and_restarted_loses_no_queued_job(
    service: h.LiveService, redis_server: h.RedisServer, small_clip_id: str
) -> None:
    # Stop the workers so the jobs stay queued in Redis, not in a worker's hands.
    stopped = workers(service)
    for proc in stopped:
        proc.stop(grace_s=10)
        service.procs.remove(proc)
    ids = [service.client.post("/v1/jobs", json={"clip_id": small_clip_id}).json()["id"] for _ in range(5)]
    wait_for(lambda: redis_server.queued() == 5, 10, "5 messages in Redis", service)

    redis_server.kill()
    ready = service.client.get("/readyz")
    assert ready.status_code == 503
    assert ready.json()["checks"]["broker"].startswith("failed")
    assert ready.json()["checks"]["database"] == "ok"
    # A job created while Redis is down is recorded and published once it is back (by the sweeper).
    late = service.client.post("/v1/jobs", json={"clip_id": small_clip_id})
    assert late.status_code == 202, late.text
    ids.append(late.json()["id"])

    redis_server.start()
    assert redis_server.queued() >= 5  # the append-only file brought them back
    for i in range(len(stopped)):
        h.start_worker(service, f"worker{i}b")
    for job_id in ids:
        job = service.wait_job(job_id, timeout_s=120)
        assert job["status"] == "succeeded", (job, service.logs())
        assert job["attempts"] == 1
    service.wait_ready()
    print(f"\nFAULT Redis SIGKILL + restart: {len(ids)} queued jobs, none lost")


def test_database_unreachable(tmp_path: Path, small_clip: Path) -> None:
    closed = h.free_port()
    env = h.base_env(tmp_path / "data", database_url=f"postgresql://eigenscope@127.0.0.1:{closed}/nothing")
    port = h.free_port()
    svc = h.LiveService(f"http://127.0.0.1:{port}", tmp_path / "data", env)
    try:
        h.start_api(svc, port=port)
        ready = svc.client.get("/readyz")
        assert ready.status_code == 503
        checks = ready.json()["checks"]
        assert checks["database"].startswith("failed"), checks
        assert (checks["broker"], checks["storage"]) == ("ok", "ok")
        up = svc.upload(small_clip)
        assert up.status_code == 503, up.text
        assert up.headers["content-type"] == "application/problem+json"
        assert up.json()["type"].endswith("/database-unavailable")
        assert int(up.headers["retry-after"]) > 0
        assert svc.client.get("/v1/jobs/0123").status_code == 503
        assert svc.client.post("/v1/jobs", json={"clip_id": "x"}).status_code == 503
        assert list((svc.data_dir / "clips").iterdir()) == []
        assert list((svc.data_dir / "tmp").iterdir()) == []
        assert svc.procs[0].alive()
    finally:
        svc.stop()


def test_storage_unreachable(tmp_path: Path, small_clip: Path, redis_server: h.RedisServer) -> None:
    import shutil

    db = f"sqlite:///{tmp_path / 'store.db'}"
    env = h.base_env(tmp_path / "data", database_url=db, redis_url=redis_server.url, queue="storage-test")
    port = h.free_port()
    svc = h.LiveService(f"http://127.0.0.1:{port}", tmp_path / "data", env)
    try:
        h.start_api(svc, port=port)
        svc.wait_ready()
        shutil.rmtree(svc.data_dir)  # the volume is gone
        ready = svc.client.get("/readyz")
        assert ready.status_code == 503
        checks = ready.json()["checks"]
        assert checks["storage"].startswith("failed"), checks
        assert (checks["database"], checks["broker"]) == ("ok", "ok")
        up = svc.upload(small_clip)
        assert up.status_code == 503, up.text
        assert up.json()["type"].endswith("/storage-unavailable")
        store = Store(db)
        try:
            assert store.usage("").stored_bytes == 0  # no record either
        finally:
            store.dispose()
        assert not svc.data_dir.exists()
    finally:
        svc.stop()


@pytest.fixture
def small_clip(truth_clip: tuple[Path, Any]) -> Path:
    return truth_clip[0]


def test_queued_jobs_run_soon_after_redis_lost_its_messages(
    tmp_path: Path, truth_clip: tuple[Path, Any]
) -> None:
    """Issue 27, item 5: twelve jobs, the worker SIGKILLed mid-job and Redis killed -9 without
    persistence. The job that was running came back by its lease, but the nine still queued waited for
    the hourly republish (``requeue_after_s``); now the API sees the messages are gone and publishes them
    again, and nothing runs twice."""
    redis_server = h.RedisServer(tmp_path / "redis", persistent=False)
    redis_server.start()
    port = h.free_port()
    env = fault_env(tmp_path, redis_server, broker_reconcile_interval_s="2")
    service = h.LiveService(f"http://127.0.0.1:{port}", tmp_path / "data", env)
    try:
        h.start_api(service, port=port)
        victim = h.start_worker(service, "worker0")
        service.wait_ready()
        clip_id = service.upload(truth_clip[0]).json()["id"]
        ids = [service.client.post("/v1/jobs", json={"clip_id": clip_id}).json()["id"] for _ in range(12)]
        wait_for(
            lambda: any(service.client.get(f"/v1/jobs/{j}").json()["status"] == "running" for j in ids),
            60,
            "a running job",
            service,
        )
        os.killpg(victim.pid, signal.SIGKILL)
        service.procs.remove(victim)
        redis_server.kill()
        redis_server.start()
        restarted = time.monotonic()
        assert redis_server.queued() == 0  # every message is gone
        h.start_worker(service, "worker1")
        jobs = [service.wait_job(j, timeout_s=max(restarted + 150 - time.monotonic(), 1)) for j in ids]
        took_s = time.monotonic() - restarted
        assert [j["status"] for j in jobs] == ["succeeded"] * 12, service.logs()
        # Nothing ran twice: one attempt each, two for the job the killed worker was running.
        assert sorted(j["attempts"] for j in jobs) == [1] * 11 + [2]
        print(f"\nFAULT Redis kill -9 without persistence: 12 jobs done {took_s:.0f} s after the restart")
    finally:
        service.stop()
        redis_server.kill()
