"""The workers' Celery application, built from :class:`backend.settings.Settings` by :func:`create_celery`.

The broker, queue and reliability settings come from :func:`backend.broker.celery_config`, which the API's
producer app (:func:`backend.broker.create_producer`) uses too: the API publishes ``run_job`` by task name
and never imports this package. The module-level app the ``celery`` command line needs lives in
:mod:`workers.celery_main`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

from celery import Celery

from backend.broker import APP_NAME, celery_config
from backend.settings import Settings
from backend.storage import Storage
from backend.store import Store

if TYPE_CHECKING:
    from workers.metrics import WorkerMetrics


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


def create_celery(settings: Settings | None = None) -> EigenscopeCelery:
    """Build the Celery app for ``settings`` (read from the environment when None)."""
    settings = settings if settings is not None else Settings()
    app = EigenscopeCelery(APP_NAME, set_as_current=False, include=["workers.tasks"])
    app.eigenscope_settings = settings
    app.conf.update(celery_config(settings))
    return app
