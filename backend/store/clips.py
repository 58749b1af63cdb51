"""The store's clips: uploaded clips and the (empty, then filled in) clips of live streams."""

from __future__ import annotations

import base64
import binascii
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import and_, select, update
from sqlalchemy.exc import IntegrityError

from backend.errors import ConflictError, InvalidInputError, NotFoundError
from backend.store.engine import StoreBase, _scoped_key, _winner_of_race, storage_quota_error, utcnow
from backend.store.records import ACTIVE, ANY_OWNER, NO_LIMITS, ClipRecord, NewClip, TenantLimits
from backend.store.schema import ClipRow, JobRow


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


class ClipStore(StoreBase):
    """Clips in the store (a part of :class:`~backend.store.Store`)."""

    def add_clip(self, clip: NewClip, *, limits: TenantLimits = NO_LIMITS) -> tuple[ClipRecord, bool]:
        """Record an uploaded clip; returns ``(clip, created)``.

        With ``limits.max_stored_bytes`` refuse (429) if the owner would exceed it. With an
        ``idempotency_key`` that (this owner's) earlier upload of the same content already used, that clip
        is returned with ``created=False``; used for other content it raises :class:`InvalidInputError`.
        """
        owner, max_stored_bytes = clip.owner, limits.max_stored_bytes
        row = ClipRow(
            id=clip.clip_id,
            filename=clip.filename,
            path=clip.path,
            info=clip.info,
            size_bytes=clip.size_bytes,
            created_at=utcnow(),
            owner=owner,
            expires_at=clip.expires_at,
            idempotency_key=_scoped_key(owner, clip.idempotency_key),
            content_sha256=clip.content_sha256,
        )
        try:
            with self._tx() as s:
                if max_stored_bytes is not None:
                    self._lock_owner(s, owner)
                    used = self._usage(s, owner).stored_bytes
                    if used + clip.size_bytes > max_stored_bytes:
                        raise storage_quota_error(
                            used, clip.size_bytes, max_stored_bytes, limits.retry_after_s
                        )
                s.add(row)
        except IntegrityError as exc:
            # Lost a race with a request carrying the same key: its clip, if it is the same content.
            found = _winner_of_race(
                exc, clip.idempotency_key, self.clip_by_idempotency_key, clip.content_sha256, owner
            )
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

    def update_clip(self, clip_id: str, *, path: str, info: dict[str, Any], size_bytes: int) -> None:
        """Fill in a stream's clip once its frames are written."""
        with self._tx() as s:
            s.execute(
                update(ClipRow)
                .where(ClipRow.id == clip_id)
                .values(path=path, info=info, size_bytes=size_bytes)
            )

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
