"""One delivery of a ``run_job`` message: claim the job, run the analysis, record the outcome.

This is the logic behind :func:`workers.tasks.run_job`, kept free of Celery's task machinery so it can be
tested with a real store and a stand-in runner. The job row is the source of truth:

- the job is *claimed* first (lease + attempt count); a delivery that finds the job finished drops the
  message, one that finds a live lease held by another worker asks to be retried after it expires;
- a heartbeat thread renews the lease while the analysis runs; progress is written at most every
  ``progress_interval_s`` (and on every stage change);
- a progress write that no longer lands (the job was cancelled or taken over) aborts the analysis;
- outputs are written to a fresh directory and renamed into place, so a re-run never mixes files; the
  folders of an earlier, abandoned attempt are removed when the job is claimed again;
- the analysis runs under a memory budget (an address-space limit on this process while it runs);
- retries only where they can help: a deterministic failure -- a bad clip or bad parameters (domain
  errors), a job over its memory budget, an unexpected error of the analysis itself (it would fail the
  same way again) -- fails the job at once with a problem document. Only infrastructure faults (the
  database, the storage or the network failing: ``OSError``, an unavailable database) give the job
  back to the queue, until ``max_attempts`` is reached; a lost worker is taken over by the sweeper or the
  next delivery (see :meth:`backend.store.Store.recover_stale_jobs`).
"""

from __future__ import annotations

import logging
import os
import resource
import shutil
import signal
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from pydantic import TypeAdapter, ValidationError

from api_schemas import (
    AnalysisParameters,
    AnalysisResult,
    ExcitationSpec,
    ForceLog,
    ImpulseExcitation,
    StepReleaseExcitation,
)
from backend.errors import PROBLEM_TYPES, UnavailableError, problem_document
from backend.logs import job_id_var
from backend.store import ClaimOutcome, ClipRecord, JobRecord, Lease, Store, lease_owner_token

log = logging.getLogger(__name__)

ProgressCallback = Callable[[str, float], None]

_EXCITATION: TypeAdapter[
    StepReleaseExcitation | ImpulseExcitation | list[StepReleaseExcitation | ImpulseExcitation]
] = TypeAdapter(ExcitationSpec)

#: Messages of native libraries (OpenCV, threads) that ran out of memory or address space.
_EXHAUSTION_MARKERS = (
    "insufficient memory",
    "failed to allocate",
    "can't start new thread",
    "cannot allocate",
)
#: With ``EIGENSCOPE_TEST_HOOKS=1`` only: a clip uploaded under a name starting with this kills the
#: worker process that runs its job, every time (fault-injection for the test suite).
KILL_WORKER_MARKER = "__eigenscope_kill_worker__"


class Runner(Protocol):
    """The signature of :func:`workers.runner.run_analysis`."""

    def __call__(
        self,
        clip_path: str | Path,
        out_dir: str | Path,
        *,
        excitation: StepReleaseExcitation
        | ImpulseExcitation
        | Sequence[StepReleaseExcitation | ImpulseExcitation]
        | None = ...,
        parameters: AnalysisParameters | None = ...,
        progress: ProgressCallback | None = ...,
        force_log: ForceLog | None = ...,
    ) -> AnalysisResult: ...


class JobObserver(Protocol):
    """What a worker's metrics want to know about each delivery (see :mod:`workers.metrics`)."""

    def started(self, job: JobRecord, *, queue_wait_s: float) -> None: ...

    def finished(
        self,
        job: JobRecord,
        *,
        outcome: str,
        duration_s: float,
        failure: str | None,
        timings_s: dict[str, float],
    ) -> None: ...


@dataclass
class _Report:
    """What one delivery did, for its observer."""

    observer: JobObserver | None
    job: JobRecord | None = None
    started: float = 0.0
    failure: str | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    told: bool = False

    def claimed(self, job: JobRecord) -> None:
        self.job, self.started = job, time.monotonic()
        wait = max(time.time() - job.enqueued_at, 0.0) if job.enqueued_at else 0.0
        log.info("job %s: attempt %d started after %.2f s in the queue", job.id, job.attempts, wait)
        if self.observer is not None:
            self.observer.started(job, queue_wait_s=wait)

    def done(self, outcome: Outcome) -> Outcome:
        """Log and count how the delivery ended, once. Called before the job's final state is stored (so
        whoever sees the job end sees it counted), and again, doing nothing, when the delivery returns."""
        if self.told:
            return outcome
        self.told = True
        if self.job is not None:
            took = time.monotonic() - self.started
            why = f" ({self.failure})" if self.failure else ""
            log.info(
                "job %s: attempt %d %s%s in %.2f s", self.job.id, self.job.attempts, outcome.status, why, took
            )
        if self.observer is not None and self.job is not None:
            self.observer.finished(
                self.job,
                outcome=outcome.status,
                duration_s=time.monotonic() - self.started,
                failure=self.failure,
                timings_s=self.timings_s,
            )
        return outcome


