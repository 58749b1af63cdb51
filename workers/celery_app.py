"""The Celery application, built from :class:`service.settings.Settings` by :func:`create_celery`.

One function builds the app for both sides: the API uses it only to publish ``run_job`` messages by task
name (it never imports :mod:`workers.tasks`, the runner or the pipeline), the workers to consume them.
The module-level app the ``celery`` command line needs lives in :mod:`workers.celery_main`.

Reliability settings: late acks, reject on worker lost, prefetch 1, soft and hard time limits, a Redis
visibility timeout above the hard limit, no result backend (the job row in the SQL store is the state).
Without ``EIGENSCOPE_REDIS_URL`` the broker is kombu's filesystem transport in ``DATA_DIR/broker``,
polled every ``broker_polling_interval_s`` seconds.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from celery import Celery

from service.settings import Settings
from service.storage import Storage
from service.store import Store

if TYPE_CHECKING:
    from workers.metrics import WorkerMetrics

#: The one task the API publishes: ``run_job(job_id)``.
TASK_RUN_JOB = "eigenscope.run_job"


@dataclass(frozen=True)
class WorkerContext:
    """What a task needs, created once per worker process."""

    settings: Settings
    store: Store
    storage: Storage
    metrics: WorkerMetrics


class EigenscopeCelery(Celery):  # type: ignore[misc]
    """A Celery app that carries the Eigenscope settings and a per-process :class:`WorkerContext`."""

    eigenscope_settings: Settings
    _context: WorkerContext | None = None
    _context_pid: int | None = None

    def context(self) -> WorkerContext:
        """The store and storage of this process (recreated after a fork)."""
        if self._context is None or self._context_pid != os.getpid():
            from workers.metrics import WorkerMetrics

            settings = self.eigenscope_settings
            store = Store(
                settings.effective_database_url, lease_s=settings.lease_s, max_attempts=settings.max_attempts
            )
            storage = Storage(settings.data_path)
            self._context = WorkerContext(settings, store, storage, WorkerMetrics())
            self._context_pid = os.getpid()
        return self._context


def broker_options(settings: Settings) -> tuple[str, dict[str, Any]]:
    """Broker URL and transport options for ``settings`` (creating the embedded broker's folders)."""
    if settings.redis_url:
        return settings.redis_url, {
            "visibility_timeout": settings.effective_visibility_timeout_s,
            "socket_connect_timeout": 5,
            "socket_timeout": 30,
        }
    root = settings.broker_dir
    queue_dir, processed, control = root / "queue", root / "processed", root / "control"
    for folder in (queue_dir, processed, control):
        folder.mkdir(parents=True, exist_ok=True)
    return "filesystem://localhost//", {
        "data_folder_in": str(queue_dir),
        "data_folder_out": str(queue_dir),
        "store_processed": True,  # move (atomic rename) rather than copy to /tmp: one consumer per message
        "processed_folder": str(processed),
        "control_folder": str(control),
        "polling_interval": settings.broker_polling_interval_s,
    }


def create_celery(settings: Settings | None = None) -> EigenscopeCelery:
    """Build the Celery app for ``settings`` (read from the environment when None)."""
    settings = settings if settings is not None else Settings()
    broker_url, transport_options = broker_options(settings)
    app = EigenscopeCelery("eigenscope", set_as_current=False, include=["workers.tasks"])
    app.eigenscope_settings = settings
    embedded = settings.embedded
    app.conf.update(
        broker_url=broker_url,
        broker_transport_options=transport_options,
        broker_connection_retry_on_startup=True,
        broker_connection_timeout=5,
        task_default_queue=settings.queue,
        task_routes={TASK_RUN_JOB: {"queue": settings.queue}},
        task_serializer="json",
        accept_content=["json"],
        task_ignore_result=True,
        task_store_errors_even_if_ignored=False,
        result_backend=None,
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        task_acks_on_failure_or_timeout=True,
        worker_prefetch_multiplier=1,
        worker_cancel_long_running_tasks_on_connection_loss=True,
        task_soft_time_limit=settings.task_soft_time_limit_s,
        task_time_limit=settings.task_hard_time_limit_s,
        task_publish_retry=True,
        task_publish_retry_policy={"max_retries": 2, "interval_start": 0, "interval_step": 0.5},
        worker_max_tasks_per_child=200,
        # Events and remote control feed Flower in Redis mode; the embedded broker skips their polling.
        worker_send_task_events=not embedded,
        task_send_sent_event=not embedded,
        worker_enable_remote_control=not embedded,
        timezone="UTC",
        enable_utc=True,
    )
    return app
