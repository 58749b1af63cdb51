"""How a worker holds a job: the claim (a lease with its owner and expiry, the attempt counted), its
renewal (:class:`Lease`, a heartbeat thread), the writes that land only while the lease is still the
writer's (progress, completion, failure, release), and the recovery of jobs whose lease ran out.

The claim is one optimistic-concurrency update (``version`` column), so two deliveries of the same message
never run the job at the same time; cancellation and take-over reach a running worker as writes that no
longer land.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import uuid
from typing import TYPE_CHECKING, Any, Protocol

from sqlalchemy import select, update

from backend.errors import problem_document
from backend.storage import pid_alive
from backend.store.engine import StoreBase, _ended, utcnow
from backend.store.records import ANY_OWNER, TERMINAL, Claim, ClaimOutcome, JobRecord
from backend.store.schema import JobRow

log = logging.getLogger(__name__)


def lease_owner_token() -> str:
    """``host/pid/random``: identifies one run of a job by one process."""
    return f"{socket.gethostname()}/{os.getpid()}/{uuid.uuid4().hex[:12]}"


def owner_is_dead_here(owner: str | None) -> bool:
    """True if ``owner`` names a process on this host that no longer exists."""
    if not owner:
        return False
    host, _, rest = owner.partition("/")
    pid_text = rest.partition("/")[0]
    if host != socket.gethostname() or not pid_text.isdigit():
        return False
    return not pid_alive(int(pid_text))


def _problem_worker_lost(attempts: int) -> dict[str, Any]:
    return problem_document(
        "worker-lost",
        f"the worker running this job stopped {attempts} time(s) (crash, out of memory or time limit); "
        "the clip may be too large for the workers' memory",
    )


class LeaseHolder(Protocol):
    """What :class:`Lease` needs of the store."""

    lease_s: float

    def renew_lease(self, job_id: str, owner: str) -> bool: ...


class Lease:
    """Renews the job's lease in a background thread; remembers if it was lost (``lost``).

    Use as a context manager around the run of a job claimed by ``owner``.
    """

    def __init__(self, store: LeaseHolder, job_id: str, owner: str) -> None:
        self.store, self.job_id, self.owner = store, job_id, owner
        self.lost = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"lease-{job_id[:8]}", daemon=True)

    def __enter__(self) -> Lease:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def _run(self) -> None:
        interval = max(self.store.lease_s / 3.0, 0.5)
        while not self._stop.wait(interval):
            try:
                if not self.store.renew_lease(self.job_id, self.owner):
                    self.lost.set()
                    return
            except Exception:  # the database blinked: try again; the lease outlives a few misses
                log.warning("job %s: lease renewal failed", self.job_id, exc_info=True)


class LeaseStore(StoreBase):
    """Claims and leases of jobs (a part of :class:`~backend.store.Store`)."""

    if TYPE_CHECKING:  # the other parts' methods this one builds on

        def get_job(self, job_id: str, owner: str | None = ANY_OWNER) -> JobRecord: ...
        def fail_stream_job(self, job_id: str, problem: dict[str, Any]) -> bool: ...

    def recover_stale_jobs(self, *, requeue_after_s: float) -> list[str]:
        """Requeue jobs whose worker died and republish long-queued jobs; returns ids to publish.

        A running job whose lease expired (or whose owner process on this host is gone) goes back to
        ``queued``; if it has used all attempts it fails instead. A job queued longer than
        ``requeue_after_s`` is published again in case its message was lost (duplicates are harmless:
        only one delivery can claim the job).
        """
        now = time.time()
        to_publish: list[str] = []
        with self._tx() as s:
            running = s.scalars(select(JobRow).where(JobRow.status == "running")).all()
            stale_queued = s.scalars(
                select(JobRow.id).where(
                    JobRow.status == "queued",
                    JobRow.enqueued_at < now - requeue_after_s,
                    JobRow.source != "stream",  # a stream's job is run by its session, never by a message
                )
            ).all()
        for job in running:
            expired = job.lease_until is None or job.lease_until < now or owner_is_dead_here(job.lease_owner)
            if not expired:
                continue
            if job.source == "stream":
                # A stream cannot be run again from a message: its frames were the session's.
                self.fail_stream_job(job.id, _problem_worker_lost(job.attempts))
                continue
            if job.attempts >= self.max_attempts:
                values: dict[str, Any] = {
                    "status": "failed",
                    "stage": "failed",
                    "finished_at": utcnow(),
                    "error": _problem_worker_lost(job.attempts),
                    "lease_owner": None,
                    "lease_until": None,
                }
                values = _ended(values, now)
            else:
                values = {"status": "queued", "stage": "requeued", "lease_owner": None, "lease_until": None}
                values["enqueued_at"] = now
            with self._tx() as s:
                res = s.execute(
                    update(JobRow)
                    .where(JobRow.id == job.id, JobRow.version == job.version)
                    .values(version=JobRow.version + 1, **values)
                )
            if res.rowcount and values["status"] == "queued":  # type: ignore[attr-defined]
                to_publish.append(job.id)
        for job_id in stale_queued:
            with self._tx() as s:
                res = s.execute(
                    update(JobRow)
                    .where(JobRow.id == job_id, JobRow.status == "queued")
                    .values(enqueued_at=now)
                )
            if res.rowcount:  # type: ignore[attr-defined]
                to_publish.append(job_id)
        return to_publish

    def claim_job(self, job_id: str, owner: str) -> Claim:
        """Take the job for ``owner``: status running, attempt counted, lease set.

        See :class:`ClaimOutcome` for what the caller does otherwise.
        """
        for _ in range(20):
            with self._tx() as s:
                row = s.scalars(select(JobRow).where(JobRow.id == job_id)).first()
                if row is None:
                    return Claim(ClaimOutcome.MISSING)
                job = JobRecord.of(row)
                version = row.version
            if job.status in TERMINAL:
                return Claim(ClaimOutcome.FINISHED, job)
            now = time.time()
            if job.status == "running":
                lease_left = (job.lease_until or 0.0) - now
                if lease_left > 0 and not owner_is_dead_here(job.lease_owner):
                    return Claim(ClaimOutcome.BUSY, job, retry_in_s=lease_left + 0.5)
            if job.attempts >= self.max_attempts:
                values: dict[str, Any] = {
                    "status": "failed",
                    "stage": "failed",
                    "finished_at": utcnow(),
                    "error": _problem_worker_lost(job.attempts),
                    "lease_owner": None,
                    "lease_until": None,
                }
                values = _ended(values, now)
                outcome = ClaimOutcome.EXHAUSTED
            else:
                values = {
                    "status": "running",
                    "stage": "starting",
                    "progress": 0.0,
                    "attempts": job.attempts + 1,
                    "started_at": job.started_at or utcnow(),
                    "lease_owner": owner,
                    "lease_until": now + self.lease_s,
                    "error": None,
                }
                outcome = ClaimOutcome.CLAIMED
            with self._tx() as s:
                res = s.execute(
                    update(JobRow)
                    .where(JobRow.id == job_id, JobRow.version == version)
                    .values(version=JobRow.version + 1, **values)
                )
                landed = bool(res.rowcount)  # type: ignore[attr-defined]
            if landed:
                return Claim(outcome, self.get_job(job_id))
        return Claim(ClaimOutcome.BUSY, None, retry_in_s=1.0)

    def _owned_update(self, job_id: str, owner: str, values: dict[str, Any]) -> bool:
        with self._tx() as s:
            res = s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.status == "running", JobRow.lease_owner == owner)
                .values(version=JobRow.version + 1, **values)
            )
            return bool(res.rowcount)  # type: ignore[attr-defined]

    def renew_lease(self, job_id: str, owner: str) -> bool:
        """Extend the lease; False if the job is no longer ours (cancelled or taken over)."""
        return self._owned_update(job_id, owner, {"lease_until": time.time() + self.lease_s})

    def report_progress(self, job_id: str, owner: str, stage: str, progress: float) -> bool:
        """Record stage and progress (and renew the lease); False if the job is no longer ours."""
        values = {
            "stage": stage[:64],
            "progress": min(max(float(progress), 0.0), 1.0),
            "lease_until": time.time() + self.lease_s,
        }
        return self._owned_update(job_id, owner, values)

    def complete_job(self, job_id: str, owner: str, result: dict[str, Any], *, output_bytes: int = 0) -> bool:
        values = {
            "output_bytes": int(output_bytes),
            "status": "succeeded",
            "stage": "done",
            "progress": 1.0,
            "result": result,
            "error": None,
            "finished_at": utcnow(),
            "lease_owner": None,
            "lease_until": None,
        }
        return self._owned_update(job_id, owner, _ended(values, time.time()))

    def fail_job(self, job_id: str, owner: str, problem: dict[str, Any]) -> bool:
        values = {
            "status": "failed",
            "stage": "failed",
            "error": problem,
            "finished_at": utcnow(),
            "lease_owner": None,
            "lease_until": None,
        }
        return self._owned_update(job_id, owner, _ended(values, time.time()))

    def release_job(self, job_id: str, owner: str, *, stage: str = "retrying") -> bool:
        """Give the job back to the queue (for a retry); the attempt stays counted."""
        values = {
            "status": "queued",
            "stage": stage,
            "lease_owner": None,
            "lease_until": None,
            "enqueued_at": time.time(),
        }
        return self._owned_update(job_id, owner, values)
