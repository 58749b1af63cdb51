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

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

from service.store import JobRecord

_DURATION_BUCKETS = (0.25, 0.5, 1, 2, 3, 5, 8, 13, 20, 30, 60, 120, 300, 600, 1800)
_WAIT_BUCKETS = (0.01, 0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 30, 60, 300, 1800)
_STAGE_BUCKETS = (0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 30, 120)


class WorkerMetrics:
    """The metrics above, in their own registry; implements :class:`workers.execution.JobObserver`."""

    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry if registry is not None else CollectorRegistry(auto_describe=False)
        r = self.registry
        self.duration = Histogram(
            "eigenscope_job_duration_seconds",
            "Run time of one job delivery, claim to end, by outcome",
            ["outcome"],
            registry=r,
            buckets=_DURATION_BUCKETS,
        )
        self.queue_wait = Histogram(
            "eigenscope_job_queue_wait_seconds",
            "Time a job waited in the queue before a worker claimed it",
            registry=r,
            buckets=_WAIT_BUCKETS,
        )
        self.stage = Histogram(
            "eigenscope_analysis_stage_seconds",
            "Time of each analysis stage",
            ["stage"],
            registry=r,
            buckets=_STAGE_BUCKETS,
        )
        self.failures = Counter(
            "eigenscope_job_failures", "Failed jobs by problem type", ["type"], registry=r
        )
        self.retries = Counter("eigenscope_job_retries", "Deliveries that ran a job again", registry=r)
        live = {"registry": r, "multiprocess_mode": "livesum"}
        self.busy = Gauge("eigenscope_worker_busy", "Worker processes running a job", **live)
        self.processes = Gauge("eigenscope_worker_processes", "Live worker pool processes", **live)

    def process_started(self) -> None:
        """In each pool process, once."""
        self.processes.set(1)
        self.busy.set(0)

    def started(self, job: JobRecord, *, queue_wait_s: float) -> None:
        self.busy.set(1)
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
        self.duration.labels(outcome).observe(duration_s)
        if outcome == "failed":
            self.failures.labels(failure or "unknown").inc()
        for stage, seconds in timings_s.items():
            self.stage.labels(stage).observe(seconds)


def process_stopped() -> None:
    """In a pool process that ends: its live gauges leave the sums."""
    if os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        from prometheus_client import multiprocess

        multiprocess.mark_process_dead(os.getpid())


def serve_metrics(port: int, *, host: str = "0.0.0.0") -> Any:
    """Serve every pool process's metrics (and the build info) on ``port``; returns the server."""
    from prometheus_client import start_http_server

    from service.metrics import BuildInfoCollector, multiprocess_registry

    registry = multiprocess_registry() or CollectorRegistry(auto_describe=False)
    registry.register(BuildInfoCollector("worker"))
    return start_http_server(port, addr=host, registry=registry)
