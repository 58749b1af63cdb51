"""``/v1/jobs``: create, poll (or long-poll), list, cancel and delete analysis jobs; fetch their artifacts."""

from __future__ import annotations

import asyncio
import mimetypes
import time
from typing import Annotated

from fastapi import APIRouter, Header, Path, Query, Request, Response
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from api_schemas import ARTIFACT_NAMES, AnalysisResult, JobCreate, JobList, JobModel, JobStatus
from backend.store import TERMINAL
from service import jobs, views
from service.deps import ContextDep, Cursor, IdempotencyKey, PageSize, TenantDep
from service.openapi import ETAG_HEADER, RETRY_AFTER_HEADER, problem_responses

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

JobId = Annotated[str, Path(min_length=1, max_length=64, description="Job id from `create_job`.")]
IfNoneMatch = Annotated[
    str | None,
    Header(
        alias="If-None-Match",
        max_length=1024,
        description="The `ETag` of a representation the client holds: 304 while it is still current.",
    ),
]
#: Fastest and slowest re-read of a job while a long-poll waits.
_POLL_FIRST_S, _POLL_MAX_S = 0.05, 0.5


def _root(request: Request) -> str:
    return str(request.scope.get("root_path", ""))


@router.post(
    "",
    name="create_job",
    status_code=202,
    summary="Queue an analysis",
    description=(
        "Queue an analysis of an uploaded clip. Poll the job at the `Location` URL; the answer's `ETag` "
        "names the job as it is, so the first poll may already long-poll for a change "
        "(`GET /v1/jobs/{job_id}?wait=60` with `If-None-Match`). With an `Idempotency-Key` header a retried "
        "request returns the same job (`Idempotent-Replayed: true`); reusing the key for a different body "
        "is a 422."
    ),
    responses={
        **problem_responses(401, 408, 413, 422, 429, 503),
        202: {
            "headers": {
                "Location": {"description": "URL of the job", "schema": {"type": "string"}},
                "ETag": ETAG_HEADER,
                "Retry-After": {**RETRY_AFTER_HEADER, "description": "Seconds to wait before polling"},
                "Idempotent-Replayed": {
                    "description": "`true` when the job was created before with this Idempotency-Key",
                    "schema": {"type": "string", "enum": ["true"]},
                },
            }
        },
    },
)
def create_job(
    body: JobCreate,
    request: Request,
    response: Response,
    ctx: ContextDep,
    tenant: TenantDep,
    idempotency_key: IdempotencyKey = None,
) -> JobModel:
    job, created = jobs.create_job(ctx, body, tenant=tenant, idempotency_key=idempotency_key)
    view = views.job_view(job, root_path=_root(request))
    response.headers["Location"] = f"{_root(request)}/v1/jobs/{job.id}"
    # The same tag a GET of the job gives now: a client can long-poll for its first change at once.
    response.headers["ETag"] = views.etag_of(view.model_dump_json().encode())
    response.headers["Retry-After"] = str(ctx.settings.retry_after_s)
    if not created:
        response.headers["Idempotent-Replayed"] = "true"
    return view


@router.get(
    "",
    name="list_jobs",
    summary="List jobs, newest first",
    description=(
        "A page of job summaries: each job without its result, with the result's headline (`summary`) and "
        "the URL of the whole result (`result_url`, the job's `result.json`). Page on with `cursor` set "
        "to the previous page's `next_cursor`."
    ),
    responses=problem_responses(401, 422, 429, 503),
)
def list_jobs(
    request: Request,
    ctx: ContextDep,
    tenant: TenantDep,
    status: Annotated[list[JobStatus] | None, Query(description="Only jobs in these states.")] = None,
    clip_id: Annotated[str | None, Query(max_length=64, description="Only jobs of this clip.")] = None,
    limit: PageSize = 20,
    cursor: Cursor = None,
) -> JobList:
    statuses = [s.value for s in status] if status else []
    return jobs.list_jobs(
        ctx,
        tenant=tenant,
        statuses=statuses,
        clip_id=clip_id,
        limit=limit,
        cursor=cursor,
        root_path=_root(request),
    )


@router.get(
    "/{job_id}",
    name="get_job",
    summary="Poll a job",
    description=(
        "The job, with its `ETag`. **Long-poll** with `wait=SECONDS`: the answer comes as soon as the job "
        "has ended (or, with `If-None-Match`, as soon as it differs from that representation: new progress "
        "or stage), or when the wait runs out (then the job as it is; waits above the server's cap, 60 s by "
        "default, are cut to it). With `If-None-Match` naming the current representation the answer is "
        "304 without a body."
    ),
    response_model=JobModel,
    responses={
        200: {
            "headers": {
                "ETag": ETAG_HEADER,
                "Retry-After": {
                    **RETRY_AFTER_HEADER,
                    "description": "Seconds to wait before polling again (queued or running jobs)",
                },
            }
        },
        304: {
            "description": "Not Modified: the `If-None-Match` representation is current",
            "headers": {
                "ETag": ETAG_HEADER,
                "Retry-After": {
                    **RETRY_AFTER_HEADER,
                    "description": "Seconds to wait before polling again (queued or running jobs)",
                },
            },
        },
        **problem_responses(401, 404, 422, 429, 503),
    },
)
async def get_job(
    job_id: JobId,
    request: Request,
    ctx: ContextDep,
    tenant: TenantDep,
    wait: Annotated[
        float | None,
        Query(ge=0, description="Long-poll: wait up to this many seconds for the job to end or change."),
    ] = None,
    if_none_match: IfNoneMatch = None,
) -> Response:
    root = _root(request)
    deadline = time.monotonic() + min(wait or 0.0, ctx.settings.long_poll_max_s)
    interval = _POLL_FIRST_S
    while True:
        job = await run_in_threadpool(ctx.store.get_job, job_id, tenant)
        body = views.job_view(job, root_path=root).model_dump_json().encode()
        etag = views.etag_of(body)
        current = views.etag_matches(if_none_match, etag)
        left = deadline - time.monotonic()
        if wait is None or job.status in TERMINAL or (if_none_match and not current) or left <= 0:
            break
        if await request.is_disconnected():
            break
        await asyncio.sleep(min(interval, left))
        interval = min(interval * 1.5, _POLL_MAX_S)
    headers = {"ETag": etag, "Cache-Control": "no-cache"}
    if job.status not in TERMINAL:
        headers["Retry-After"] = str(ctx.settings.retry_after_s)
    if current:
        return Response(status_code=304, headers=headers)
    return Response(body, media_type="application/json", headers=headers)


