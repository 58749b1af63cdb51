"""The FastAPI application factory: ``uvicorn --factory service.app:create_app``.

The app reads its :class:`~backend.settings.Settings` from the environment unless given some, keeps its
state in a :class:`~service.context.ServiceContext` on ``app.state.ctx``, and never imports the analysis
pipeline: jobs are published to the workers by task name.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.routing import APIRoute

from backend.logs import configure_logging
from backend.settings import Settings
from backend.version import __version__
from service.bodies import BodyCap, BodyLimits
from service.context import ServiceContext
from service.methods import MethodSemantics, PathMethods
from service.observability import RequestMiddleware
from service.openapi import install_openapi
from service.problems import install_problem_handlers
from service.routes import clips, health, jobs, page, streams
from service.routes.docs import install_docs

#: The OpenAPI and AsyncAPI ``info.version``: the package version, written once in ``backend/version.py``
#: (the URL's ``/v1`` is the API's major version).
API_VERSION = __version__

DESCRIPTION = (
    "Eigenscope measures eigenfrequency, damping, stiffness and mass of objects from RGB-D clips. Upload a "
    "clip, queue a job, poll it, fetch the result and its images. Every error is an RFC 9457 "
    "`application/problem+json` document."
)

log = logging.getLogger(__name__)


def _operation_id(route: APIRoute) -> str:
    return route.name


def create_app(settings: Settings | None = None, *, configure_log: bool | None = None) -> FastAPI:
    """Build the API for ``settings`` (from the environment when None).

    ``configure_log`` sets up the process's logging (:mod:`backend.logs`); by default it does when the
    settings come from the environment, as in the server processes (an app built for a test leaves the
    test's logging alone).
    """
    if configure_log is None:
        configure_log = settings is None
    settings = settings if settings is not None else Settings()
    if configure_log:
        configure_logging(settings.log_level, settings.log_format)
    ctx = ServiceContext.build(settings)

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        ctx.start()
        log.info(
            "eigenscope API ready: data %s, %s broker, store %s",
            settings.data_path,
            "embedded" if settings.embedded else "redis",
            ctx.store.engine.url.render_as_string(hide_password=True),
        )
        if ctx.keys.enabled:
            log.info(
                "API keys: %d configured; /v1 needs `Authorization: Bearer <key>`", len(ctx.keys.tenants)
            )
        else:
            log.warning(
                "no API keys configured (EIGENSCOPE_API_KEYS / EIGENSCOPE_API_KEYS_FILE): the API is OPEN, "
                "anyone who can reach it can read and delete every clip and job"
            )
        try:
            yield
        finally:
            ctx.stop()

    app = FastAPI(
        title="Eigenscope",
        version=API_VERSION,
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
        docs_url=None,
        redoc_url=None,
    )
    app.state.ctx = ctx
    app.add_middleware(
        BodyLimits,
        max_body_bytes=settings.max_json_body_bytes,
        idle_timeout_s=settings.body_idle_timeout_s,
        # A job request may carry a force log (api_schemas.ForceLog): up to 200,000 samples.
        route_caps={("POST", "/v1/jobs"): BodyCap(settings.max_job_body_bytes, "EIGENSCOPE_MAX_JOB_BODY_KB")},
        max_large_bodies=settings.max_large_bodies_in_flight,
    )
    install_problem_handlers(app)
    app.include_router(clips.router)
    app.include_router(jobs.router)
    app.include_router(streams.router)
    app.include_router(health.router)
    page.install_page(app)
    install_docs(app)
    install_openapi(app, version=API_VERSION, description=DESCRIPTION)

    app.add_middleware(MethodSemantics, methods_of=PathMethods(app.openapi))
    app.add_middleware(RequestMiddleware, metrics=ctx.metrics)
    return app
