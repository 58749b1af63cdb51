"""One delivery of a job (``workers.execution.execute_job``) against a real store, with stand-in runners."""

from __future__ import annotations

import resource
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from api_schemas import AnalysisResult, Spectrum
from backend.settings import Settings
from backend.storage import Storage
from backend.store import NewClip, NewJob, Store
from workers.execution import ExecutionLimits, execute_job
from workers.pipeline.errors import ClipError


def result() -> AnalysisResult:
    return AnalysisResult(
        eigenfrequency_hz=4.0,
        objects=[],
        spectrum=Spectrum(frequencies_hz=[0.0], power=[0.0]),
        method="default",
        parameters={},
        fps=30.0,
        fps_source="bundle",
        frames_used=[0, 16],
        frame_size_px=[48, 32],
        version="test",
    )


@pytest.fixture
def job_id(store: Store, settings: Settings, small_clip: Path) -> str:
    storage = Storage(settings.data_path)
    storage.ensure()
    (storage.root / "clips" / "c1").mkdir(parents=True)
    (storage.root / "clips" / "c1" / "clip.npz").write_bytes(small_clip.read_bytes())
    store.add_clip(NewClip(clip_id="c1", filename="a.npz", path="clips/c1/clip.npz", info={}, size_bytes=1))
    job, _ = store.create_job(
        NewJob(clip_id="c1", excitation={"type": "step_release", "force_n": 2.0}, parameters={"frames": 16})
    )
    return job.id


def test_success_publishes_outputs(store: Store, settings: Settings, job_id: str) -> None:
    seen: dict[str, Any] = {}

    def runner(
        clip_path: Any, out_dir: Any, *, excitation: Any, parameters: Any, progress: Any, force_log: Any
    ) -> AnalysisResult:
        seen.update(excitation=excitation, parameters=parameters, force_log=force_log)
        progress("flow", 0.5)
        (Path(out_dir) / "mask.png").write_bytes(b"\x89PNG")
        return result()

    outcome = execute_job(
        store, settings.data_path, job_id, runner=runner, limits=ExecutionLimits(progress_interval_s=0)
    )
    assert outcome.status == "succeeded"
    job = store.get_job(job_id)
    assert job.status == "succeeded"
    assert job.progress == 1.0
    assert job.result is not None
    assert job.result["artifacts"]["mask"] == "mask.png"
    assert (settings.data_path / "jobs" / job_id / "mask.png").read_bytes() == b"\x89PNG"
    assert seen["excitation"].force_n == 2.0
    assert seen["parameters"].frames == 16
    assert seen["force_log"] is None
    assert list((settings.data_path / "tmp").iterdir()) == []
    # A second delivery of the same message does nothing.
    assert execute_job(store, settings.data_path, job_id, runner=runner).status == "finished"


def test_domain_error_fails_the_job_with_a_problem(store: Store, settings: Settings, job_id: str) -> None:
    def runner(*_a: Any, **_k: Any) -> AnalysisResult:
        raise ClipError("npz: 'rgb' is truncated at frame 3")

    assert execute_job(store, settings.data_path, job_id, runner=runner).status == "failed"
    job = store.get_job(job_id)
    assert job.status == "failed"
    assert job.error is not None
    assert job.error["status"] == 422
    assert "truncated" in job.error["detail"]
    assert job.error["type"].endswith("/invalid-clip")


FORCE_LOG = {
    "time_s": [i / 500 - 0.1 for i in range(40)],
    "force_n": [6.0] * 20 + [0.0] * 20,
    "offset_s": 0.0,
    "frame_id": None,
    "name": "push.csv",
}


@pytest.fixture
def force_job_id(store: Store, job_id: str) -> str:
    """A job of the same clip sent with a force log and no excitation (as the API stores it)."""
    from api_schemas import ForceLog

    log = ForceLog.model_validate(FORCE_LOG)
    job, _ = store.create_job(
        NewJob(
            clip_id="c1",
            excitation=None,
            parameters={"frames": 16},
            force_log=log.model_dump(mode="json"),
            force_log_summary=log.summary().model_dump(mode="json"),
        )
    )
    return job.id


def test_the_force_log_reaches_the_runner(store: Store, settings: Settings, force_job_id: str) -> None:
    """The log is stored apart from the job's record (which carries its summary) and handed to the runner
    whole."""
    seen: dict[str, Any] = {}

    def runner(clip_path: Any, out_dir: Any, *, force_log: Any, **_k: Any) -> AnalysisResult:
        seen["force_log"] = force_log
        return result()

    assert store.get_job(force_job_id).force_log_summary == {
        "name": "push.csv",
        "samples": 40,
        "start_s": -0.1,
        "end_s": pytest.approx(-0.1 + 39 / 500),
        "columns": ["force_n"],
        "frame_id": None,
    }
    assert execute_job(store, settings.data_path, force_job_id, runner=runner).status == "succeeded"
    assert seen["force_log"].model_dump(mode="json") == {**FORCE_LOG, "fx": None, "fy": None, "fz": None}


