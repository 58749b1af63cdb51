"""``/v1/streams``: open live stream sessions, follow them, and their WebSocket (frames in, estimates out)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request, Response, WebSocket
from starlette.concurrency import run_in_threadpool

from api_schemas import StreamCreate, StreamList, StreamModel
from service import streams
from service.deps import ContextDep, TenantDep
from service.openapi import problem_responses

router = APIRouter(prefix="/v1/streams", tags=["streams"])

StreamId = Annotated[str, Path(min_length=1, max_length=64, description="Stream id from `create_stream`.")]


def _base(request: Request) -> tuple[str, str]:
    return str(request.base_url).rstrip("/"), str(request.scope.get("root_path", ""))


@router.post(
    "",
    name="create_stream",
    status_code=201,
    summary="Open a live stream",
    description=(
        "Open a live capture session. Connect to `websocket_url` (the same API key in `Authorization`), "
        "send frames as binary messages and receive `accepted`, `estimate`, `converged`, `result` and "
        "`error` messages: see the AsyncAPI document `/asyncapi.json`. The stream ends as a job "
        "(`job_id`) with its result and images, its frames kept as a clip (`clip_id`). Keep "
        "`resume_token` to reconnect after a dropped connection."
    ),
    responses={
        **problem_responses(401, 422, 429, 503),
        201: {"headers": {"Location": {"description": "URL of the stream", "schema": {"type": "string"}}}},
    },
)
async def create_stream(
    body: StreamCreate, request: Request, response: Response, ctx: ContextDep, tenant: TenantDep
) -> StreamModel:
    base, root = _base(request)
    stream = await streams.create_stream(ctx, body, tenant=tenant, base_url=base, root_path=root)
    response.headers["Location"] = f"{root}/v1/streams/{stream.id}"
    return stream


@router.get(
    "", name="list_streams", summary="List streams, newest first", responses=problem_responses(401, 429, 503)
)
def list_streams(
    request: Request,
    ctx: ContextDep,
    tenant: TenantDep,
    active: Annotated[bool, Query(description="Only streams that have not ended.")] = False,
    limit: Annotated[int, Query(ge=1, le=100, description="Page size.")] = 20,
) -> StreamList:
    base, root = _base(request)
    items = ctx.store.list_streams(owner=tenant, active=active, limit=limit)
    return StreamList(
        items=[streams.stream_view(s, ws_url=streams.websocket_url(base, root, s.id)) for s in items]
    )


@router.get(
    "/{stream_id}",
    name="get_stream",
    summary="Follow a stream",
    description="Its status, frames received, latest estimate and whether it converged.",
    responses=problem_responses(401, 404, 429, 503),
)
async def get_stream(
    stream_id: StreamId, request: Request, ctx: ContextDep, tenant: TenantDep
) -> StreamModel:
    base, root = _base(request)
    stream = await run_in_threadpool(ctx.store.get_stream, stream_id, tenant)
    return streams.stream_view(stream, ws_url=streams.websocket_url(base, root, stream.id))


@router.websocket("/{stream_id}", name="stream_socket")
async def stream_socket(websocket: WebSocket, stream_id: str) -> None:
    await streams.serve_websocket(websocket.app.state.ctx, websocket, stream_id)
