"""Publishing jobs to the workers, by task name only (the API never imports the task code)."""

from __future__ import annotations

import json
import logging
import threading
import uuid
from typing import Any

from backend.broker import TASK_RUN_JOB, create_producer
from backend.logs import current_traceparent
from backend.settings import Settings

log = logging.getLogger(__name__)

#: kombu's Redis hash of the messages delivered to a worker and not acknowledged yet.
_UNACKED_KEY = "unacked"


def _job_of(message: dict[str, Any]) -> str:
    """The job id of a ``run_job`` message (its task id is ``<job id>-<8 hex>``)."""
    task_id = str(message["headers"]["id"])
    return task_id.rsplit("-", 1)[0]


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
        """Send ``run_job(job_id)``; raises if the broker cannot take it. The message carries the current
        W3C ``traceparent`` (the request's), so the worker's lines about the job name the trace."""
        # The task id starts with the job id, so Celery's own log lines name the job.
        task_id = f"{job_id}-{uuid.uuid4().hex[:8]}"
        traceparent = current_traceparent()
        self.app.send_task(
            TASK_RUN_JOB,
            args=[job_id],
            queue=self.settings.queue,
            ignore_result=True,
            task_id=task_id,
            headers={"traceparent": traceparent} if traceparent else None,
        )

    def held_job_ids(self, *, limit: int = 100_000) -> set[str] | None:
        """The ids of the jobs whose ``run_job`` message the broker holds, waiting or delivered and not yet
        acknowledged; None when it cannot say (the embedded broker, an unreachable Redis, a queue longer
        than ``limit``, a message it cannot read).

        Read from Redis as kombu keeps it: the queue's lists (``<queue>`` and its priority lists) and the
        ``unacked`` hash; a message's task id starts with its job id (:meth:`publish`).
        """
        if self.settings.embedded or not self.settings.redis_url:
            return None
        import redis

        client = redis.Redis.from_url(self.settings.redis_url, socket_connect_timeout=3, socket_timeout=10)
        queue = self.settings.queue
        try:
            keys = [queue, *client.scan_iter(match=f"{queue}\x06\x16*", count=100)]
            messages: list[Any] = []
            for key in keys:
                if client.llen(key) > limit:
                    return None
                messages += client.lrange(key, 0, -1)
            held: set[str] = set()
            for raw in messages:
                held.add(_job_of(json.loads(raw)))
            for raw in client.hvals(_UNACKED_KEY):
                held.add(_job_of(json.loads(raw)[0]))
        except (redis.RedisError, ValueError, KeyError, TypeError, IndexError, AttributeError):
            log.warning("cannot read the broker's messages; no reconciliation this time", exc_info=True)
            return None
        finally:
            client.close()
        return held

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
