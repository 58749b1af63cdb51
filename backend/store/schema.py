"""The store's tables: clips, jobs and stream sessions (SQLAlchemy declarative rows), and the columns and
indexes :meth:`~backend.store.engine.StoreBase.create_schema` adds to tables made by older releases."""

from __future__ import annotations

from datetime import datetime
from typing import Any, ClassVar

from sqlalchemy import JSON, BigInteger, DateTime, Float, Index, Integer, String
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column


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
    force_log: Mapped[dict[str, Any] | None] = mapped_column(
        JSON,
        nullable=True,
        deferred=True,
        doc="The force log sent with the request (up to 200,000 samples): loaded only by the worker that "
        "runs the job (``JobStore.job_force_log``), never with the row.",
    )
    force_log_summary: Mapped[dict[str, Any] | None] = mapped_column(
        JSON, nullable=True, doc="What the job shows of its force log (``api_schemas.ForceLogSummary``)."
    )


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
        "force_log": "JSON",
        "force_log_summary": "JSON",
    },
}
#: Indexes of added columns, created with them.
_ADDED_INDEXES = (
    "CREATE UNIQUE INDEX IF NOT EXISTS ix_eigenscope_clips_idempotency_key "
    "ON eigenscope_clips (idempotency_key)",
    "CREATE INDEX IF NOT EXISTS ix_eigenscope_jobs_callback_status ON eigenscope_jobs (callback_status)",
)
