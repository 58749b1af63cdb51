"""Clip upload, lookup and deletion (the logic behind the ``/v1/clips`` routes)."""

from __future__ import annotations

import logging
import time
import unicodedata
from pathlib import PurePosixPath
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request

from api_schemas import ClipInfoModel
from backend.errors import InsufficientStorageError, InvalidInputError, ServiceError, UnavailableError
from backend.storage import Quota
from backend.store import ClipRecord, NewClip, new_id, storage_quota_error
from service.context import ServiceContext
from service.multipart import receive_file
from service.probing import SLOW_PROBE_HOLD_S, SLOW_PROBE_MARKER, ProbeCaps, probe_clip
from service.retention import expiry

#: Slack for the multipart framing when the Content-Length is compared with a quota.
_FORM_OVERHEAD = 64 * 1024

log = logging.getLogger(__name__)


def clip_view(clip: ClipRecord) -> ClipInfoModel:
    """The API representation of a stored clip."""
    info: dict[str, Any] = dict(clip.info)
    return ClipInfoModel.model_validate(
        {
            **info,
            "id": clip.id,
            "filename": clip.filename,
            "size_bytes": clip.size_bytes,
            "created_at": clip.created_at,
        }
    )


def display_name(filename: str | None) -> str:
    """The upload's file name for display only: last path component, no control characters, 255 max.

    It is never used to build a path (the stored file is ``clips/<id>/clip<ext>``, the extension the
    server's, from the clip's content).
    """
    name = PurePosixPath((filename or "").replace("\\", "/")).name
    name = "".join(c for c in name if unicodedata.category(c)[0] != "C").strip()
    return name[-255:] or "clip"


async def _replay(
    ctx: ServiceContext, request: Request, existing: ClipRecord, idempotency_key: str
) -> tuple[ClipInfoModel, bool]:
    """A retried upload: its content (hashed as it arrives, then dropped) must be the first upload's."""
    sink = await run_in_threadpool(ctx.storage.new_upload, ctx.settings.max_upload_bytes, hashing=True)
    try:
        await receive_file(request, sink)
    finally:
        sink.discard()
    if sink.sha256 != existing.content_sha256:
        raise InvalidInputError(
            f"Idempotency-Key {idempotency_key!r} was already used to upload other content (clip "
            f"{existing.id}); use a new key for a new upload",
            code="idempotency-key-reused",
        )
    return clip_view(existing), False


async def upload_clip(
    ctx: ServiceContext, request: Request, tenant: str, *, idempotency_key: str | None = None
) -> tuple[ClipInfoModel, bool]:
    """Stream the request's ``file`` field to storage, validate it in the probe, and record it.

    Returns ``(clip, created)``: with an ``idempotency_key`` this tenant already uploaded the same content
    with, that clip and False. Refused before the body is read: 503 when the database or the storage is
    unavailable, 429 when the key's stored bytes are at their quota (or the declared size would pass it),
    507 when the disk is too full, 503 when ``max_uploads_in_flight`` uploads are being received already.
    A body that stalls is answered 408 (see :mod:`service.bodies`). A refused or failed upload leaves
    neither a file nor a record.
    """
    settings = ctx.settings
    if ctx.uploads_in_flight >= settings.max_uploads_in_flight:
        raise UnavailableError(
            f"{ctx.uploads_in_flight} uploads are in progress, the most this server receives at once "
            "(EIGENSCOPE_MAX_UPLOADS_IN_FLIGHT); try again shortly",
            code="too-many-uploads",
            retry_after_s=settings.quota_retry_after_s,
        )
    ctx.uploads_in_flight += 1  # one event loop: no other upload runs between the check and this
    try:
        return await _upload_clip(ctx, request, tenant, idempotency_key)
    finally:
        ctx.uploads_in_flight -= 1