def test_a_bad_force_log_fails_the_job_with_its_problem(
    store: Store, settings: Settings, force_job_id: str
) -> None:
    """What the analysis finds wrong with a log (no hold or strike, another clock) fails the job once, as
    a 422 ``invalid-force`` problem carrying the message, never a crash or a retry."""
    from workers.pipeline.errors import ForceError

    def runner(*_a: Any, **_k: Any) -> AnalysisResult:
        raise ForceError("the force log push.csv shows no hold, release or strike above its noise")

    assert execute_job(store, settings.data_path, force_job_id, runner=runner).status == "failed"
    job = store.get_job(force_job_id)
    assert job.attempts == 1
    assert job.error is not None
    assert job.error["status"] == 422
    assert job.error["type"].endswith("/invalid-force")
    assert job.error["detail"] == "the force log push.csv shows no hold, release or strike above its noise"


def test_infrastructure_fault_is_retried_then_failed(store: Store, settings: Settings, job_id: str) -> None:
    """Only faults of what the analysis runs on (storage, database, network) are worth another try."""

    def runner(*_a: Any, **_k: Any) -> AnalysisResult:
        raise OSError(5, "Input/output error", str(settings.data_path / "jobs" / "x" / "mask.png"))

    first = execute_job(store, settings.data_path, job_id, runner=runner)
    assert first.status == "retry"
    assert first.retry_in_s is not None
    assert store.get_job(job_id).status == "queued"
    second = execute_job(store, settings.data_path, job_id, runner=runner)  # max_attempts=2
    assert second.status == "failed"
    job = store.get_job(job_id)
    assert job.attempts == 2
    assert job.error is not None
    assert "OSError" in job.error["detail"]
    assert "mask.png" in job.error["detail"]
    assert str(settings.data_path) not in job.error["detail"]  # no server path in a problem
    assert "/jobs/" not in job.error["detail"]


@pytest.mark.parametrize(
    "error",
    [
        ValueError("cannot convert float NaN to integer"),
        RuntimeError("segfault-ish"),
        IndexError("index 3 is out of bounds for axis 0 with size 3"),
    ],
)
def test_unexpected_error_fails_once_without_retry(
    store: Store, settings: Settings, job_id: str, error: Exception
) -> None:
    """A bug of the analysis fails the same way on every attempt: one attempt, then a clear problem."""
    calls = []

    def runner(*_a: Any, **_k: Any) -> AnalysisResult:
        calls.append(1)
        raise error

    outcome = execute_job(store, settings.data_path, job_id, runner=runner)
    assert outcome.status == "failed"
    assert outcome.retry_in_s is None
    job = store.get_job(job_id)
    assert (job.status, job.attempts, len(calls)) == ("failed", 1, 1)
    assert job.error is not None
    assert job.error["type"].endswith("/analysis-crashed")
    assert type(error).__name__ in job.error["detail"]
    assert "not retried" in job.error["detail"]


def test_job_over_its_memory_budget_fails_once(store: Store, settings: Settings, job_id: str) -> None:
    """The runner runs under an address-space cap: an allocation past it is a MemoryError, and the job
    fails at once with `resources-exhausted` instead of growing the worker (and is not retried)."""
    from workers.execution import vm_size_bytes

    before = resource.getrlimit(resource.RLIMIT_AS)
    budget_mb = vm_size_bytes() // 2**20 + 512
    seen: dict[str, Any] = {}

    def runner(*_a: Any, **_k: Any) -> AnalysisResult:
        seen["limit"] = resource.getrlimit(resource.RLIMIT_AS)[0]
        np.ones(2 * 2**30, np.uint8)  # 2 GiB: past the budget
        raise AssertionError("the allocation succeeded")

    outcome = execute_job(
        store, settings.data_path, job_id, runner=runner, limits=ExecutionLimits(memory_budget_mb=budget_mb)
    )
    assert outcome.status == "failed"
    assert seen["limit"] == budget_mb * 2**20
    assert resource.getrlimit(resource.RLIMIT_AS) == before  # restored for the next job
    job = store.get_job(job_id)
    assert (job.status, job.attempts) == ("failed", 1)
    assert job.error is not None
    assert job.error["type"].endswith("/resources-exhausted")
    assert job.error["status"] == 413
    assert f"{budget_mb} MiB" in job.error["detail"]
    assert "EIGENSCOPE_JOB_MEMORY_MB" in job.error["detail"]


