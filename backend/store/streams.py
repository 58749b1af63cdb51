"""The store's live streams: a session's record beside its clip and its job (ordinary rows of theirs,
``source='stream'``), its progress, and the end of a session whose worker or client is gone."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

from sqlalchemy import delete, select, update

from backend.errors import NotFoundError
from backend.store.engine import StoreBase, utcnow
from backend.store.records import (
    ACTIVE,
    ANY_OWNER,
    NO_LIMITS,
    STREAM_ACTIVE,
    ClipRecord,
    JobRecord,
    NewClip,
    NewJob,
    NewStream,
    StreamRecord,
    TenantLimits,
)
from backend.store.schema import ClipRow, JobRow, StreamRow


class StreamStore(StoreBase):
    """Live streams in the store (a part of :class:`~backend.store.Store`)."""

    if TYPE_CHECKING:  # the other parts' methods this one builds on

        def add_clip(self, clip: NewClip, *, limits: TenantLimits = NO_LIMITS) -> tuple[ClipRecord, bool]: ...
        def create_job(self, job: NewJob, *, limits: TenantLimits = NO_LIMITS) -> tuple[JobRecord, bool]: ...

    def create_stream(
        self, stream: NewStream, *, limits: TenantLimits = NO_LIMITS
    ) -> tuple[StreamRecord, JobRecord]:
        """Record a new stream with its (empty) clip and its queued job (``source='stream'``).

        The clip and the job take the stream's owner and expiry. ``limits`` apply as for a job.
        """
        owner, expires_at = stream.owner, stream.expires_at
        clip_record, _ = self.add_clip(replace(stream.clip, owner=owner, expires_at=expires_at))
        job = NewJob(
            clip_id=clip_record.id,
            excitation=stream.excitation,
            parameters=stream.parameters,
            owner=owner,
            expires_at=expires_at,
            source="stream",
        )
        try:
            job_record, _ = self.create_job(job, limits=limits)
        except BaseException:
            with self._tx() as s:
                s.execute(delete(ClipRow).where(ClipRow.id == clip_record.id))
            raise
        row = StreamRow(
            id=stream.stream_id,
            owner=owner,
            job_id=job_record.id,
            clip_id=clip_record.id,
            status="waiting",
            token_digest=stream.token_digest,
            request=stream.request,
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

    def delete_orphan_streams(self) -> int:
        """Delete the records (and last estimates) of streams whose job is gone (deleted by its owner
        before deleting a job removed its stream too); returns how many."""
        with self._tx() as s:
            res = s.execute(delete(StreamRow).where(StreamRow.job_id.not_in(select(JobRow.id))))
        return int(res.rowcount or 0)  # type: ignore[attr-defined]
