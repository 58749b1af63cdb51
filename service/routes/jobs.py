"""``/v1/jobs``: create, poll, list and cancel analysis jobs; fetch their artifacts."""

from __future__ import annotations

import mimetypes
from typing import Annotated

from fastapi import APIRouter, Header, Path, Query, Request, Response
from fastapi.responses import FileResponse

from api_schemas import JobCreate, JobList, JobModel, JobStatus
from service import jobs
from service.deps import ContextDep, TenantDep
from service.openapi import problem_responses

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

JobId = Annotated[str, Path(min_length=1, max_length=64, description="Job id from `create_job`.")]


def _root(request: Request) -> str:
    return str(request.scope.get("root_path", ""))


@router.post(
    "",
    name="create_job",
    status_code=202,
    summary="Queue an analysis",
    description=(
        "Queue an analysis of an uploaded clip. Poll the job at the `Location` URL. With an "
        "`Idempotency-Key` header a retried request returns the same job; reusing the key for a different "
        "body is a 422."
    ),
    responses={
        **problem_responses(401, 408, 413, 422, 429, 503),
        202: {
            "headers": {
                "Location": {"description": "URL of the job", "schema": {"type": "string"}},
                "Retry-After": {
                    "description": "Seconds to wait before polling",
                    "schema": {"type": "integer"},
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
    idempotency_key: Annotated[
        str | None,
        Header(
            alias="Idempotency-Key",
            min_length=1,
            max_length=255,
            description="Client-chosen key that makes retries of this request safe.",
        ),
    ] = None,
) -> JobModel:
    job, created = jobs.create_job(ctx, body, tenant=tenant, idempotency_key=idempotency_key)
    response.headers["Location"] = f"{_root(request)}/v1/jobs/{job.id}"
    response.headers["Retry-After"] = str(ctx.settings.retry_after_s)
    if not created:
        response.headers["Idempotent-Replayed"] = "true"
    return jobs.job_view(job, root_path=_root(request))


@router.get(
    "",
    name="list_jobs",
    summary="List jobs, newest first",
    responses=problem_responses(401, 422, 429, 503),
)
def list_jobs(
    request: Request,
    ctx: ContextDep,
    tenant: TenantDep,
    status: Annotated[list[JobStatus] | None, Query(description="Only jobs in these states.")] = None,
    clip_id: Annotated[str | None, Query(max_length=64, description="Only jobs of this clip.")] = None,
    limit: Annotated[int, Query(ge=1, le=100, description="Page size.")] = 20,
    cursor: Annotated[
        str | None, Query(max_length=64, description="`next_cursor` of the previous page.")
    ] = None,
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
    "/{job_id}", name="get_job", summary="Poll a job", responses=problem_responses(401, 404, 429, 503)
)
def get_job(
    job_id: JobId, request: Request, response: Response, ctx: ContextDep, tenant: TenantDep
) -> JobModel:
    job = ctx.store.get_job(job_id, tenant)
    if job.status in ("queued", "running"):
        response.headers["Retry-After"] = str(ctx.settings.retry_after_s)
    return jobs.job_view(job, root_path=_root(request))


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
    return jobs.job_view(ctx.store.cancel_job(job_id, tenant), root_path=_root(request))


@router.get(
    "/{job_id}/artifacts/{name}",
    name="get_job_artifact",
    summary="Download an artifact",
    description="A file the analysis produced (`mask.png`, other images, `result.json`).",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The file, with its media type (`image/png` for images, `application/json` "
            "for `result.json`).",
            "content": {
                "image/png": {"schema": {"type": "string", "format": "binary"}},
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            },
        },
        **problem_responses(401, 404, 429, 503),
    },
)
def get_job_artifact(
    job_id: JobId,
    name: Annotated[str, Path(min_length=1, max_length=128, description="Artifact file name.")],
    ctx: ContextDep,
    tenant: TenantDep,
) -> FileResponse:
    path = jobs.artifact_file(ctx, job_id, name, tenant=tenant)
    media_type = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    return FileResponse(path, media_type=media_type, filename=path.name, content_disposition_type="inline")
