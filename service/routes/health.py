"""Liveness, readiness and Prometheus metrics."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import APIRouter, Request, Response
from pydantic import BaseModel, ConfigDict
from starlette.concurrency import run_in_threadpool

from backend.errors import UnauthorizedError, UnavailableError
from service.auth import check_metrics_token
from service.deps import ContextDep
from service.openapi import problem_responses

router = APIRouter(tags=["health"])
log = logging.getLogger(__name__)


class Health(BaseModel):
    model_config = ConfigDict(title="Health")

    status: str
    checks: dict[str, str] = {}


@router.get("/healthz", name="healthz", summary="The process is alive")
def healthz() -> Health:
    return Health(status="ok")


@router.get(
    "/readyz",
    name="readyz",
    summary="Database, broker and storage are reachable",
    responses=problem_responses(503),
)
async def readyz(ctx: ContextDep) -> Health:
    checks: dict[str, str] = {}

    def run(name: str, fn: Any) -> None:
        try:
            fn()
            checks[name] = "ok"
        except Exception:
            # The reason stays in the server's log: exception text names hosts, paths and drivers.
            log.warning("readiness check %s failed", name, exc_info=True)
            checks[name] = "failed"

    await run_in_threadpool(run, "database", ctx.store.ping)
    await run_in_threadpool(run, "broker", ctx.queue.ping)
    await run_in_threadpool(run, "storage", ctx.storage.check)
    failed = [k for k, v in checks.items() if v != "ok"]
    if failed:
        raise UnavailableError(f"not ready: {', '.join(failed)} unreachable", code="not-ready", checks=checks)
    return Health(status="ready", checks=checks)


@router.get(
    "/metrics",
    name="metrics",
    summary="Prometheus metrics",
    description="Needs `Authorization: Bearer <EIGENSCOPE_METRICS_TOKEN>` when that token is set; refused "
    "without it on a server with API keys (its counts span every key's jobs).",
    response_class=Response,
    responses={
        200: {"content": {"text/plain": {"schema": {"type": "string"}}}, "description": "Metrics"},
        **problem_responses(401, 429),
    },
)
def metrics(request: Request, ctx: ContextDep) -> Response:
    token = ctx.settings.metrics_token
    client = request.client.host if request.client is not None else ""
    authorization = request.headers.get("authorization")
    if token is not None:
        ctx.auth_limiter.check(client)
    try:
        check_metrics_token(token, ctx.keys.enabled, authorization)
    except UnauthorizedError:
        if token is not None and authorization:  # a wrong token was presented: a guess
            ctx.auth_limiter.failed(client)
        raise
    return Response(ctx.metrics.render(), media_type=ctx.metrics.content_type)
