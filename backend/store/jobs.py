"""The store's jobs as the API sees them: queued, found, listed, cancelled, deleted and expired, and the
bookkeeping of their queue messages. How a worker claims and holds one is :mod:`backend.store.leases`."""

from __future__ import annotations

import base64
import binascii
import re
import time
from collections.abc import Sequence
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from backend.errors import (
    ConflictError,
    InvalidInputError,
    NotFoundError,
    QuotaExceededError,
    problem_document,
)
from backend.store.engine import (
    StoreBase,
    _ended,
    _scoped_key,
    _winner_of_race,
    new_id,
    storage_quota_error,
    utcnow,
)
from backend.store.records import (
    ACTIVE,
    ANY_OWNER,
    NO_LIMITS,
    STREAM_ACTIVE,
    TERMINAL,
    JobRecord,
    NewJob,
    TenantLimits,
)
from backend.store.schema import ClipRow, JobRow, StreamRow


def _encode_cursor(seq: int) -> str:
    return base64.urlsafe_b64encode(f"s{seq}".encode()).decode().rstrip("=")


#: A job sequence number a cursor may carry: a positive 63-bit integer (what both databases store).
_CURSOR = re.compile(r"^s([1-9][0-9]{0,17})$")


def _decode_cursor(cursor: str) -> int:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
        match = _CURSOR.match(raw)
        if match is None:
            raise ValueError(raw)
        return int(match.group(1))
    except (ValueError, binascii.Error, UnicodeDecodeError):
        raise InvalidInputError(
            f"cursor {cursor!r} is not valid; pass the next_cursor of a previous page", code="invalid-cursor"
        ) from None


