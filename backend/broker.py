"""The Celery broker both sides talk through: its options, the app configuration and the task names.

The API publishes jobs by task name with the small producer app of :func:`create_producer`; it never
imports :mod:`workers` (the task code, the runner or the pipeline). The workers build their consuming app
(:func:`workers.celery_app.create_celery`) from the same :func:`celery_config`, so both sides agree on the
broker, the queue and the serializer by construction.

Reliability settings: late acks, reject on worker lost, prefetch 1, soft and hard time limits, a Redis
visibility timeout above the hard limit, no result backend (the job row in the SQL store is the state).
Without ``EIGENSCOPE_REDIS_URL`` the broker is kombu's filesystem transport in ``DATA_DIR/broker``,
polled every ``broker_polling_interval_s`` seconds, with two changes (:class:`EmbeddedTransport`): a message
file appears in the queue folder only once it is written whole, and a worker asked to stop stops waiting
for messages at once.
"""

from __future__ import annotations

import os
import uuid
from time import monotonic
from typing import Any

from kombu.transport import filesystem
from kombu.utils.json import dumps

from backend.settings import Settings

#: The one task the API publishes: ``run_job(job_id)`` (registered by :mod:`workers.tasks`).
TASK_RUN_JOB = "eigenscope.run_job"

#: Name of the Celery app on both sides.
APP_NAME = "eigenscope"


class _EmbeddedChannel(filesystem.Channel):  # type: ignore[misc]
    """kombu's filesystem channel whose messages are written beside the queue and renamed into it.

    kombu's own ``_put`` creates ``<queue>.msg`` and then writes it; a consumer polling in between moves
    the empty file away, fails to decode it and the message is lost (the job stays queued for ever). A
    rename is atomic: the consumer sees no file or a whole one.
    """

    def _put(self, queue: str, payload: Any, **kwargs: Any) -> None:
        name = f"{round(monotonic() * 1000)}_{uuid.uuid4()}.{queue}.msg"
        final = os.path.join(self.data_folder_out, name)
        partial = os.path.join(self.data_folder_out, f"partial-{name}.part")  # matches no ``*.<queue>.msg``
        try:
            with open(partial, "wb") as fh:
                fh.write(dumps(payload).encode())
            os.replace(partial, final)
        except OSError as exc:
            raise filesystem.ChannelError(f"Cannot add file {final!r} to directory") from exc


#: A wait for messages on the embedded broker looks at a Celery worker's stop request this often, seconds.
STOP_CHECK_S = 0.25


class EmbeddedTransport(filesystem.Transport):  # type: ignore[misc]
    """The embedded broker's transport (``broker_transport``): kombu's filesystem one, whole messages only,
    and a wait for messages that ends when the worker is asked to stop.

    Celery's loop for a transport without asynchronous I/O waits up to 2 s for messages per turn
    (``drain_events(timeout=2.0)``) and looks at a stop request (a SIGTERM) only between turns: every
    ``eigenscope serve`` took 4.5-5.7 s to stop, idle. Here a wait looks at the request every
    :data:`STOP_CHECK_S` and ends at once when there is one (``celery.worker.state``, set only by a worker's
    signal handlers); otherwise it waits as long as it was asked to, as kombu's does.
    """

    Channel = _EmbeddedChannel

    def drain_events(self, connection: Any, timeout: float | None = None) -> Any:
        if timeout is None:
            return super().drain_events(connection, timeout=None)
        from celery.worker import state

        deadline = monotonic() + timeout
        while True:
            try:
                return super().drain_events(
                    connection, timeout=max(min(deadline - monotonic(), STOP_CHECK_S), 0.0)
                )
            except TimeoutError:
                # a stop request is an exit code (0 for a warm stop) or True; None or False when there is none
                flags = (state.should_stop, state.should_terminate)
                if any(f is not None and f is not False for f in flags) or monotonic() >= deadline:
                    raise


def ensure_broker_folders(settings: Settings) -> None:
    """Create the folders the embedded broker's producer and consumers share (``DATA_DIR/broker``)."""
    for sub in ("queue", "processed", "control"):
        (settings.broker_dir / sub).mkdir(parents=True, exist_ok=True)


def broker_options(settings: Settings) -> tuple[str, dict[str, Any]]:
    """Broker URL and transport options for ``settings`` (creating the embedded broker's folders)."""
    if settings.redis_url:
        return settings.redis_url, {
            "visibility_timeout": settings.effective_visibility_timeout_s,
            "socket_connect_timeout": 5,
            "socket_timeout": 30,
        }
    ensure_broker_folders(settings)
    root = settings.broker_dir
    queue_dir, processed, control = root / "queue", root / "processed", root / "control"
    return "filesystem://localhost//", {
        "data_folder_in": str(queue_dir),
        "data_folder_out": str(queue_dir),
        "store_processed": True,  # move (atomic rename) rather than copy to /tmp: one consumer per message
        "processed_folder": str(processed),
        "control_folder": str(control),
        "polling_interval": settings.broker_polling_interval_s,
    }


def celery_config(settings: Settings) -> dict[str, Any]:
    """The Celery configuration of both the producer (API) and the consumer (workers) for ``settings``."""
    broker_url, transport_options = broker_options(settings)
    embedded = settings.embedded
    return {
        "broker_url": broker_url,
        "broker_transport": None if settings.redis_url else f"{__name__}:EmbeddedTransport",
        "broker_transport_options": transport_options,
        "broker_connection_retry_on_startup": True,
        "broker_connection_timeout": 5,
        "task_default_queue": settings.queue,
        "task_routes": {TASK_RUN_JOB: {"queue": settings.queue}},
        "task_serializer": "json",
        "accept_content": ["json"],
        "task_ignore_result": True,
        "task_store_errors_even_if_ignored": False,
        "result_backend": None,
        "task_acks_late": True,
        "task_reject_on_worker_lost": True,
        "task_acks_on_failure_or_timeout": True,
        "worker_prefetch_multiplier": 1,
        "worker_cancel_long_running_tasks_on_connection_loss": True,
        "task_soft_time_limit": settings.task_soft_time_limit_s,
        "task_time_limit": settings.task_hard_time_limit_s,
        "task_publish_retry": True,
        "task_publish_retry_policy": {"max_retries": 2, "interval_start": 0, "interval_step": 0.5},
        "worker_max_tasks_per_child": 200,
        # Events and remote control feed Flower in Redis mode; the embedded broker skips their polling.
        "worker_send_task_events": not embedded,
        "task_send_sent_event": not embedded,
        "worker_enable_remote_control": not embedded,
        "timezone": "UTC",
        "enable_utc": True,
    }


def create_producer(settings: Settings) -> Any:
    """A Celery app that only publishes (``send_task`` by name): no task modules, no worker code."""
    from celery import Celery

    app = Celery(APP_NAME, set_as_current=False)
    app.conf.update(celery_config(settings))
    return app
