"""``/v1/clips``: upload, inspect and delete clips."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Request, Response
from starlette.concurrency import run_in_threadpool

from api_schemas import ClipInfoModel, ClipList
from service import clips
from service.deps import ContextDep, Cursor, IdempotencyKey, PageSize, TenantDep
from service.openapi import UPLOAD_REQUEST_BODY, problem_responses

router = APIRouter(prefix="/v1/clips", tags=["clips"])

ClipId = Annotated[str, Path(min_length=1, max_length=64, description="Clip id from `create_clip`.")]


@router.post(
    "",
    name="create_clip",
    status_code=201,
    summary="Upload a clip",
    description=(
        "Upload a clip as multipart/form-data, field `file`. The body is streamed to storage and the clip is "
        "validated before the response: 413 over the size cap (or a clip that would decode past the "
        "server's caps), 415 for a format Eigenscope does not read, 422 with the reader's message for a "
        "malformed clip, 408 when the body stalls, 503 while too many uploads are in progress. With an "
        "`Idempotency-Key` header a retried "
        "upload of the same content returns the same clip (`Idempotent-Replayed: true`); the key reused for "
        "other content is a 422."
    ),
    responses={
        **problem_responses(401, 408, 413, 415, 422, 429, 503, 507),
        201: {
            "headers": {
                "Location": {"description": "URL of the clip", "schema": {"type": "string"}},
                "Idempotent-Replayed": {
                    "description": "`true` when the clip was uploaded before with this Idempotency-Key",
                    "schema": {"type": "string"},
                },
            }
        },
    },
    openapi_extra=UPLOAD_REQUEST_BODY,
)
async def create_clip(
    request: Request,
    response: Response,
    ctx: ContextDep,
    tenant: TenantDep,
    idempotency_key: IdempotencyKey = None,
) -> ClipInfoModel:
    clip, created = await clips.upload_clip(ctx, request, tenant, idempotency_key=idempotency_key)
    response.headers["Location"] = f"{request.scope.get('root_path', '')}/v1/clips/{clip.id}"
    if not created:
        response.headers["Idempotent-Replayed"] = "true"
    return clip


@router.get(
    "",
    name="list_clips",
    summary="List clips, newest first",
    responses=problem_responses(401, 422, 429, 503),
)
def list_clips(
    ctx: ContextDep,
    tenant: TenantDep,
    limit: PageSize = 20,
    cursor: Cursor = None,
) -> ClipList:
    records, next_cursor = ctx.store.list_clips(limit=limit, cursor=cursor, owner=tenant)
    return ClipList(items=[clips.clip_view(c) for c in records], next_cursor=next_cursor)


@router.get(
    "/{clip_id}", name="get_clip", summary="Describe a clip", responses=problem_responses(401, 404, 429, 503)
)
def get_clip(clip_id: ClipId, ctx: ContextDep, tenant: TenantDep) -> ClipInfoModel:
    return clips.clip_view(ctx.store.get_clip(clip_id, tenant))


@router.delete(
    "/{clip_id}",
    name="delete_clip",
    status_code=204,
    summary="Delete a clip",
    description="Delete the clip file. Refused (409) while a queued or running job uses it.",
    responses=problem_responses(401, 404, 409, 429, 503),
)
async def delete_clip(clip_id: ClipId, ctx: ContextDep, tenant: TenantDep) -> Response:
    await run_in_threadpool(clips.delete_clip, ctx, clip_id, tenant)
    return Response(status_code=204)
