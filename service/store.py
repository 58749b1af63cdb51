"""The job and clip store: SQLAlchemy over SQLite (default) or PostgreSQL.

The job row is the source of truth for a job's state; Celery only carries "run job X" messages. A worker
must *claim* a job before running it: the claim sets a lease (owner and expiry) and counts the attempt,
in one optimistic-concurrency update (``version`` column), so two deliveries of the same message never
run the job at the same time. The lease is renewed while the job runs; progress, completion and failure
writes only land while the writer still owns the lease, which is how cancellation and take-over reach a
running worker.

Records are returned as frozen dataclasses, never as live ORM objects.
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import socket
import time
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import Enum
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    DateTime,
    Engine,
    Float,
    Integer,
    String,
    create_engine,
    event,
    func,
    select,
    text,
    update,
)
from sqlalchemy.exc import IntegrityError, OperationalError, ProgrammingError
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

from service.errors import ConflictError, InvalidInputError, NotFoundError

ACTIVE = ("queued", "running")
TERMINAL = ("succeeded", "failed", "cancelled")


def utcnow() -> datetime:
    return datetime.now(UTC)


def new_id() -> str:
    """A fresh resource id: 32 lowercase hex digits."""
    return uuid.uuid4().hex


def normalize_database_url(url: str) -> str:
    """Use the psycopg 3 driver for bare ``postgresql://`` URLs (psycopg2 is not a dependency)."""
    for prefix in ("postgresql://", "postgres://"):
        if url.startswith(prefix):
            return "postgresql+psycopg://" + url[len(prefix) :]
    return url


class Base(DeclarativeBase):
    type_annotation_map: ClassVar[dict[Any, Any]] = {dict[str, Any]: JSON}


