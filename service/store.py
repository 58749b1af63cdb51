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
import hashlib
import json
import os
import re
import secrets
import socket
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import Enum
from typing import Any, ClassVar, TypeVar

from sqlalchemy import (
    JSON,
    BigInteger,
    DateTime,
    Engine,
    Float,
    Index,
    Integer,
    String,
    and_,
    case,
    create_engine,
    delete,
    event,
    func,
    inspect,
    select,
    text,
    update,
)
from sqlalchemy.exc import IntegrityError, InterfaceError, OperationalError, ProgrammingError
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

from service.errors import (
    ConflictError,
    DatabaseUnavailableError,
    InvalidInputError,
    NotFoundError,
    QuotaExceededError,
    problem_document,
)
from service.storage import pid_alive

ACTIVE = ("queued", "running")
TERMINAL = ("succeeded", "failed", "cancelled")

#: ``owner`` argument meaning "any tenant" (the workers and the cleanup, never a request).
ANY_OWNER = None


def utcnow() -> datetime:
    return datetime.now(UTC)


def new_id() -> str:
    """A fresh, unguessable resource id: 128 random bits as 32 lowercase hex digits."""
    return secrets.token_hex(16)


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
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    owner: Mapped[str] = mapped_column(String(64), default="", server_default="", index=True)
    expires_at: Mapped[float | None] = mapped_column(Float, nullable=True, doc="Epoch seconds.")
    idempotency_key: Mapped[str | None] = mapped_column(String(255), nullable=True)
    content_sha256: Mapped[str | None] = mapped_column(String(64), nullable=True)

    __table_args__ = (Index("ix_eigenscope_clips_idempotency_key", "idempotency_key", unique=True),)


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
    owner: Mapped[str] = mapped_column(String(64), default="", server_default="", index=True)
    expires_at: Mapped[float | None] = mapped_column(Float, nullable=True, doc="Epoch seconds.")
    output_bytes: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    callback_url: Mapped[str | None] = mapped_column(String(2048), nullable=True)
    callback_status: Mapped[str | None] = mapped_column(
        String(16), nullable=True, index=True, doc="pending, delivered or failed; None while the job runs."
    )
    callback_attempts: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    callback_next_at: Mapped[float | None] = mapped_column(Float, nullable=True, doc="Epoch seconds.")
    callback_lease_until: Mapped[float | None] = mapped_column(Float, nullable=True, doc="Epoch seconds.")
    callback_error: Mapped[str | None] = mapped_column(String(500), nullable=True)
    source: Mapped[str] = mapped_column(String(16), default="upload", server_default="upload")


class StreamRow(Base):
    """A live stream session; its job and clip are ordinary rows of the other tables."""

    __tablename__ = "eigenscope_streams"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    owner: Mapped[str] = mapped_column(String(64), default="", index=True)
    job_id: Mapped[str] = mapped_column(String(64), index=True)
    clip_id: Mapped[str] = mapped_column(String(64))
    status: Mapped[str] = mapped_column(String(16), index=True)
    token_digest: Mapped[str] = mapped_column(String(64))
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    frames_received: Mapped[int] = mapped_column(Integer, default=0)
    converged: Mapped[bool] = mapped_column(default=False)
    last_estimate: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    error: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    updated_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    expires_at: Mapped[float | None] = mapped_column(Float, nullable=True, doc="Epoch seconds.")