class JobAbortedError(Exception):
    """The job is no longer ours (cancelled or taken over): stop without writing anything."""


@dataclass(frozen=True, slots=True)
class Outcome:
    """What the task does with the message: drop it (``retry_in_s`` None) or retry after a delay."""

    status: str
    retry_in_s: float | None = None


def vm_size_bytes() -> int:
    """This process's address space now (``VmSize``), bytes; 0 where ``/proc`` has none."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        pass
    return 0


class BudgetTooSmallError(Exception):
    """The memory budget is below what this process already uses: an operator's setting to fix."""


@contextmanager
def memory_budget(megabytes: int) -> Iterator[None]:
    """Run the block with this process's address space capped at ``megabytes`` MiB (0: no cap).

    An allocation past the cap fails (``MemoryError`` in Python, an allocation error in native code)
    instead of growing the worker until the kernel kills it. The previous limit is restored after.
    """
    if megabytes <= 0:
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = megabytes * 1024 * 1024
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    in_use = vm_size_bytes()
    if in_use and cap < in_use + 64 * 1024 * 1024:
        raise BudgetTooSmallError(
            f"the memory budget of {megabytes} MiB (EIGENSCOPE_JOB_MEMORY_MB) is below the "
            f"{in_use // 2**20} MiB of address space the worker already uses; ask the operator to raise it"
        )
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def is_exhaustion(exc: BaseException) -> bool:
    """True when ``exc`` says the analysis ran out of memory (or address space, or threads)."""
    if isinstance(exc, MemoryError | BudgetTooSmallError):
        return True
    text = str(exc).lower()
    return type(exc).__name__ in ("error", "RuntimeError") and any(m in text for m in _EXHAUSTION_MARKERS)


def is_infrastructure_fault(exc: BaseException) -> bool:
    """True for failures of what the analysis runs on (storage, database, network), which a later
    attempt may not meet; everything else an analysis raises would fail the same way again."""
    if isinstance(exc, OSError | UnavailableError):
        return True
    return any(
        cls.__module__.startswith("sqlalchemy") and cls.__name__ in ("OperationalError", "InterfaceError")
        for cls in type(exc).__mro__
    )


class _Progress:
    """The ``progress(stage, fraction)`` callback: throttled writes; raises :class:`JobAbortedError`."""

    def __init__(self, store: Store, job_id: str, owner: str, lease: Lease, interval_s: float) -> None:
        self.store, self.job_id, self.owner, self.lease = store, job_id, owner, lease
        self.interval_s = interval_s
        self._last_write = 0.0
        self._last_stage: str | None = None

    def __call__(self, stage: str, fraction: float) -> None:
        if self.lease.lost.is_set():
            raise JobAbortedError(self.job_id)
        now = time.monotonic()
        if stage == self._last_stage and now - self._last_write < self.interval_s:
            return
        self._last_write, self._last_stage = now, stage
        if not self.store.report_progress(self.job_id, self.owner, stage, fraction):
            self.lease.lost.set()
            raise JobAbortedError(self.job_id)


@dataclass(frozen=True)
class ExecutionLimits:
    """How a delivery runs: how often it reports progress, and what stops it.

    Attributes
    ----------
    progress_interval_s : float
        Least time between two progress writes of one stage.
    soft_time_limit_s : float or None
        The task's soft time limit (for the problem's message).
    timeout_errors : tuple of exception types
        Raised into the runner when the soft time limit strikes (Celery's ``SoftTimeLimitExceeded``).
    test_hooks : bool
        Enable fault injection (``EIGENSCOPE_TEST_HOOKS``; see :data:`KILL_WORKER_MARKER`). Off in
        production: without it no request can trigger a hook.
    memory_budget_mb : int
        Address-space cap of this process while the runner runs (``EIGENSCOPE_JOB_MEMORY_MB``; 0: none).
    """

    progress_interval_s: float = 0.25
    soft_time_limit_s: float | None = None
    timeout_errors: tuple[type[BaseException], ...] = ()
    test_hooks: bool = False
    memory_budget_mb: int = 0