class JobStore(StoreBase):
    """Jobs in the store (a part of :class:`~backend.store.Store`)."""

    def create_job(self, job: NewJob, *, limits: TenantLimits = NO_LIMITS) -> tuple[JobRecord, bool]:
        """Insert a queued job on one of ``job.owner``'s clips; returns ``(job, created)``.

        With an ``idempotency_key`` already used (by this owner) for the same ``request_hash`` the earlier
        job is returned with ``created=False``; used for another request it raises
        :class:`InvalidInputError`. With ``limits.max_active_jobs`` an owner who already has that many
        queued or running jobs gets :class:`QuotaExceededError`, as does, with ``limits.max_stored_bytes``,
        one whose clips and job outputs already take that much (the job's outputs would be stored too).
        """
        owner, key = job.owner, job.idempotency_key
        if key is not None:
            existing = self.job_by_idempotency_key(key, job.request_hash, owner)
            if existing is not None:
                return existing, False
        row = JobRow(
            id=new_id(),
            clip_id=job.clip_id,
            status="queued",
            progress=0.0,
            stage="queued",
            attempts=0,
            excitation=job.excitation,
            parameters=job.parameters,
            created_at=utcnow(),
            idempotency_key=_scoped_key(owner, key),
            request_hash=job.request_hash,
            enqueued_at=time.time(),
            version=0,
            owner=owner,
            expires_at=job.expires_at,
            output_bytes=0,
            callback_url=job.callback_url,
            callback_attempts=0,
            source=job.source,
            force_log=job.force_log,
            force_log_summary=job.force_log_summary,
        )
        try:
            with self._tx() as s:
                clip = s.get(ClipRow, job.clip_id)
                if clip is None or clip.owner != owner:
                    raise InvalidInputError(
                        f"clip {job.clip_id!r} does not exist (never uploaded, or deleted); "
                        "upload it with POST /v1/clips and use the returned id",
                        code="unknown-clip",
                    )
                self._check_job_quota(s, owner, limits)
                s.add(row)
        except IntegrityError as exc:
            # Lost a race with a request carrying the same key.
            return _winner_of_race(exc, key, self.job_by_idempotency_key, job.request_hash, owner), False
        return JobRecord.of(row), True

    def _check_job_quota(self, s: Session, owner: str, limits: TenantLimits) -> None:
        """Refuse (429) one more job of ``owner`` past ``limits``, in the transaction that inserts it."""
        if limits.max_active_jobs is None and limits.max_stored_bytes is None:
            return
        self._lock_owner(s, owner)
        usage = self._usage(s, owner)
        max_stored_bytes, max_active_jobs = limits.max_stored_bytes, limits.max_active_jobs
        if max_stored_bytes is not None and usage.stored_bytes >= max_stored_bytes:
            raise storage_quota_error(usage.stored_bytes, 0, max_stored_bytes, limits.retry_after_s)
        active = usage.active_jobs
        if max_active_jobs is not None and active >= max_active_jobs:
            raise QuotaExceededError(
                f"this API key already has {active} queued or running jobs, the most allowed "
                f"(EIGENSCOPE_MAX_ACTIVE_JOBS_PER_KEY={max_active_jobs}); wait for some to finish",
                code="too-many-jobs",
                retry_after_s=limits.retry_after_s,
                limit=max_active_jobs,
            )

    def job_by_idempotency_key(self, key: str, request_hash: str | None, owner: str = "") -> JobRecord | None:
        """The job ``owner`` created with ``key``; raises :class:`InvalidInputError` if it was for another
        request."""
        with self._tx(readonly=True) as s:
            row = s.scalars(select(JobRow).where(JobRow.idempotency_key == _scoped_key(owner, key))).first()
            if row is None:
                return None
            if row.request_hash != request_hash:
                raise InvalidInputError(
                    f"Idempotency-Key {key!r} was already used with a different request body (job {row.id}); "
                    "use a new key for a new request",
                    code="idempotency-key-reused",
                )
            return JobRecord.of(row)

    def find_job(self, job_id: str, owner: str | None = ANY_OWNER) -> JobRecord | None:
        """The job, if it exists and belongs to ``owner`` (any owner when None)."""
        with self._tx(readonly=True) as s:
            row = s.scalars(select(JobRow).where(JobRow.id == job_id)).first()
            if row is None or (owner is not None and row.owner != owner):
                return None
            return JobRecord.of(row)

    def job_force_log(self, job_id: str) -> dict[str, Any] | None:
        """The force log job ``job_id`` was sent with (``api_schemas.ForceLog`` as JSON), or None: read
        apart from the job's record, which only carries its summary."""
        with self._tx(readonly=True) as s:
            log: dict[str, Any] | None = s.scalar(select(JobRow.force_log).where(JobRow.id == job_id))
            return log

    def get_job(self, job_id: str, owner: str | None = ANY_OWNER) -> JobRecord:
        job = self.find_job(job_id, owner)
        if job is None:
            raise NotFoundError(f"no job with id {job_id!r}", code="job-not-found")
        return job

    def list_jobs(
        self,
        *,
        statuses: Sequence[str] = (),
        clip_id: str | None = None,
        limit: int = 20,
        cursor: str | None = None,
        owner: str | None = ANY_OWNER,
    ) -> tuple[list[JobRecord], str | None]:
        """Jobs newest first; returns the page and the cursor of the next page (None on the last)."""
        query = select(JobRow).order_by(JobRow.seq.desc()).limit(limit + 1)
        if owner is not None:
            query = query.where(JobRow.owner == owner)
        if statuses:
            query = query.where(JobRow.status.in_(list(statuses)))
        if clip_id is not None:
            query = query.where(JobRow.clip_id == clip_id)
        if cursor is not None:
            query = query.where(JobRow.seq < _decode_cursor(cursor))
        with self._tx(readonly=True) as s:
            rows = [JobRecord.of(r) for r in s.scalars(query).all()]
        if len(rows) > limit:
            return rows[:limit], _encode_cursor(rows[limit - 1].seq)
        return rows, None

    def cancel_job(self, job_id: str, owner: str | None = ANY_OWNER) -> JobRecord:
        """Cancel a queued or running job (a running worker stops at its next progress report)."""
        for _ in range(20):
            job = self.get_job(job_id, owner)
            if job.status == "cancelled":
                return job
            if job.status in ("succeeded", "failed"):
                raise ConflictError(
                    f"job {job_id} already {job.status}; only queued or running jobs can be cancelled",
                    code="job-finished",
                )
            values = {
                "status": "cancelled",
                "stage": "cancelled",
                "finished_at": utcnow(),
                "lease_owner": None,
                "lease_until": None,
            }
            if self._cas(job_id, job.status, _ended(values, time.time())):
                if job.source == "stream":  # its stream has ended too (its session stops at once)
                    problem = problem_document("stream-aborted", f"the stream's job {job_id} was cancelled")
                    with self._tx() as s:
                        s.execute(
                            update(StreamRow)
                            .where(StreamRow.job_id == job_id, StreamRow.status.in_(STREAM_ACTIVE))
                            .values(status="failed", error=problem, updated_at=utcnow())
                        )
                return self.get_job(job_id)
        raise ConflictError(f"job {job_id} is changing too fast to cancel; try again", code="job-busy")

    def delete_job(self, job_id: str, owner: str | None = ANY_OWNER) -> JobRecord:
        """Delete a job's record (a queued or running one is cancelled first); returns what it was.

        A worker still running it stops at its next progress report (its writes no longer land), and a
        callback not yet delivered is dropped with the record.
        """
        for _ in range(20):
            job = self.get_job(job_id, owner)
            if job.status in ACTIVE:
                self.cancel_job(job_id, owner)
                continue
            with self._tx() as s:
                res = s.execute(delete(JobRow).where(JobRow.id == job_id, JobRow.status.in_(TERMINAL)))
                if res.rowcount:  # type: ignore[attr-defined]
                    s.execute(delete(StreamRow).where(StreamRow.job_id == job_id))  # its stream's record
                    return job
        raise ConflictError(f"job {job_id} is changing too fast to delete; try again", code="job-busy")

    def _cas(self, job_id: str, status: str, values: dict[str, Any]) -> bool:
        """Update the job if its status is still ``status``; bump the version. True if it landed."""
        with self._tx() as s:
            res = s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.status == status)
                .values(version=JobRow.version + 1, **values)
            )
            return bool(res.rowcount)  # type: ignore[attr-defined]

    def mark_unpublished(self, job_id: str) -> None:
        """Flag a queued job whose message could not be published, so the next sweep publishes it."""
        with self._tx() as s:
            s.execute(
                update(JobRow).where(JobRow.id == job_id, JobRow.status == "queued").values(enqueued_at=0.0)
            )

    def queued_jobs(self, *, enqueued_before: float, limit: int = 100_000) -> dict[str, float]:
        """``{job id: enqueued_at}`` of the jobs waiting for a message's delivery (queued, not a stream's)
        published before ``enqueued_before`` (epoch seconds)."""
        with self._tx(readonly=True) as s:
            rows = s.execute(
                select(JobRow.id, JobRow.enqueued_at)
                .where(
                    JobRow.status == "queued",
                    JobRow.source != "stream",
                    JobRow.enqueued_at < enqueued_before,
                )
                .limit(limit)
            ).all()
        return {str(job_id): float(at or 0.0) for job_id, at in rows}

    def count_jobs_by_status(self) -> dict[str, int]:
        with self._tx(readonly=True) as s:
            rows = s.execute(select(JobRow.status, func.count()).group_by(JobRow.status)).all()
        return {str(status): int(n) for status, n in rows}

    def expired_jobs(self, now: float, limit: int = 500) -> list[JobRecord]:
        """Finished jobs whose time is up (active jobs are kept until they finish)."""
        query = (
            select(JobRow)
            .where(JobRow.expires_at.is_not(None), JobRow.expires_at < now, JobRow.status.in_(TERMINAL))
            .limit(limit)
        )
        with self._tx(readonly=True) as s:
            return [JobRecord.of(r) for r in s.scalars(query).all()]

    def delete_finished_job(self, job_id: str) -> bool:
        """Delete a job's record (and its stream's, if it was one) if it is finished; True if deleted."""
        with self._tx() as s:
            res = s.execute(delete(JobRow).where(JobRow.id == job_id, JobRow.status.in_(TERMINAL)))
            if res.rowcount:  # type: ignore[attr-defined]
                s.execute(delete(StreamRow).where(StreamRow.job_id == job_id))
            return bool(res.rowcount)  # type: ignore[attr-defined]