class ClipRow(Base):
    __tablename__ = "eigenscope_clips"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    filename: Mapped[str] = mapped_column(String(255))
    path: Mapped[str] = mapped_column(String(512), doc="Relative to the data directory.")
    info: Mapped[dict[str, Any]] = mapped_column(JSON)
    size_bytes: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class JobRow(Base):
    __tablename__ = "eigenscope_jobs"
    __table_args__ = {"sqlite_autoincrement": True}  # noqa: RUF012 - SQLAlchemy reads it per class

    seq: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    id: Mapped[str] = mapped_column(String(64), unique=True, index=True)
    clip_id: Mapped[str] = mapped_column(String(64), index=True)
    status: Mapped[str] = mapped_column(String(16), index=True)
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    stage: Mapped[str | None] = mapped_column(String(64), nullable=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    excitation: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    parameters: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    error: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    idempotency_key: Mapped[str | None] = mapped_column(String(255), unique=True, nullable=True)
    request_hash: Mapped[str | None] = mapped_column(String(64), nullable=True)
    lease_owner: Mapped[str | None] = mapped_column(String(255), nullable=True)
    lease_until: Mapped[float | None] = mapped_column(Float, nullable=True, doc="Epoch seconds.")
    enqueued_at: Mapped[float | None] = mapped_column(Float, nullable=True, doc="Epoch seconds.")
    version: Mapped[int] = mapped_column(Integer, default=0)


def _aware(value: datetime | None) -> datetime | None:
    if value is None or value.tzinfo is not None:
        return value
    return value.replace(tzinfo=UTC)  # SQLite drops the zone; we only ever store UTC


@dataclass(frozen=True, slots=True)
class ClipRecord:
    id: str
    filename: str
    path: str
    info: dict[str, Any]
    size_bytes: int
    created_at: datetime

    @classmethod
    def of(cls, row: ClipRow) -> ClipRecord:
        created = _aware(row.created_at)
        assert created is not None
        return cls(row.id, row.filename, row.path, dict(row.info), row.size_bytes, created)


@dataclass(frozen=True, slots=True)
class JobRecord:
    id: str
    seq: int
    clip_id: str
    status: str
    progress: float
    stage: str | None
    attempts: int
    excitation: dict[str, Any] | None
    parameters: dict[str, Any]
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    error: dict[str, Any] | None
    result: dict[str, Any] | None
    lease_owner: str | None
    lease_until: float | None

    @classmethod
    def of(cls, row: JobRow) -> JobRecord:
        created = _aware(row.created_at)
        assert created is not None
        return cls(
            id=row.id,
            seq=row.seq,
            clip_id=row.clip_id,
            status=row.status,
            progress=float(row.progress),
            stage=row.stage,
            attempts=row.attempts,
            excitation=row.excitation,
            parameters=dict(row.parameters),
            created_at=created,
            started_at=_aware(row.started_at),
            finished_at=_aware(row.finished_at),
            error=row.error,
            result=row.result,
            lease_owner=row.lease_owner,
            lease_until=row.lease_until,
        )


class ClaimOutcome(Enum):
    CLAIMED = "claimed"
    FINISHED = "finished"  # terminal (succeeded, failed or cancelled): drop the message
    BUSY = "busy"  # another live worker holds the lease: try again after `retry_in_s`
    MISSING = "missing"  # no such job: drop the message
    EXHAUSTED = "exhausted"  # attempts used up: the job was marked failed


@dataclass(frozen=True, slots=True)
class Claim:
    outcome: ClaimOutcome
    job: JobRecord | None = None
    retry_in_s: float = 0.0


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
    pid = int(pid_text)
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def _encode_cursor(seq: int) -> str:
    return base64.urlsafe_b64encode(f"s{seq}".encode()).decode().rstrip("=")


def _decode_cursor(cursor: str) -> int:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
        if not raw.startswith("s"):
            raise ValueError(raw)
        return int(raw[1:])
    except (ValueError, binascii.Error, UnicodeDecodeError):
        raise InvalidInputError(
            f"cursor {cursor!r} is not valid; pass the next_cursor of a previous page", code="invalid-cursor"
        ) from None


def _problem_worker_lost(attempts: int) -> dict[str, Any]:
    return {
        "type": "https://eigenscope.dev/problems/worker-lost",
        "title": "Worker lost",
        "status": 500,
        "detail": (
            f"the worker running this job stopped {attempts} time(s) (crash, out of memory or time limit); "
            "the clip may be too large for the workers' memory"
        ),
    }


class Store:
    """Jobs and clips in a SQL database.

    Parameters
    ----------
    url : str
        SQLAlchemy database URL. SQLite files get WAL mode, a busy timeout and immediate transactions, so
        several processes can share one file.
    lease_s : float
        How long a claim lasts without renewal.
    max_attempts : int
        Claims a job may have before it is failed instead of run again.
    """

    def __init__(self, url: str, *, lease_s: float = 30.0, max_attempts: int = 3) -> None:
        self.url = normalize_database_url(url)
        self.lease_s = lease_s
        self.max_attempts = max_attempts
        self.engine = self._make_engine(self.url)
        self._sessions = sessionmaker(self.engine, expire_on_commit=False)

    @staticmethod
    def _make_engine(url: str) -> Engine:
        if url.startswith("sqlite"):
            engine = create_engine(url, connect_args={"timeout": 30, "check_same_thread": False})

            @event.listens_for(engine, "connect")
            def _sqlite_connect(dbapi_conn: Any, _record: Any) -> None:
                dbapi_conn.isolation_level = None  # we issue BEGIN ourselves
                cur = dbapi_conn.cursor()
                cur.execute("PRAGMA journal_mode=WAL")
                cur.execute("PRAGMA synchronous=NORMAL")
                cur.execute("PRAGMA busy_timeout=30000")
                cur.close()

            @event.listens_for(engine, "begin")
            def _sqlite_begin(conn: Any) -> None:
                # Take the write lock up front: a deferred transaction that later writes can fail at once
                # with "database is locked" under WAL instead of waiting for the busy timeout.
                conn.exec_driver_sql("BEGIN IMMEDIATE")

            return engine
        return create_engine(url, pool_pre_ping=True, pool_size=5, max_overflow=5)

    # Life cycle -----------------------------------------------------------------------------

    def create_schema(self) -> None:
        """Create the tables if they do not exist (safe to call from several processes at once)."""
        for attempt in range(5):
            try:
                Base.metadata.create_all(self.engine)
                return
            except (IntegrityError, ProgrammingError, OperationalError):
                if attempt == 4:
                    raise
                time.sleep(0.2 * (attempt + 1))

    def ping(self) -> None:
        """Raise if the database cannot be reached."""
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))

    def dispose(self) -> None:
        self.engine.dispose()

    @contextmanager
    def _tx(self) -> Iterator[Session]:
        with self._sessions() as session, session.begin():
            yield session

    # Clips ----------------------------------------------------------------------------------

    def add_clip(
        self, *, clip_id: str, filename: str, path: str, info: dict[str, Any], size_bytes: int
    ) -> ClipRecord:
        row = ClipRow(
            id=clip_id, filename=filename, path=path, info=info, size_bytes=size_bytes, created_at=utcnow()
        )
        with self._tx() as s:
            s.add(row)
        return ClipRecord.of(row)

    def find_clip(self, clip_id: str) -> ClipRecord | None:
        with self._tx() as s:
            row = s.get(ClipRow, clip_id)
            return ClipRecord.of(row) if row is not None else None

    def get_clip(self, clip_id: str) -> ClipRecord:
        clip = self.find_clip(clip_id)
        if clip is None:
            raise NotFoundError(f"no clip with id {clip_id!r}", code="clip-not-found")
        return clip

    def delete_clip(self, clip_id: str) -> ClipRecord:
        """Delete the clip's record; refuse while a queued or running job uses it."""
        with self._tx() as s:
            row = s.get(ClipRow, clip_id)
            if row is None:
                raise NotFoundError(f"no clip with id {clip_id!r}", code="clip-not-found")
            active = s.scalars(
                select(JobRow.id).where(JobRow.clip_id == clip_id, JobRow.status.in_(ACTIVE)).limit(5)
            ).all()
            if active:
                raise ConflictError(
                    f"clip {clip_id} is used by active job(s) {', '.join(active)}; cancel them first "
                    "(POST /v1/jobs/{id}/cancel) or wait for them to finish",
                    code="clip-in-use",
                )
            record = ClipRecord.of(row)
            s.delete(row)
        return record

    # Jobs: API side --------------------------------------------------------------------------

    def create_job(
        self,
        *,
        clip_id: str,
        excitation: dict[str, Any] | None,
        parameters: dict[str, Any],
        idempotency_key: str | None = None,
        request_hash: str | None = None,
    ) -> tuple[JobRecord, bool]:
        """Insert a queued job; returns ``(job, created)``.

        With an ``idempotency_key`` already used for the same ``request_hash`` the earlier job is returned
        with ``created=False``; used for another request it raises :class:`InvalidInputError`.
        """
        if idempotency_key is not None:
            existing = self.job_by_idempotency_key(idempotency_key, request_hash)
            if existing is not None:
                return existing, False
        row = JobRow(
            id=new_id(),
            clip_id=clip_id,
            status="queued",
            progress=0.0,
            stage="queued",
            attempts=0,
            excitation=excitation,
            parameters=parameters,
            created_at=utcnow(),
            idempotency_key=idempotency_key,
            request_hash=request_hash,
            enqueued_at=time.time(),
            version=0,
        )
        try:
            with self._tx() as s:
                if s.get(ClipRow, clip_id) is None:
                    raise InvalidInputError(
                        f"clip {clip_id!r} does not exist (never uploaded, or deleted); "
                        "upload it with POST /v1/clips and use the returned id",
                        code="clip-not-found",
                    )
                s.add(row)
        except IntegrityError:
            if idempotency_key is None:
                raise
            # Lost a race with a request carrying the same key.
            existing = self.job_by_idempotency_key(idempotency_key, request_hash)
            if existing is None:
                raise
            return existing, False
        return JobRecord.of(row), True

    def job_by_idempotency_key(self, key: str, request_hash: str | None) -> JobRecord | None:
        """The job created with ``key``; raises :class:`InvalidInputError` if it was for another request."""
        with self._tx() as s:
            row = s.scalars(select(JobRow).where(JobRow.idempotency_key == key)).first()
            if row is None:
                return None
            if row.request_hash != request_hash:
                raise InvalidInputError(
                    f"Idempotency-Key {key!r} was already used with a different request body (job {row.id}); "
                    "use a new key for a new request",
                    code="idempotency-key-reused",
                )
            return JobRecord.of(row)

    def find_job(self, job_id: str) -> JobRecord | None:
        with self._tx() as s:
            row = s.scalars(select(JobRow).where(JobRow.id == job_id)).first()
            return JobRecord.of(row) if row is not None else None

    def get_job(self, job_id: str) -> JobRecord:
        job = self.find_job(job_id)
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
    ) -> tuple[list[JobRecord], str | None]:
        """Jobs newest first; returns the page and the cursor of the next page (None on the last)."""
        query = select(JobRow).order_by(JobRow.seq.desc()).limit(limit + 1)
        if statuses:
            query = query.where(JobRow.status.in_(list(statuses)))
        if clip_id is not None:
            query = query.where(JobRow.clip_id == clip_id)
        if cursor is not None:
            query = query.where(JobRow.seq < _decode_cursor(cursor))
        with self._tx() as s:
            rows = [JobRecord.of(r) for r in s.scalars(query).all()]
        if len(rows) > limit:
            return rows[:limit], _encode_cursor(rows[limit - 1].seq)
        return rows, None

    def cancel_job(self, job_id: str) -> JobRecord:
        """Cancel a queued or running job (a running worker stops at its next progress report)."""
        for _ in range(20):
            job = self.get_job(job_id)
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
            if self._cas(job_id, job.status, values):
                return self.get_job(job_id)
        raise ConflictError(f"job {job_id} is changing too fast to cancel; try again", code="job-busy")

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

    def count_jobs_by_status(self) -> dict[str, int]:
        with self._tx() as s:
            rows = s.execute(select(JobRow.status, func.count()).group_by(JobRow.status)).all()
        return {str(status): int(n) for status, n in rows}

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
                select(JobRow.id).where(JobRow.status == "queued", JobRow.enqueued_at < now - requeue_after_s)
            ).all()
        for job in running:
            expired = job.lease_until is None or job.lease_until < now or owner_is_dead_here(job.lease_owner)
            if not expired:
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

    # Jobs: worker side -----------------------------------------------------------------------

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

    def complete_job(self, job_id: str, owner: str, result: dict[str, Any]) -> bool:
        values = {
            "status": "succeeded",
            "stage": "done",
            "progress": 1.0,
            "result": result,
            "error": None,
            "finished_at": utcnow(),
            "lease_owner": None,
            "lease_until": None,
        }
        return self._owned_update(job_id, owner, values)

    def fail_job(self, job_id: str, owner: str, problem: dict[str, Any]) -> bool:
        values = {
            "status": "failed",
            "stage": "failed",
            "error": problem,
            "finished_at": utcnow(),
            "lease_owner": None,
            "lease_until": None,
        }
        return self._owned_update(job_id, owner, values)

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


def dumps_canonical(value: Any) -> str:
    """JSON with sorted keys and no spaces, for hashing request bodies."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)