def execute_job(
    store: Store,
    storage_root: Path,
    job_id: str,
    *,
    runner: Runner,
    limits: ExecutionLimits | None = None,
    observer: JobObserver | None = None,
) -> Outcome:
    """Run one delivery of job ``job_id``; see the module docstring.

    Parameters
    ----------
    store : Store
    storage_root : Path
        The data directory (``clips/``, ``jobs/``, ``tmp/``).
    runner : callable
        :func:`workers.runner.run_analysis` or a stand-in with its signature.
    limits : ExecutionLimits, optional
        Progress interval, time limit, fault injection and memory budget (the defaults: none).
    observer : JobObserver, optional
        Told when the job is claimed and how the delivery ended (the worker's metrics).

    Every log record of the delivery carries the job id (:data:`backend.logs.job_id_var`).
    """
    token = job_id_var.set(job_id)
    report = _Report(observer)
    try:
        outcome = _execute(
            store, storage_root, job_id, runner=runner, limits=limits or ExecutionLimits(), report=report
        )
        return report.done(outcome)
    finally:
        job_id_var.reset(token)


@dataclass(frozen=True)
class _Inputs:
    """What a claimed job's runner takes: the clip (its record and file) and the stored request, checked."""

    clip: ClipRecord
    clip_path: Path
    excitation: Any
    parameters: AnalysisParameters
    force_log: ForceLog | None


def _execute(
    store: Store,
    storage_root: Path,
    job_id: str,
    *,
    runner: Runner,
    limits: ExecutionLimits,
    report: _Report,
) -> Outcome:
    from backend.storage import Storage

    storage = Storage(storage_root)
    owner = lease_owner_token()
    claim = store.claim_job(job_id, owner)
    if claim.outcome is ClaimOutcome.BUSY:
        log.info("job %s is held by another worker; retrying in %.1f s", job_id, claim.retry_in_s)
        return Outcome("busy", retry_in_s=claim.retry_in_s)
    if claim.outcome is not ClaimOutcome.CLAIMED:
        log.info("job %s: %s, message dropped", job_id, claim.outcome.value)
        return Outcome(claim.outcome.value)
    job = claim.job
    assert job is not None
    report.claimed(job)

    def fail(p: dict[str, Any]) -> Outcome:
        report.failure = str(p.get("code") or p.get("type", "")).rsplit("/", 1)[-1]
        report.done(Outcome("failed"))
        store.fail_job(job_id, owner, p)
        return Outcome("failed")

    inputs = _inputs(store, storage, job)
    if not isinstance(inputs, _Inputs):
        return fail(inputs)
    if limits.test_hooks:
        _fault_injection(inputs.clip)
    if storage.remove_job_workdirs(job_id):  # an earlier attempt was abandoned (its worker was killed)
        log.info("job %s: removed the folders of an abandoned attempt", job_id)
    workdir = storage.new_job_workdir(job_id, job.attempts)
    try:
        with Lease(store, job_id, owner) as lease:
            try:
                delivery = _Delivery(store, storage, job_id, owner, lease, limits, report)
                return _run(delivery, workdir, runner, inputs)
            except JobAbortedError:
                log.info("job %s: cancelled or taken over; stopped", job_id)
                return Outcome("aborted")
            except limits.timeout_errors:
                return fail(
                    problem_document(
                        "time-limit",
                        f"the analysis ran longer than the limit of {limits.soft_time_limit_s or 0:g} s; "
                        "analyse a shorter window (parameters.frames) or ask the operator to raise "
                        "EIGENSCOPE_TASK_SOFT_TIME_LIMIT_S",
                    )
                )
            except Exception as exc:
                return _failed(store, job_id, owner, job.attempts, exc, limits.memory_budget_mb, fail)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


def _inputs(store: Store, storage: Any, job: Any) -> _Inputs | dict[str, Any]:
    """The job's clip file and its stored request, checked; or the problem that fails the job."""
    clip = store.find_clip(job.clip_id)
    clip_path = storage.clip_path(clip.path) if clip is not None else None
    if clip is None or clip_path is None or not clip_path.is_file():
        return problem_document(
            "clip-gone",
            f"clip {job.clip_id} was deleted before the job ran; upload it again and create a new job",
        )
    try:
        excitation = _EXCITATION.validate_python(job.excitation) if job.excitation is not None else None
        parameters = AnalysisParameters.model_validate(job.parameters)
    except ValidationError as exc:
        return problem_document("invalid-parameter", f"stored job is invalid: {exc}")
    try:  # read apart from the job's record, which carries only its summary
        stored_log = store.job_force_log(job.id) if job.force_log_summary is not None else None
        force_log = ForceLog.model_validate(stored_log) if stored_log is not None else None
    except ValidationError as exc:
        return problem_document("invalid-force", f"stored job's force log is invalid: {exc}")
    return _Inputs(clip, clip_path, excitation, parameters, force_log)