#: Columns added after the first release: ``create_schema`` adds them to older tables.
_ADDED_COLUMNS: dict[str, dict[str, str]] = {
    "eigenscope_clips": {
        "owner": "VARCHAR(64) NOT NULL DEFAULT ''",
        "expires_at": "FLOAT",
        "idempotency_key": "VARCHAR(255)",
        "content_sha256": "VARCHAR(64)",
    },
    "eigenscope_jobs": {
        "owner": "VARCHAR(64) NOT NULL DEFAULT ''",
        "expires_at": "FLOAT",
        "output_bytes": "BIGINT NOT NULL DEFAULT 0",
        "callback_url": "VARCHAR(2048)",
        "callback_status": "VARCHAR(16)",
        "callback_attempts": "INTEGER NOT NULL DEFAULT 0",
        "callback_next_at": "FLOAT",
        "callback_lease_until": "FLOAT",
        "callback_error": "VARCHAR(500)",
        "source": "VARCHAR(16) NOT NULL DEFAULT 'upload'",
    },
}
#: Indexes of added columns, created with them.
_ADDED_INDEXES = (
    "CREATE UNIQUE INDEX IF NOT EXISTS ix_eigenscope_clips_idempotency_key "
    "ON eigenscope_clips (idempotency_key)",
    "CREATE INDEX IF NOT EXISTS ix_eigenscope_jobs_callback_status ON eigenscope_jobs (callback_status)",
)


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
    owner: str = ""
    expires_at: float | None = None
    content_sha256: str | None = None

    @classmethod
    def of(cls, row: ClipRow) -> ClipRecord:
        created = _aware(row.created_at)
        assert created is not None
        return cls(
            row.id,
            row.filename,
            row.path,
            dict(row.info),
            int(row.size_bytes),
            created,
            row.owner or "",
            row.expires_at,
            row.content_sha256,
        )


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
    owner: str = ""
    expires_at: float | None = None
    output_bytes: int = 0
    enqueued_at: float | None = None
    callback_url: str | None = None
    callback_status: str | None = None
    callback_attempts: int = 0
    callback_error: str | None = None
    source: str = "upload"

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
            owner=row.owner or "",
            expires_at=row.expires_at,
            output_bytes=int(row.output_bytes or 0),
            enqueued_at=row.enqueued_at,
            callback_url=row.callback_url,
            callback_status=row.callback_status,
            callback_attempts=int(row.callback_attempts or 0),
            callback_error=row.callback_error,
            source=row.source or "upload",
        )


@dataclass(frozen=True, slots=True)
class StreamRecord:
    id: str
    owner: str
    job_id: str
    clip_id: str
    status: str
    token_digest: str
    request: dict[str, Any]
    frames_received: int
    converged: bool
    last_estimate: dict[str, Any] | None
    error: dict[str, Any] | None
    created_at: datetime
    updated_at: datetime | None

    @classmethod
    def of(cls, row: StreamRow) -> StreamRecord:
        created = _aware(row.created_at)
        assert created is not None
        return cls(
            id=row.id,
            owner=row.owner or "",
            job_id=row.job_id,
            clip_id=row.clip_id,
            status=row.status,
            token_digest=row.token_digest,
            request=dict(row.request),
            frames_received=int(row.frames_received or 0),
            converged=bool(row.converged),
            last_estimate=row.last_estimate,
            error=row.error,
            created_at=created,
            updated_at=_aware(row.updated_at),
        )


#: Stream statuses of a session that has not ended.
STREAM_ACTIVE = ("waiting", "streaming", "finishing")


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
    return not pid_alive(int(pid_text))


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


def _encode_clip_cursor(created: datetime, clip_id: str) -> str:
    raw = f"c{created.astimezone(UTC).isoformat()}|{clip_id}"
    return base64.urlsafe_b64encode(raw.encode()).decode().rstrip("=")


def _decode_clip_cursor(cursor: str) -> tuple[datetime, str]:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
        stamp, sep, clip_id = raw[1:].partition("|")
        if not raw.startswith("c") or not sep or not clip_id:
            raise ValueError(raw)
        created = datetime.fromisoformat(stamp)
        if created.tzinfo is None:
            raise ValueError(raw)
        return created, clip_id
    except (ValueError, binascii.Error, UnicodeDecodeError):
        raise InvalidInputError(
            f"cursor {cursor!r} is not valid; pass the next_cursor of a previous page", code="invalid-cursor"
        ) from None


_R = TypeVar("_R")


def _winner_of_race(
    exc: IntegrityError,
    key: str | None,
    lookup: Callable[[str, str | None, str], _R | None],
    digest: str | None,
    owner: str,
) -> _R:
    """What an insert that broke a unique constraint lost to: the record already made with the same
    idempotency key (``lookup`` checks it was for the same request); else ``exc`` again."""
    existing = lookup(key, digest, owner) if key is not None else None
    if existing is None:
        raise exc
    return existing


