"""The store's engine: connections, transactions and schema (:class:`StoreBase`, which every part of
:class:`~backend.store.Store` builds on), and the helpers the parts share."""

from __future__ import annotations

import hashlib
import json
import secrets
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime
from typing import Any, TypeVar

from sqlalchemy import Engine, case, create_engine, event, func, inspect, select, text
from sqlalchemy.exc import IntegrityError, InterfaceError, OperationalError, ProgrammingError
from sqlalchemy.orm import Session, sessionmaker

from backend.errors import DatabaseUnavailableError, QuotaExceededError
from backend.store.records import ACTIVE, Usage
from backend.store.schema import _ADDED_COLUMNS, _ADDED_INDEXES, Base, ClipRow, JobRow


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


def _ended(values: dict[str, Any], now: float) -> dict[str, Any]:
    """``values`` of a move to a terminal status, plus: a job with a callback URL has its callback due."""
    has_callback = JobRow.callback_url.is_not(None)
    return {
        **values,
        "callback_status": case((has_callback, "pending"), else_=None),
        "callback_next_at": case((has_callback, now), else_=None),
    }


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


class StoreBase:
    """The engine every part of :class:`~backend.store.Store` builds on (see there).

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

    # Across the tables ---------------------------------------------------------------------

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