@dataclass(frozen=True)
class _Delivery:
    """One delivery of a claimed job: where it is recorded and stored, who holds it, and its limits."""

    store: Store
    storage: Any
    job_id: str
    owner: str
    lease: Any
    limits: ExecutionLimits
    report: _Report


def _run(delivery: _Delivery, workdir: Path, runner: Runner, inputs: _Inputs) -> Outcome:
    """Run the analysis under the lease and the memory budget, publish its outputs and complete the job."""
    from backend.storage import tree_bytes

    store, job_id, owner, lease, limits = (
        delivery.store,
        delivery.job_id,
        delivery.owner,
        delivery.lease,
        delivery.limits,
    )
    callback = _Progress(store, job_id, owner, lease, limits.progress_interval_s)
    callback("starting", 0.0)
    with memory_budget(limits.memory_budget_mb):
        result = runner(
            inputs.clip_path,
            workdir,
            excitation=inputs.excitation,
            parameters=inputs.parameters,
            progress=callback,
            force_log=inputs.force_log,
        )
    delivery.report.timings_s = dict(result.timings_s)
    if lease.lost.is_set() or not store.renew_lease(job_id, owner):
        raise JobAbortedError(job_id)
    output_bytes = tree_bytes(workdir)
    delivery.storage.publish_job_outputs(job_id, workdir)
    delivery.report.done(Outcome("succeeded"))
    if not store.complete_job(job_id, owner, result.model_dump(mode="json"), output_bytes=output_bytes):
        log.info("job %s was cancelled as it finished", job_id)
    return Outcome("succeeded")


def _failed(
    store: Store,
    job_id: str,
    owner: str,
    attempts: int,
    exc: Exception,
    memory_budget_mb: int,
    fail: Callable[[dict[str, Any]], Outcome],
) -> Outcome:
    """What one attempt that raised ``exc`` comes to (see the module docstring on retries)."""
    code = getattr(exc, "code", None)
    if _is_domain_error(exc) and isinstance(code, str):
        return fail(problem_document(code if code in PROBLEM_TYPES else "analysis-failed", str(exc)))
    if is_exhaustion(exc):
        log.warning("job %s: over its memory budget (%s: %s)", job_id, type(exc).__name__, exc)
        detail = (
            str(exc)
            if isinstance(exc, BudgetTooSmallError)
            else f"the analysis needed more memory than the budget of {memory_budget_mb} MiB of address "
            "space (EIGENSCOPE_JOB_MEMORY_MB); analyse a shorter window (parameters.frames) or a smaller "
            "clip, or ask the operator to raise the budget"
        )
        return fail(problem_document("resources-exhausted", detail))
    if is_infrastructure_fault(exc):
        log.warning("job %s: attempt %d met an infrastructure fault", job_id, attempts, exc_info=True)
        if attempts < store.max_attempts:
            store.release_job(job_id, owner)
            return Outcome("retry", retry_in_s=float(2**attempts))
        return fail(
            problem_document(
                "internal-error",
                f"the analysis failed {attempts} time(s) on a fault of the server; last error: "
                f"{type(exc).__name__}: {exc}",
            )
        )
    log.exception("job %s: attempt %d failed with an unexpected error (not retried)", job_id, attempts)
    return fail(
        problem_document(
            "analysis-crashed",
            f"the analysis failed with an unexpected error ({type(exc).__name__}: {exc}); it would fail "
            "the same way again, so it is not retried -- please report it with the clip",
        )
    )


def _fault_injection(clip: ClipRecord) -> None:
    """Test hooks (only called with ``test_hooks``): see :data:`KILL_WORKER_MARKER`."""
    if clip.filename.startswith(KILL_WORKER_MARKER):
        log.warning("test hook: killing worker process %d (clip %s)", os.getpid(), clip.id)
        os.kill(os.getpid(), signal.SIGKILL)


def _is_domain_error(exc: BaseException) -> bool:
    """True for :class:`workers.pipeline.errors.EigenscopeError` (looked up without importing it here)."""
    return any(
        cls.__module__ == "workers.pipeline.errors" and cls.__name__ == "EigenscopeError"
        for cls in type(exc).__mro__
    )