def _ended(values: dict[str, Any], now: float) -> dict[str, Any]:
    """``values`` of a move to a terminal status, plus: a job with a callback URL has its callback due."""
    has_callback = JobRow.callback_url.is_not(None)
    return {
        **values,
        "callback_status": case((has_callback, "pending"), else_=None),
        "callback_next_at": case((has_callback, now), else_=None),
    }


#: The callback error of a callback given up because its last attempt never reported.
_UNFINISHED_ATTEMPT = "the last attempt did not finish (the API process delivering it stopped)"


def _problem_worker_lost(attempts: int) -> dict[str, Any]:
    return problem_document(
        "worker-lost",
        f"the worker running this job stopped {attempts} time(s) (crash, out of memory or time limit); "
        "the clip may be too large for the workers' memory",
    )


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
        # SQLite: reads get deferred transactions of their own, so polls never queue for the write lock.
        self._read_engine = self._make_engine(self.url, immediate=False) if self._sqlite else self.engine
        self._read_sessions = sessionmaker(self._read_engine, expire_on_commit=False)

    @property
    def _sqlite(self) -> bool:
        return self.url.startswith("sqlite")

    @staticmethod
    def _make_engine(url: str, *, immediate: bool = True) -> Engine:
        if url.startswith("sqlite"):
            engine = create_engine(
                url,
                connect_args={"timeout": 30, "check_same_thread": False},
                json_serializer=_dumps_finite,
            )

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
                # with "database is locked" under WAL instead of waiting for the busy timeout. Read-only
                # transactions (the read engine) stay deferred: WAL readers never block.
                conn.exec_driver_sql("BEGIN IMMEDIATE" if immediate else "BEGIN")

            return engine
        connect_args = {"connect_timeout": 5} if url.startswith("postgresql") else {}
        return create_engine(
            url,
            pool_pre_ping=True,
            pool_size=5,
            max_overflow=5,
            pool_timeout=10,
            connect_args=connect_args,
            json_serializer=_dumps_finite,
        )

    # Life cycle -----------------------------------------------------------------------------

    def create_schema(self) -> None:
        """Create the tables if they do not exist (safe to call from several processes at once)."""
        for attempt in range(5):
            try:
                Base.metadata.create_all(self.engine)
                self._add_missing_columns()
                return
            except (IntegrityError, ProgrammingError, OperationalError):
                if attempt == 4:
                    raise
                time.sleep(0.2 * (attempt + 1))

    def _add_missing_columns(self) -> None:
        """Bring tables made by an older release up to date (new columns only; nothing is dropped)."""
        inspector = inspect(self.engine)
        for table, columns in _ADDED_COLUMNS.items():
            present = {c["name"] for c in inspector.get_columns(table)}
            missing = {name: ddl for name, ddl in columns.items() if name not in present}
            if not missing:
                continue
            with self.engine.begin() as conn:
                for name, ddl in missing.items():
                    conn.exec_driver_sql(f"ALTER TABLE {table} ADD COLUMN {name} {ddl}")
        with self.engine.begin() as conn:
            for ddl in _ADDED_INDEXES:
                conn.exec_driver_sql(ddl)

    def ping(self) -> None:
        """Raise if the database cannot be reached."""
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))

    def dispose(self) -> None:
        self.engine.dispose()
        self._read_engine.dispose()

    @contextmanager
    def _tx(self, *, readonly: bool = False) -> Iterator[Session]:
        """A transaction; a database that cannot be reached becomes :class:`DatabaseUnavailableError`.

        ``readonly`` transactions must not write (on SQLite they do not hold the write lock).
        """
        sessions = self._read_sessions if readonly else self._sessions
        try:
            with sessions() as session, session.begin():
                yield session
        except (OperationalError, InterfaceError) as exc:
            raise DatabaseUnavailableError(
                f"the job database is unavailable ({type(exc.orig).__name__}); try again shortly"
            ) from exc

    def _lock_owner(self, s: Session, owner: str) -> None:
        """Serialise quota checks of one tenant (SQLite transactions are serial already)."""
        if self.engine.dialect.name == "postgresql":
            key = int.from_bytes(
                hashlib.sha256(f"eigenscope:{owner}".encode()).digest()[:8], "big", signed=True
            )
            s.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": key})

    def usage(self, owner: str) -> Usage:
        """What ``owner`` holds: active jobs and stored bytes (clips plus job outputs)."""
        with self._tx(readonly=True) as s:
            return self._usage(s, owner)

    @staticmethod
    def _usage(s: Session, owner: str) -> Usage:
        clip_bytes = s.scalar(
            select(func.coalesce(func.sum(ClipRow.size_bytes), 0)).where(ClipRow.owner == owner)
        )
        job_bytes = s.scalar(
            select(func.coalesce(func.sum(JobRow.output_bytes), 0)).where(JobRow.owner == owner)
        )
        active = s.scalar(
            select(func.count()).select_from(JobRow).where(JobRow.owner == owner, JobRow.status.in_(ACTIVE))
        )
        return Usage(active_jobs=int(active or 0), stored_bytes=int(clip_bytes or 0) + int(job_bytes or 0))

    # Clips ----------------------------------------------------------------------------------

    def add_clip(
        self,
        *,
        clip_id: str,
        filename: str,
        path: str,
        info: dict[str, Any],
        size_bytes: int,
        owner: str = "",
        expires_at: float | None = None,
        max_stored_bytes: int | None = None,
        retry_after_s: int | None = None,
        idempotency_key: str | None = None,
        content_sha256: str | None = None,
    ) -> tuple[ClipRecord, bool]:
        """Record an uploaded clip; returns ``(clip, created)``.

        With ``max_stored_bytes`` refuse (429) if the owner would exceed it. With an ``idempotency_key``
        that (this owner's) earlier upload of the same content already used, that clip is returned with
        ``created=False``; used for other content it raises :class:`InvalidInputError`.
        """
        row = ClipRow(
            id=clip_id,
            filename=filename,
            path=path,
            info=info,
            size_bytes=size_bytes,
            created_at=utcnow(),
            owner=owner,
            expires_at=expires_at,
            idempotency_key=_scoped_key(owner, idempotency_key),
            content_sha256=content_sha256,
        )
        try:
            with self._tx() as s:
                if max_stored_bytes is not None:
                    self._lock_owner(s, owner)
                    used = self._usage(s, owner).stored_bytes
                    if used + size_bytes > max_stored_bytes:
                        raise storage_quota_error(used, size_bytes, max_stored_bytes, retry_after_s)
                s.add(row)
        except IntegrityError as exc:
            # Lost a race with a request carrying the same key: its clip, if it is the same content.
            found = _winner_of_race(exc, idempotency_key, self.clip_by_idempotency_key, content_sha256, owner)
            return found, False
        return ClipRecord.of(row), True

    def clip_by_idempotency_key(
        self, key: str, content_sha256: str | None, owner: str = ""
    ) -> ClipRecord | None:
        """The clip ``owner`` uploaded with ``key``; raises :class:`InvalidInputError` if its content differs
        from ``content_sha256`` (None: do not compare)."""
        with self._tx(readonly=True) as s:
            row = s.scalars(select(ClipRow).where(ClipRow.idempotency_key == _scoped_key(owner, key))).first()
            if row is None:
                return None
            if content_sha256 is not None and row.content_sha256 != content_sha256:
                raise InvalidInputError(
                    f"Idempotency-Key {key!r} was already used to upload other content (clip {row.id}); "
                    "use a new key for a new upload",
                    code="idempotency-key-reused",
                )
            return ClipRecord.of(row)

    def list_clips(
        self, *, limit: int = 20, cursor: str | None = None, owner: str | None = ANY_OWNER
    ) -> tuple[list[ClipRecord], str | None]:
        """Clips newest first; returns the page and the cursor of the next page (None on the last)."""
        query = select(ClipRow).order_by(ClipRow.created_at.desc(), ClipRow.id.desc()).limit(limit + 1)
        if owner is not None:
            query = query.where(ClipRow.owner == owner)
        if cursor is not None:
            created, clip_id = _decode_clip_cursor(cursor)
            query = query.where(
                (ClipRow.created_at < created) | (and_(ClipRow.created_at == created, ClipRow.id < clip_id))
            )
        with self._tx(readonly=True) as s:
            rows = [ClipRecord.of(r) for r in s.scalars(query).all()]
        if len(rows) > limit:
            last = rows[limit - 1]
            return rows[:limit], _encode_clip_cursor(last.created_at, last.id)
        return rows, None

    def find_clip(self, clip_id: str, owner: str | None = ANY_OWNER) -> ClipRecord | None:
        """The clip, if it exists and belongs to ``owner`` (any owner when None)."""
        with self._tx(readonly=True) as s:
            row = s.get(ClipRow, clip_id)
            if row is None or (owner is not None and row.owner != owner):
                return None
            return ClipRecord.of(row)

    def get_clip(self, clip_id: str, owner: str | None = ANY_OWNER) -> ClipRecord:
        clip = self.find_clip(clip_id, owner)
        if clip is None:
            raise NotFoundError(f"no clip with id {clip_id!r}", code="clip-not-found")
        return clip

    def delete_clip(self, clip_id: str, owner: str | None = ANY_OWNER) -> ClipRecord:
        """Delete the clip's record; refuse while a queued or running job uses it."""
        with self._tx() as s:
            row = s.get(ClipRow, clip_id)
            if row is None or (owner is not None and row.owner != owner):
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
        owner: str = "",
        expires_at: float | None = None,
        max_active_jobs: int | None = None,
        retry_after_s: int | None = None,
        callback_url: str | None = None,
        source: str = "upload",
        max_stored_bytes: int | None = None,
    ) -> tuple[JobRecord, bool]:
        """Insert a queued job on one of ``owner``'s clips; returns ``(job, created)``.

        With an ``idempotency_key`` already used (by this owner) for the same ``request_hash`` the earlier
        job is returned with ``created=False``; used for another request it raises
        :class:`InvalidInputError`. With ``max_active_jobs`` an owner who already has that many queued or
        running jobs gets :class:`QuotaExceededError`, as does, with ``max_stored_bytes``, one whose clips
        and job outputs already take that much (the job's outputs would be stored too).
        """
        if idempotency_key is not None:
            existing = self.job_by_idempotency_key(idempotency_key, request_hash, owner)
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
            idempotency_key=_scoped_key(owner, idempotency_key),
            request_hash=request_hash,
            enqueued_at=time.time(),
            version=0,
            owner=owner,
            expires_at=expires_at,
            output_bytes=0,
            callback_url=callback_url,
            callback_attempts=0,
            source=source,
        )
        try:
            with self._tx() as s:
                clip = s.get(ClipRow, clip_id)
                if clip is None or clip.owner != owner:
                    raise InvalidInputError(
                        f"clip {clip_id!r} does not exist (never uploaded, or deleted); "
                        "upload it with POST /v1/clips and use the returned id",
                        code="unknown-clip",
                    )
                if max_active_jobs is not None or max_stored_bytes is not None:
                    self._lock_owner(s, owner)
                    usage = self._usage(s, owner)
                    if max_stored_bytes is not None and usage.stored_bytes >= max_stored_bytes:
                        raise storage_quota_error(usage.stored_bytes, 0, max_stored_bytes, retry_after_s)
                    active = usage.active_jobs
                    if max_active_jobs is not None and active >= max_active_jobs:
                        raise QuotaExceededError(
                            f"this API key already has {active} queued or running jobs, the most allowed "
                            f"(EIGENSCOPE_MAX_ACTIVE_JOBS_PER_KEY={max_active_jobs}); wait for some to "
                            "finish",
                            code="too-many-jobs",
                            retry_after_s=retry_after_s,
                            limit=max_active_jobs,
                        )
                s.add(row)
        except IntegrityError as exc:
            # Lost a race with a request carrying the same key.
            return _winner_of_race(
                exc, idempotency_key, self.job_by_idempotency_key, request_hash, owner
            ), False
        return JobRecord.of(row), True

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

    # Callbacks ---------------------------------------------------------------------------------

    def due_callbacks(self, *, limit: int) -> list[tuple[str, str]]:
        """``(job id, callback URL)`` of jobs whose callback is due and not leased, most overdue first."""
        now = time.time()
        query = (
            select(JobRow.id, JobRow.callback_url)
            .where(
                JobRow.callback_status == "pending",
                JobRow.callback_next_at <= now,
                (JobRow.callback_lease_until.is_(None)) | (JobRow.callback_lease_until < now),
            )
            .order_by(JobRow.callback_next_at)
            .limit(limit)
        )
        with self._tx(readonly=True) as s:
            return [(job_id, url or "") for job_id, url in s.execute(query).all()]

    def claim_callback(
        self, job_id: str, *, lease_s: float, max_attempts: int | None = None
    ) -> JobRecord | None:
        """Lease job ``job_id``'s due callback for one attempt (counted now); None when another process
        has it. A callback that already had ``max_attempts`` (its last attempt never reported: the process
        delivering it stopped) is given up instead, so the attempts never pass the maximum."""
        now = time.time()
        free = (JobRow.callback_lease_until.is_(None)) | (JobRow.callback_lease_until < now)
        with self._tx() as s:
            if max_attempts is not None:
                s.execute(
                    update(JobRow)
                    .where(
                        JobRow.id == job_id,
                        JobRow.callback_status == "pending",
                        JobRow.callback_attempts >= max_attempts,
                        free,
                    )
                    .values(
                        callback_status="failed",
                        callback_next_at=None,
                        callback_lease_until=None,
                        callback_error=func.coalesce(JobRow.callback_error, _UNFINISHED_ATTEMPT),
                    )
                )
            res = s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.callback_status == "pending", free)
                .values(callback_lease_until=now + lease_s, callback_attempts=JobRow.callback_attempts + 1)
            )
        if not res.rowcount:  # type: ignore[attr-defined]
            return None
        return self.find_job(job_id)

    def renew_callback_lease(self, job_id: str, *, lease_s: float) -> None:
        """Extend the lease of a callback being delivered (it must not pass to another process)."""
        with self._tx() as s:
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.callback_status == "pending")
                .values(callback_lease_until=time.time() + lease_s)
            )

    def claim_due_callbacks(
        self, *, limit: int, lease_s: float, max_attempts: int | None = None
    ) -> list[JobRecord]:
        """Jobs whose callback is due, each leased to the caller for ``lease_s`` (several API processes
        deliver without sending one callback twice at once); see :meth:`claim_callback`."""
        claimed = []
        for job_id, _url in self.due_callbacks(limit=limit):
            job = self.claim_callback(job_id, lease_s=lease_s, max_attempts=max_attempts)
            if job is not None:
                claimed.append(job)
        return claimed

    def record_callback(self, job_id: str, *, status: str, next_at: float | None, error: str | None) -> None:
        """The outcome of a delivery: ``delivered``, ``failed`` (given up) or ``pending`` again at
        ``next_at``."""
        with self._tx() as s:
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id)
                .values(
                    callback_status=status,
                    callback_next_at=next_at,
                    callback_lease_until=None,
                    callback_error=None if error is None else error[:500],
                )
            )

    # Streams -----------------------------------------------------------------------------------

    def create_stream(
        self,
        *,
        stream_id: str,
        owner: str,
        clip: dict[str, Any],
        job: dict[str, Any],
        token_digest: str,
        request: dict[str, Any],
        expires_at: float | None,
        max_active_jobs: int | None = None,
        retry_after_s: int | None = None,
        max_stored_bytes: int | None = None,
    ) -> tuple[StreamRecord, JobRecord]:
        """Record a new stream with its (empty) clip and its queued job (``source='stream'``).

        ``clip`` and ``job`` are the keyword arguments of :meth:`add_clip` and :meth:`create_job` (less
        owner and expiry). Quotas apply as for a job.
        """
        clip_record, _ = self.add_clip(owner=owner, expires_at=expires_at, **clip)
        try:
            job_record, _ = self.create_job(
                clip_id=clip_record.id,
                owner=owner,
                expires_at=expires_at,
                max_active_jobs=max_active_jobs,
                retry_after_s=retry_after_s,
                source="stream",
                max_stored_bytes=max_stored_bytes,
                **job,
            )
        except BaseException:
            with self._tx() as s:
                s.execute(delete(ClipRow).where(ClipRow.id == clip_record.id))
            raise
        row = StreamRow(
            id=stream_id,
            owner=owner,
            job_id=job_record.id,
            clip_id=clip_record.id,
            status="waiting",
            token_digest=token_digest,
            request=request,
            frames_received=0,
            converged=False,
            created_at=utcnow(),
            expires_at=expires_at,
        )
        with self._tx() as s:
            s.add(row)
        return StreamRecord.of(row), job_record

    def find_stream(self, stream_id: str, owner: str | None = ANY_OWNER) -> StreamRecord | None:
        """The stream, if it exists and belongs to ``owner`` (any owner when None)."""
        with self._tx(readonly=True) as s:
            row = s.get(StreamRow, stream_id)
            if row is None or (owner is not None and row.owner != owner):
                return None
            return StreamRecord.of(row)

    def get_stream(self, stream_id: str, owner: str | None = ANY_OWNER) -> StreamRecord:
        stream = self.find_stream(stream_id, owner)
        if stream is None:
            raise NotFoundError(f"no stream with id {stream_id!r}", code="stream-not-found")
        return stream

    def list_streams(self, *, owner: str | None, active: bool, limit: int = 20) -> list[StreamRecord]:
        """Streams newest first (only those not ended when ``active``)."""
        query = select(StreamRow).order_by(StreamRow.created_at.desc()).limit(limit)
        if owner is not None:
            query = query.where(StreamRow.owner == owner)
        if active:
            query = query.where(StreamRow.status.in_(STREAM_ACTIVE))
        with self._tx(readonly=True) as s:
            return [StreamRecord.of(r) for r in s.scalars(query).all()]

    def update_stream(
        self, stream_id: str, *, only_active: bool = True, expect_status: str | None = None, **values: Any
    ) -> bool:
        """Set columns of a stream (while it has not ended, with ``only_active``; while its status is
        ``expect_status``, when given); True if it landed."""
        query = update(StreamRow).where(StreamRow.id == stream_id)
        if only_active:
            query = query.where(StreamRow.status.in_(STREAM_ACTIVE))
        if expect_status is not None:
            query = query.where(StreamRow.status == expect_status)
        with self._tx() as s:
            res = s.execute(query.values(updated_at=utcnow(), **values))
            return bool(res.rowcount)  # type: ignore[attr-defined]

    def update_clip(self, clip_id: str, *, path: str, info: dict[str, Any], size_bytes: int) -> None:
        """Fill in a stream's clip once its frames are written."""
        with self._tx() as s:
            s.execute(
                update(ClipRow)
                .where(ClipRow.id == clip_id)
                .values(path=path, info=info, size_bytes=size_bytes)
            )

    def fail_stream_job(self, job_id: str, problem: dict[str, Any]) -> bool:
        """Fail a stream's job whoever holds it (its session is gone); its stream too. True if it landed."""
        with self._tx() as s:
            res = s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.status.in_(ACTIVE), JobRow.source == "stream")
                .values(
                    version=JobRow.version + 1,
                    status="failed",
                    stage="failed",
                    error=problem,
                    finished_at=utcnow(),
                    lease_owner=None,
                    lease_until=None,
                )
            )
            landed = bool(res.rowcount)  # type: ignore[attr-defined]
            s.execute(
                update(StreamRow)
                .where(StreamRow.job_id == job_id, StreamRow.status.in_(STREAM_ACTIVE))
                .values(status="failed", error=problem, updated_at=utcnow())
            )
        return landed

    # Retention ---------------------------------------------------------------------------------

    def expired_jobs(self, now: float, limit: int = 500) -> list[JobRecord]:
        """Finished jobs whose time is up (active jobs are kept until they finish)."""
        query = (
            select(JobRow)
            .where(JobRow.expires_at.is_not(None), JobRow.expires_at < now, JobRow.status.in_(TERMINAL))
            .limit(limit)
        )
        with self._tx(readonly=True) as s:
            return [JobRecord.of(r) for r in s.scalars(query).all()]

    def expired_clips(self, now: float, limit: int = 500) -> list[ClipRecord]:
        """Clips whose time is up and that no queued or running job uses."""
        busy = select(JobRow.clip_id).where(JobRow.status.in_(ACTIVE))
        query = (
            select(ClipRow)
            .where(ClipRow.expires_at.is_not(None), ClipRow.expires_at < now, ClipRow.id.not_in(busy))
            .limit(limit)
        )
        with self._tx(readonly=True) as s:
            return [ClipRecord.of(r) for r in s.scalars(query).all()]

    def delete_finished_job(self, job_id: str) -> bool:
        """Delete a job's record (and its stream's, if it was one) if it is finished; True if deleted."""
        with self._tx() as s:
            res = s.execute(delete(JobRow).where(JobRow.id == job_id, JobRow.status.in_(TERMINAL)))
            if res.rowcount:  # type: ignore[attr-defined]
                s.execute(delete(StreamRow).where(StreamRow.job_id == job_id))
            return bool(res.rowcount)  # type: ignore[attr-defined]

    def delete_orphan_streams(self) -> int:
        """Delete the records (and last estimates) of streams whose job is gone (deleted by its owner
        before deleting a job removed its stream too); returns how many."""
        with self._tx() as s:
            res = s.execute(delete(StreamRow).where(StreamRow.job_id.not_in(select(JobRow.id))))
        return int(res.rowcount or 0)  # type: ignore[attr-defined]

    def existing_ids(self, clip_ids: Sequence[str], job_ids: Sequence[str]) -> tuple[set[str], set[str]]:
        """Which of these clip and job ids have records."""
        clips: set[str] = set()
        jobs: set[str] = set()
        with self._tx(readonly=True) as s:
            for start in range(0, len(clip_ids), 500):
                chunk = list(clip_ids[start : start + 500])
                clips |= set(s.scalars(select(ClipRow.id).where(ClipRow.id.in_(chunk))).all())
            for start in range(0, len(job_ids), 500):
                chunk = list(job_ids[start : start + 500])
                jobs |= set(s.scalars(select(JobRow.id).where(JobRow.id.in_(chunk))).all())
        return clips, jobs


