"""What the store hands out and takes in: frozen records of rows (never live ORM objects), claims, a
tenant's usage and limits, and the new clips, jobs and streams to record."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from enum import Enum
from typing import Any

from backend.store.schema import ClipRow, JobRow, StreamRow

ACTIVE = ("queued", "running")
TERMINAL = ("succeeded", "failed", "cancelled")

#: ``owner`` argument meaning "any tenant" (the workers and the cleanup, never a request).
ANY_OWNER = None

#: Stream statuses of a session that has not ended.
STREAM_ACTIVE = ("waiting", "streaming", "finishing")


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
    #: What the job shows of the force log it was sent with (the log itself: ``JobStore.job_force_log``).
    force_log_summary: dict[str, Any] | None = None

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
            force_log_summary=row.force_log_summary,
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


@dataclass(frozen=True, slots=True)
class Usage:
    """What one tenant holds."""

    active_jobs: int
    stored_bytes: int


@dataclass(frozen=True, slots=True)
class TenantLimits:
    """What one tenant may hold when a clip, job or stream is added (None: no limit).

    ``max_active_jobs`` bounds its queued and running jobs, ``max_stored_bytes`` its clips and job outputs
    together; ``retry_after_s`` is the Retry-After of a refusal. A clip counts against the bytes only.
    """

    max_active_jobs: int | None = None
    max_stored_bytes: int | None = None
    retry_after_s: int | None = None


#: No limit at all (the workers', the tests' and the command line's default).
NO_LIMITS = TenantLimits()


@dataclass(frozen=True, slots=True)
class NewClip:
    """A clip to record (:meth:`~backend.store.clips.ClipStore.add_clip`): its row's fields.

    ``path`` is relative to the data directory. With an ``idempotency_key`` (scoped to the ``owner``), an
    earlier upload of the same ``content_sha256`` under that key is returned instead.
    """

    clip_id: str
    filename: str
    path: str
    info: dict[str, Any]
    size_bytes: int
    owner: str = ""
    expires_at: float | None = None
    idempotency_key: str | None = None
    content_sha256: str | None = None


@dataclass(frozen=True, slots=True)
class NewJob:
    """A job to queue (:meth:`~backend.store.jobs.JobStore.create_job`): its row's fields.

    With an ``idempotency_key`` (scoped to the ``owner``), an earlier job of the same ``request_hash``
    under that key is returned instead. ``source`` is ``upload`` or ``stream``. ``force_log`` is the
    request's force log (``api_schemas.ForceLog`` as JSON) and ``force_log_summary`` what the job shows of
    it (``api_schemas.ForceLogSummary``).
    """

    clip_id: str
    excitation: dict[str, Any] | None
    parameters: dict[str, Any]
    owner: str = ""
    expires_at: float | None = None
    callback_url: str | None = None
    source: str = "upload"
    idempotency_key: str | None = None
    request_hash: str | None = None
    force_log: dict[str, Any] | None = None
    force_log_summary: dict[str, Any] | None = None


@dataclass(frozen=True, slots=True)
class NewStream:
    """A live stream to record (:meth:`~backend.store.streams.StreamStore.create_stream`) with its (empty)
    clip and its job's excitation and parameters. The clip's owner and expiry are the stream's."""

    stream_id: str
    owner: str
    token_digest: str
    request: dict[str, Any]
    expires_at: float | None
    clip: NewClip
    excitation: dict[str, Any] | None
    parameters: dict[str, Any]
