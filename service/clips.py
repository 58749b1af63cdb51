"""Clip upload, lookup and deletion (the logic behind the ``/v1/clips`` routes)."""

from __future__ import annotations

import logging
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request

from api_schemas import ClipInfoModel
from service.context import ServiceContext
from service.errors import InsufficientStorageError, ServiceError
from service.multipart import receive_file
from service.probing import probe_clip
from service.store import ClipRecord, new_id

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


async def upload_clip(ctx: ServiceContext, request: Request) -> ClipInfoModel:
    """Stream the request's ``file`` field to storage, validate it in the probe, and record it."""
    limit = ctx.settings.max_upload_bytes
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > ctx.storage.free_bytes():
        raise InsufficientStorageError(
            f"the server has less free storage than the {int(declared)} bytes of this upload; try again later"
        )
    sink = ctx.storage.new_upload(limit)
    try:
        received = await receive_file(request, sink)
        sink.close()
        info = await run_in_threadpool(
            probe_clip,
            sink.path,
            timeout_s=ctx.settings.probe_timeout_s,
            memory_mb=ctx.settings.probe_memory_mb,
        )
        clip_id = new_id()
        filename = (received.filename or "clip")[-255:]
        relative = await run_in_threadpool(ctx.storage.keep_clip, sink, clip_id, received.filename)
        record = await run_in_threadpool(
            ctx.store.add_clip,
            clip_id=clip_id,
            filename=filename,
            path=relative,
            info=info,
            size_bytes=sink.size,
        )
    except ServiceError as exc:
        ctx.metrics.clips_rejected.labels(exc.code).inc()
        sink.discard()
        raise
    except BaseException:
        sink.discard()
        raise
    ctx.metrics.uploaded_bytes.inc(sink.size)
    log.info("clip %s: %s, %d bytes, %s", record.id, info.get("format"), record.size_bytes, filename)
    return clip_view(record)


def delete_clip(ctx: ServiceContext, clip_id: str) -> None:
    """Delete a clip unless an active job uses it (409); finished jobs keep their results."""
    ctx.store.delete_clip(clip_id)
    ctx.storage.delete_clip(clip_id)
