"""Prometheus metrics of a worker: job durations, queue waits, per-stage analysis time, failures by problem
type, retries, busy and alive worker processes, build info.

A worker's pool processes write their metrics to files in ``PROMETHEUS_MULTIPROC_DIR`` (prometheus_client's
multiprocess mode), which ``eigenscope worker`` creates for itself before anything imports
prometheus_client. Its main process serves them on ``EIGENSCOPE_WORKER_METRICS_PORT`` (workers on other
machines expose their own); under ``eigenscope serve`` the worker shares the API's directory and the API's
``/metrics`` shows them.

Metrics:

=============================================  ==========  ==================================================
``eigenscope_job_duration_seconds{outcome}``   histogram   one delivery, claim to end (``succeeded``,
                                                           ``failed``, ``retry``, ``aborted``)
``eigenscope_job_queue_wait_seconds``          histogram   queued (or re-queued) until claimed
``eigenscope_analysis_stage_seconds{stage}``   histogram   the analysis's own timings (decode, flow, ...)
``eigenscope_job_failures_total{type}``        counter     failed jobs by problem type (``invalid-clip`` ...)
``eigenscope_job_retries_total``               counter     deliveries that ran a job again
``eigenscope_worker_busy``                     gauge       pool processes running a job now (sum)
``eigenscope_worker_processes``                gauge       live pool processes (sum)
=============================================  ==========  ==================================================
"""

from __future__ import annotations

import os
from typing import Any

from prometheus_client import CollectorRegistry

from backend.metrics import WORKER_FAMILIES, WithDefaults
from backend.store import JobRecord


class WorkerMetrics:
    """The metrics above, in their own registry; implements :class:`workers.execution.JobObserver`."""

    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry if registry is not None else CollectorRegistry(auto_describe=False)
        made = {f.name: f.make(self.registry) for f in WORKER_FAMILIES}
        self.duration = made["eigenscope_job_duration_seconds"]
        self.queue_wait = made["eigenscope_job_queue_wait_seconds"]
        self.stage = made["eigenscope_analysis_stage_seconds"]
        self.failures = made["eigenscope_job_failures"]
        self.retries = made["eigenscope_job_retries"]
        self.busy = made["eigenscope_worker_busy"]
        self.processes = made["eigenscope_worker_processes"]

    def process_started(self) -> None:
        """In each pool process, once."""
        self.processes.set(1)
        self.busy.set(0)

    def started(self, job: JobRecord, *, queue_wait_s: float) -> None:
        self.busy.set(1)
        self.claimed(job, queue_wait_s=queue_wait_s)

    def claimed(self, job: JobRecord, *, queue_wait_s: float) -> None:
        """A job (an analysis or a live stream) was claimed after ``queue_wait_s`` in the queue."""
        self.queue_wait.observe(queue_wait_s)
        if job.attempts > 1:
            self.retries.inc()

    def finished(
        self,
        job: JobRecord,
        *,
        outcome: str,
        duration_s: float,
        failure: str | None,
        timings_s: dict[str, float],
    ) -> None:
        self.busy.set(0)
        self.ended(outcome=outcome, duration_s=duration_s, failure=failure, timings_s=timings_s)

    def ended(
        self, *, outcome: str, duration_s: float, failure: str | None, timings_s: dict[str, float]
    ) -> None:
        """A job (an analysis or a live stream) ended with ``outcome`` after ``duration_s``."""
        self.duration.labels(outcome).observe(duration_s)
        if outcome == "failed":
            self.failures.labels(failure or "unknown").inc()
        for key, seconds in timings_s.items():
            self.stage.labels(key).observe(seconds)


def process_stopped() -> None:
    """In a pool process that ends: its live gauges leave the sums."""
    if os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        from prometheus_client import multiprocess

        multiprocess.mark_process_dead(os.getpid())


def serve_metrics(port: int, *, host: str = "0.0.0.0") -> Any:
    """Serve every pool process's metrics (and the build info) on ``port``; returns the server."""
    from prometheus_client import start_http_server

    from backend.metrics import BuildInfoCollector, multiprocess_collector

    registry = CollectorRegistry(auto_describe=False)
    shared = multiprocess_collector()
    registry.register(WithDefaults([shared] if shared is not None else [], WORKER_FAMILIES))
    registry.register(BuildInfoCollector("worker"))
    return start_http_server(port, addr=host, registry=registry)