async def _admit(ctx: ServiceContext, request: Request, tenant: str) -> Quota:
    """Refuse an upload its key's storage quota or the disk cannot take, from what is stored, what the
    key's other uploads hold and the declared size; returns the running count the body is checked
    against as it arrives (without a Content-Length, or with a false one, it stops at the quota)."""
    settings = ctx.settings
    quota = settings.max_stored_bytes_per_key
    used = (await run_in_threadpool(ctx.store.usage, tenant)).stored_bytes
    in_flight = ctx.upload_reservations.held(tenant)  # this key's other uploads being received
    declared_text = request.headers.get("content-length")
    declared = int(declared_text) if declared_text and declared_text.isdigit() else None
    if used + in_flight >= quota or (
        declared is not None and used + in_flight + declared - _FORM_OVERHEAD > quota
    ):
        raise storage_quota_error(used + in_flight, declared or 0, quota, settings.quota_retry_after_s)
    if declared is not None and declared > await run_in_threadpool(ctx.storage.free_bytes):
        raise InsufficientStorageError(
            f"the server has less free storage than the {declared} bytes of this upload; try again later"
        )
    return Quota(
        ctx.upload_reservations,
        tenant,
        quota - used,
        lambda held: storage_quota_error(used + held, 0, quota, settings.quota_retry_after_s),
    )


async def _upload_clip(
    ctx: ServiceContext, request: Request, tenant: str, idempotency_key: str | None
) -> tuple[ClipInfoModel, bool]:
    settings = ctx.settings
    if idempotency_key is not None:
        existing = await run_in_threadpool(ctx.store.clip_by_idempotency_key, idempotency_key, None, tenant)
        if existing is not None:
            return await _replay(ctx, request, existing, idempotency_key)
    running = await _admit(ctx, request, tenant)
    sink = await run_in_threadpool(
        ctx.storage.new_upload, settings.max_upload_bytes, hashing=idempotency_key is not None, quota=running
    )
    clip_id = new_id()
    kept = False
    try:
        received = await receive_file(request, sink)
        await run_in_threadpool(sink.give_name, received.filename)  # fsync: not on the event loop
        try:
            info = await run_in_threadpool(
                probe_clip,
                sink.path,
                timeout_s=settings.probe_timeout_s,
                memory_mb=settings.probe_memory_mb,
                caps=ProbeCaps(
                    max_frames=settings.max_frames,
                    max_pixels=settings.max_pixels_per_frame,
                    max_decoded_mb=settings.max_decoded_mb,
                    max_inflation_ratio=settings.max_inflation_ratio,
                    inflation_floor_mb=settings.inflation_floor_mb,
                ),
                scratch_dir=sink.path.parent,
                nice=settings.background_niceness,
                hold_s=SLOW_PROBE_HOLD_S
                if settings.test_hooks and display_name(received.filename).startswith(SLOW_PROBE_MARKER)
                else 0.0,
            )
        except ServiceError as exc:
            # The readers name the file they read (clip<ext>); the client knows it by its own name.
            exc.detail = exc.detail.replace(sink.path.name, display_name(received.filename))
            raise
        relative = await run_in_threadpool(ctx.storage.keep_clip, sink, clip_id, info.get("format"))
        kept = True
        clip = NewClip(
            clip_id=clip_id,
            filename=display_name(received.filename),
            path=relative,
            info=info,
            size_bytes=sink.size,
            owner=tenant,
            expires_at=expiry(time.time(), settings.retention_s),
            idempotency_key=idempotency_key,
            content_sha256=sink.sha256,
        )
        record, created = await run_in_threadpool(ctx.store.add_clip, clip, limits=ctx.tenant_limits)
        sink.release_quota()  # counted as a stored clip from now on
        if not created:  # a concurrent request with the same key and content won the race
            ctx.storage.delete_clip(clip_id)
            return clip_view(record), False
    except BaseException as exc:
        if isinstance(exc, ServiceError):
            ctx.metrics.clips_rejected.labels(exc.code).inc()
        sink.discard()
        if kept:
            ctx.storage.delete_clip(clip_id)
        raise
    ctx.metrics.uploaded_bytes.inc(sink.size)
    log.info("clip %s: %s, %d bytes, %r", record.id, info.get("format"), record.size_bytes, record.filename)
    return clip_view(record), True


def delete_clip(ctx: ServiceContext, clip_id: str, tenant: str) -> None:
    """Delete one of ``tenant``'s clips unless an active job uses it (409); finished jobs keep their
    results."""
    ctx.store.delete_clip(clip_id, tenant)
    ctx.storage.delete_clip(clip_id)