@router.delete(
    "/{job_id}",
    name="delete_job",
    status_code=204,
    summary="Delete a job",
    description=(
        "Delete the job's record and its artifacts. A queued or running job is cancelled first; a webhook "
        "not yet delivered is dropped."
    ),
    responses=problem_responses(401, 404, 409, 429, 503),
)
async def delete_job(job_id: JobId, ctx: ContextDep, tenant: TenantDep) -> Response:
    await run_in_threadpool(jobs.delete_job, ctx, job_id, tenant)
    return Response(status_code=204)


@router.post(
    "/{job_id}/cancel",
    name="cancel_job",
    summary="Cancel a job",
    description=(
        "Cancel a queued or running job (best effort: a running analysis stops at its next progress "
        "report). The record stays, with status `cancelled`. 409 if the job already succeeded or failed."
    ),
    responses=problem_responses(401, 404, 409, 429, 503),
)
def cancel_job(job_id: JobId, request: Request, ctx: ContextDep, tenant: TenantDep) -> JobModel:
    return views.job_view(ctx.store.cancel_job(job_id, tenant), root_path=_root(request))


@router.get(
    "/{job_id}/result",
    name="get_job_result",
    summary="A job's result",
    description=(
        "The `AnalysisResult` of a succeeded job (its `artifacts` as URLs), with an `ETag` (a result never "
        "changes): with `If-None-Match` naming it the answer is 304 without a body. 404 "
        "(`result-not-found`) while the job has no result. Job lists link here (`result_url`)."
    ),
    response_model=AnalysisResult,
    responses={
        200: {"headers": {"ETag": ETAG_HEADER}},
        304: {
            "description": "Not Modified: the `If-None-Match` result is current",
            "headers": {"ETag": ETAG_HEADER},
        },
        **problem_responses(401, 404, 429, 503),
    },
)
async def get_job_result(
    job_id: JobId, request: Request, ctx: ContextDep, tenant: TenantDep, if_none_match: IfNoneMatch = None
) -> Response:
    result = await run_in_threadpool(jobs.job_result, ctx, job_id, tenant=tenant, root_path=_root(request))
    body = result.model_dump_json().encode()
    headers = {"ETag": views.etag_of(body), "Cache-Control": "private, no-cache"}
    if views.etag_matches(if_none_match, headers["ETag"]):
        return Response(status_code=304, headers=headers)
    return Response(body, media_type="application/json", headers=headers)


@router.get(
    "/{job_id}/artifacts/{name}",
    name="get_job_artifact",
    summary="Download an artifact",
    description=(
        "A file the analysis produced, by name: the images (`image/png`, the mode animation `image/gif`), "
        "the mode shapes (`modes.npz`, `application/octet-stream`) and `result.json` (the job's result as "
        "the analysis wrote it, `application/json`; `get_job_result` serves it as a typed document), with "
        "an `ETag`: with `If-None-Match` naming it the answer is 304 without a body. The result's "
        "`artifacts` give each file's URL."
    ),
    response_class=FileResponse,
    responses={
        200: {
            "description": "The file, with its media type (`image/png` for images, `image/gif` for "
            "`modes.gif`, `application/json` for `result.json`).",
            "headers": {"ETag": ETAG_HEADER},
            # Files (binary) whatever their type, the images first and application/octet-stream before
            # application/json: generators (openapi-python-client takes the first media type it knows) then
            # return the bytes of any artifact. The result as a typed document is `get_job_result`.
            "content": {
                media: {"schema": {"type": "string", "format": "binary", "contentMediaType": media}}
                for media in ("image/png", "image/gif", "application/octet-stream", "application/json")
            },
        },
        304: {
            "description": "Not Modified: the `If-None-Match` file is current",
            "headers": {"ETag": ETAG_HEADER},
        },
        **problem_responses(401, 404, 429, 503),
    },
)
def get_job_artifact(
    job_id: JobId,
    name: Annotated[
        str,
        Path(
            min_length=1,
            max_length=128,
            description="Artifact file name: one the job's `result.artifacts` lists.",
            json_schema_extra={"enum": list(ARTIFACT_NAMES)},
        ),
    ],
    ctx: ContextDep,
    tenant: TenantDep,
    if_none_match: IfNoneMatch = None,
) -> Response:
    path = jobs.artifact_file(ctx, job_id, name, tenant=tenant)
    stat = path.stat()
    etag = views.etag_of(f"{job_id}/{path.name}/{stat.st_size}/{stat.st_mtime_ns}".encode())
    # The files of a job never change once published; private: each key sees only its own.
    headers = {"ETag": etag, "Cache-Control": "private, no-cache"}
    if views.etag_matches(if_none_match, etag):
        return Response(status_code=304, headers=headers)
    media_type = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    return FileResponse(
        path,
        media_type=media_type,
        filename=path.name,
        content_disposition_type="inline",
        headers=headers,
        stat_result=stat,
    )
