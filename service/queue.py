"""Publishing jobs to the workers, by task name only (the API never imports the task code)."""

from __future__ import annotations

import logging
import threading
import uuid
from typing import Any

from service.broker import TASK_RUN_JOB, create_producer
from service.settings import Settings

log = logging.getLogger(__name__)


class JobQueue:
    """Publishes ``run_job`` messages through a producer-only Celery app (created lazily)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._app: Any = None
        self._lock = threading.Lock()

    @property
    def app(self) -> Any:
        with self._lock:
            if self._app is None:
                self._app = create_producer(self.settings)
            return self._app

    def publish(self, job_id: str) -> None:
        """Send ``run_job(job_id)``; raises if the broker cannot take it."""
        # The task id starts with the job id, so Celery's own log lines name the job.
        task_id = f"{job_id}-{uuid.uuid4().hex[:8]}"
        self.app.send_task(
            TASK_RUN_JOB, args=[job_id], queue=self.settings.queue, ignore_result=True, task_id=task_id
        )

    def ping(self) -> None:
        """Raise unless the broker is reachable."""
        if self.settings.embedded:
            folder = self.settings.broker_dir / "queue"
            if not folder.is_dir():
                raise OSError(f"embedded broker folder {folder} is missing")
            return
        with self.app.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, timeout=3)

    def close(self) -> None:
        with self._lock:
            if self._app is not None:
                try:
                    self._app.close()
                except Exception:  # pragma: no cover - shutdown best effort
                    log.debug("closing the Celery app failed", exc_info=True)
                self._app = None