@dataclass(frozen=True, slots=True)
class Usage:
    """What one tenant holds."""

    active_jobs: int
    stored_bytes: int


def storage_quota_error(used: int, adding: int, limit: int, retry_after_s: int | None) -> QuotaExceededError:
    """429 for a key whose stored clips and job outputs (``used`` bytes) cannot take ``adding`` more (0:
    a job or stream, whose outputs would be stored, on a key already at its quota)."""
    mib = 1024 * 1024
    more = f"{adding / mib:.1f} MiB more would exceed its quota of" if adding else "at least its quota of"
    return QuotaExceededError(
        f"this API key stores {used / mib:.1f} MiB of clips and results, {more} "
        f"{limit / mib:.0f} MiB (EIGENSCOPE_MAX_STORED_MB_PER_KEY); delete clips or jobs, or wait for old "
        "ones to expire",
        code="storage-quota-exceeded",
        retry_after_s=retry_after_s,
        limit_bytes=limit,
        used_bytes=used,
    )


def _scoped_key(owner: str, key: str | None) -> str | None:
    """Idempotency keys are per tenant: two keys' clients may pick the same string."""
    if key is None:
        return None
    if not owner:
        return key
    return f"{owner}:{hashlib.sha256(key.encode()).hexdigest()}"  # fits the 255-character column


def _dumps_finite(value: Any) -> str:
    """JSON for the store's JSON columns: NaN and infinities are refused (``ValueError``), never stored as
    tokens that PostgreSQL rejects and SQLite hands back as numbers no JSON schema allows."""
    return json.dumps(value, allow_nan=False)


def dumps_canonical(value: Any) -> str:
    """JSON with sorted keys and no spaces, for hashing request bodies."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)
