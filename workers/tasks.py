"""Celery tasks. Thin: the work is :func:`workers.execution.execute_job`.

Only worker processes import this module (through the app's ``include``); importing it loads the
analysis pipeline once per worker, before the pool forks, so no job pays for it.
"""

from __future__ import annotations

import logging
from typing import Any

from celery import Task, shared_task
from celery.exceptions import MaxRetriesExceededError, SoftTimeLimitExceeded

from backend.broker import TASK_RUN_JOB
from backend.logs import traced
from workers.celery_app import EigenscopeCelery
from workers.execution import ExecutionLimits, execute_job
from workers.runner import job_runner

log = logging.getLogger(__name__)

#: Re-deliveries of a message whose job another live worker holds, before giving up on the message
#: (the API's sweep publishes the job again if its worker died).
MAX_BUSY_RETRIES = 100


@shared_task(  # type: ignore[untyped-decorator]
    name=TASK_RUN_JOB, bind=True, acks_late=True, reject_on_worker_lost=True, ignore_result=True
)
def run_job(self: Task, job_id: str) -> str:
    """Run job ``job_id`` (see :func:`workers.execution.execute_job`)."""
    app = self.app
    assert isinstance(app, EigenscopeCelery)
    ctx = app.context()
    # The trace of the request that created the job (W3C traceparent, in the message's headers).
    with traced(self.request.get("traceparent")):
        outcome = _execute(ctx, job_id)
    if outcome.retry_in_s is not None:
        try:
            raise self.retry(countdown=outcome.retry_in_s, max_retries=MAX_BUSY_RETRIES)
        except MaxRetriesExceededError:
            log.warning("job %s: giving up on this message after %d retries", job_id, MAX_BUSY_RETRIES)
    return str(outcome.status)


def _execute(ctx: Any, job_id: str) -> Any:
    return execute_job(
        ctx.store,
        ctx.storage.root,
        job_id,
        runner=job_runner(ctx.settings),
        limits=ExecutionLimits(
            progress_interval_s=ctx.settings.progress_interval_s,
            soft_time_limit_s=ctx.settings.task_soft_time_limit_s,
            timeout_errors=(SoftTimeLimitExceeded,),
            test_hooks=ctx.settings.test_hooks,
            memory_budget_mb=ctx.settings.job_memory_mb,
        ),
        observer=ctx.metrics,
    )
