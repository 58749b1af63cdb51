"""Liveness, readiness and Prometheus metrics."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Response
from pydantic import BaseModel, ConfigDict
from starlette.concurrency import run_in_threadpool

from service.deps import ContextDep
from service.errors import UnavailableError
from service.openapi import problem_responses

router = APIRouter(tags=["health"])


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
        except Exception as exc:
            checks[name] = f"failed: {type(exc).__name__}: {exc}"[:300]

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
    response_class=Response,
    responses={200: {"content": {"text/plain": {"schema": {"type": "string"}}}, "description": "Metrics"}},
)
def metrics(ctx: ContextDep) -> Response:
    return Response(ctx.metrics.render(), media_type=ctx.metrics.content_type)