def test_budget_below_the_worker_itself_is_a_clear_failure(
    store: Store, settings: Settings, job_id: str
) -> None:
    def runner(*_a: Any, **_k: Any) -> AnalysisResult:
        raise AssertionError("must not run")

    assert (
        execute_job(
            store, settings.data_path, job_id, runner=runner, limits=ExecutionLimits(memory_budget_mb=1)
        ).status
        == "failed"
    )
    job = store.get_job(job_id)
    assert job.error is not None
    assert job.error["type"].endswith("/resources-exhausted")
    assert "already uses" in job.error["detail"]


def test_abandoned_attempt_folders_are_removed(store: Store, settings: Settings, job_id: str) -> None:
    """A killed attempt leaves its output and scratch folders; the sweeper removes them as soon as the
    job is no longer running, and the next attempt's claim removes them too."""
    from service.context import ServiceContext

    storage = Storage(settings.data_path)
    tmp = storage.root / "tmp"
    other = store.create_job(NewJob(clip_id="c1", excitation=None, parameters={}))[0].id

    def abandoned(job: str, attempt: int) -> list[Path]:
        folders = [tmp / f"job-{job}-{attempt}-0123abcd", tmp / f"job-{job}-{attempt}-0123abcd-scratch"]
        for folder in folders:
            folder.mkdir()
            (folder / "half-written.png").write_bytes(b"x")
        return folders

    # The claim of the next attempt removes the earlier one's folders.
    left = abandoned(job_id, 1)
    seen = []

    def runner(clip_path: Any, out_dir: Any, **_k: Any) -> AnalysisResult:
        seen.extend(p for p in left if p.exists())
        return result()

    assert execute_job(store, settings.data_path, job_id, runner=runner).status == "succeeded"
    assert seen == []
    assert list(tmp.iterdir()) == []

    # The sweeper removes them once the job is not running (queued again, failed, cancelled or gone),
    # and leaves a running attempt's folders alone.
    left = abandoned(other, 1)
    ctx = ServiceContext.build(settings)
    try:
        assert store.claim_job(other, "me/1/x").job is not None
        assert ctx.remove_abandoned_workdirs() == 0
        assert all(p.exists() for p in left)
        assert store.release_job(other, "me/1/x")  # its worker died: the job is queued again
        assert ctx.remove_abandoned_workdirs() == 2
        assert list(tmp.iterdir()) == []
    finally:
        ctx.store.dispose()


def test_cancel_while_running_stops_the_runner(store: Store, settings: Settings, job_id: str) -> None:
    def runner(clip_path: Any, out_dir: Any, *, progress: Any, **_k: Any) -> AnalysisResult:
        progress("flow", 0.1)
        store.cancel_job(job_id)
        progress("spectrum", 0.6)  # raises: the job is no longer ours
        raise AssertionError("not reached")

    assert (
        execute_job(
            store, settings.data_path, job_id, runner=runner, limits=ExecutionLimits(progress_interval_s=0)
        ).status
        == "aborted"
    )
    job = store.get_job(job_id)
    assert job.status == "cancelled"
    assert job.result is None
    assert not (settings.data_path / "jobs" / job_id).exists()


def test_deleted_clip_fails_the_job(store: Store, settings: Settings, job_id: str) -> None:
    (settings.data_path / "clips" / "c1" / "clip.npz").unlink()

    def runner(*_a: Any, **_k: Any) -> AnalysisResult:
        raise AssertionError("must not run")

    assert execute_job(store, settings.data_path, job_id, runner=runner).status == "failed"
    error = store.get_job(job_id).error
    assert error is not None
    assert error["status"] == 410


def test_kill_hook_is_inert_without_test_hooks(store: Store, settings: Settings, small_clip: Path) -> None:
    """A clip named with the kill marker runs normally unless EIGENSCOPE_TEST_HOOKS is on."""
    from workers.execution import KILL_WORKER_MARKER

    storage = Storage(settings.data_path)
    storage.ensure()
    (storage.root / "clips" / "k1").mkdir(parents=True)
    (storage.root / "clips" / "k1" / "clip.npz").write_bytes(small_clip.read_bytes())
    store.add_clip(
        NewClip(
            clip_id="k1",
            filename=KILL_WORKER_MARKER + ".npz",
            path="clips/k1/clip.npz",
            info={},
            size_bytes=1,
        )
    )
    job, _ = store.create_job(NewJob(clip_id="k1", excitation=None, parameters={}))

    def runner(clip_path: Any, out_dir: Any, **_: Any) -> AnalysisResult:
        (Path(out_dir) / "mask.png").write_bytes(b"\x89PNG12345")
        return result()

    assert Settings().test_hooks is False
    assert execute_job(store, settings.data_path, job.id, runner=runner).status == "succeeded"
    done = store.get_job(job.id)
    assert done.status == "succeeded"
    assert done.output_bytes == 9  # counted against the key's stored-bytes quota
