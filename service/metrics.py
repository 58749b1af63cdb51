"""Prometheus metrics of the API (own registry, no global state), correct with several API processes.

With ``PROMETHEUS_MULTIPROC_DIR`` set (``eigenscope serve`` sets it for its API processes and its worker),
every process writes its counters and histograms to files there and a scrape sums them all
(``prometheus_client`` multiprocess mode): whichever process answers ``/metrics``, the numbers are the
service's. Without it the metrics are this process's.

Every family is declared once, in :data:`API_FAMILIES` and :data:`WORKER_FAMILIES` (the workers build
theirs from it), and every one is in every scrape from the start: a family no process has touched yet
(in multiprocess mode only touched ones have files) is shown with no sample, or at 0 when it has no
labels. ``eigenscope_jobs{status}`` is read from the job store at scrape time; ``eigenscope_build_info``
names the version.
"""

from __future__ import annotations

import logging
import os
import platform
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
)
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    InfoMetricFamily,
    Metric,
)

from service.store import Store

log = logging.getLogger(__name__)

JOB_STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")

_HTTP_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60)
_DURATION_BUCKETS = (0.25, 0.5, 1, 2, 3, 5, 8, 13, 20, 30, 60, 120, 300, 600, 1800)
_WAIT_BUCKETS = (0.01, 0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 30, 60, 300, 1800)
_STAGE_BUCKETS = (0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 30, 120)
_LATENCY_BUCKETS = (0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1, 1.5, 2, 3, 5, 10, 30)


@dataclass(frozen=True)
class Family:
    """One metric family: its name (a counter's without ``_total``), kind, help and labels."""

    name: str
    kind: Literal["counter", "gauge", "histogram"]
    help: str
    labels: tuple[str, ...] = ()
    buckets: tuple[float, ...] = ()

    def make(self, registry: CollectorRegistry) -> Any:
        """The prometheus_client metric of this family in ``registry`` (gauges sum live processes)."""
        labels = list(self.labels)
        if self.kind == "counter":
            return Counter(self.name, self.help, labels, registry=registry)
        if self.kind == "gauge":
            return Gauge(self.name, self.help, labels, registry=registry, multiprocess_mode="livesum")
        return Histogram(self.name, self.help, labels, registry=registry, buckets=self.buckets)

    def empty(self) -> Metric:
        """The family with no sample, or at 0 when it has no labels (what a scrape shows before any
        process has touched it)."""
        if self.kind == "counter":
            counter = CounterMetricFamily(self.name, self.help, labels=self.labels or None)
            if not self.labels:
                counter.add_metric([], 0.0)
            return counter
        if self.kind == "gauge":
            gauge = GaugeMetricFamily(self.name, self.help, labels=self.labels or None)
            if not self.labels:
                gauge.add_metric([], 0.0)
            return gauge
        histogram = HistogramMetricFamily(self.name, self.help, labels=self.labels or None)
        if not self.labels:
            buckets = [(str(float(b)), 0.0) for b in self.buckets] + [("+Inf", 0.0)]
            histogram.add_metric([], buckets, 0.0)
        return histogram


#: The API's families (``Metrics``). Stream metrics are the relay's: it sees every frame message, drop and
#: result of the streams it serves.
API_FAMILIES: tuple[Family, ...] = (
    Family(
        "eigenscope_http_requests",
        "counter",
        "HTTP requests by route template, method and status",
        ("method", "route", "status"),
    ),
    Family(
        "eigenscope_http_request_duration_seconds",
        "histogram",
        "HTTP request duration by route template",
        ("method", "route"),
        _HTTP_BUCKETS,
    ),
    Family("eigenscope_uploaded_bytes", "counter", "Bytes of accepted clips"),
    Family("eigenscope_clips_rejected", "counter", "Uploads rejected, by reason", ("code",)),
    Family("eigenscope_jobs_created", "counter", "Jobs created (a live stream is a job too)"),
    Family("eigenscope_stream_sessions", "gauge", "Live stream connections open now"),
    Family("eigenscope_stream_frames_received", "counter", "Frame messages received from stream clients"),
    Family(
        "eigenscope_stream_frames_dropped",
        "counter",
        "Frame messages refused, by reason (`window`: over the flow-control window; `too_large`)",
        ("reason",),
    ),
    Family(
        "eigenscope_stream_result_latency_seconds",
        "histogram",
        "Seconds from a stream's `end` message to its `result`",
        (),
        _LATENCY_BUCKETS,
    ),
)
#: A worker's families (:class:`workers.metrics.WorkerMetrics`); stream jobs count as every other job.
WORKER_FAMILIES: tuple[Family, ...] = (
    Family(
        "eigenscope_job_duration_seconds",
        "histogram",
        "Run time of one job delivery, claim to end, by outcome",
        ("outcome",),
        _DURATION_BUCKETS,
    ),
    Family(
        "eigenscope_job_queue_wait_seconds",
        "histogram",
        "Time a job waited in the queue before a worker claimed it",
        (),
        _WAIT_BUCKETS,
    ),
    Family(
        "eigenscope_analysis_stage_seconds",
        "histogram",
        "Time of each analysis stage (Job.stage's names)",
        ("stage",),
        _STAGE_BUCKETS,
    ),
    Family("eigenscope_job_failures", "counter", "Failed jobs by problem type", ("type",)),
    Family("eigenscope_job_retries", "counter", "Deliveries that ran a job again"),
    Family("eigenscope_worker_busy", "gauge", "Worker processes running a job"),
    Family("eigenscope_worker_processes", "gauge", "Live worker pool processes"),
)


class WithDefaults:
    """The families of ``collectors``, and each of ``families`` none of them has, empty (see
    :meth:`Family.empty`)."""

    def __init__(self, collectors: Iterable[Any], families: Iterable[Family]) -> None:
        self.collectors = list(collectors)
        self.families = tuple(families)

    def collect(self) -> Iterator[Metric]:
        seen: set[str] = set()
        for collector in self.collectors:
            for metric in collector.collect():
                seen.add(metric.name)
                yield metric
        for family in self.families:
            if family.name not in seen:
                yield family.empty()


#: The environment variable of prometheus_client's multiprocess mode.
MULTIPROC_ENV = "PROMETHEUS_MULTIPROC_DIR"


class _JobsCollector:
    """``eigenscope_jobs{status}`` read from the job store at scrape time."""

    def __init__(self, store: Store) -> None:
        self.store = store

    def collect(self) -> Iterator[Any]:
        family = GaugeMetricFamily("eigenscope_jobs", "Jobs in the store by status", labels=["status"])
        try:
            counts = self.store.count_jobs_by_status()
        except Exception:
            log.warning("metrics: cannot count jobs", exc_info=True)
            return
        for status in JOB_STATUSES:
            family.add_metric([status], counts.get(status, 0))
        yield family


class BuildInfoCollector:
    """``eigenscope_build_info{version, api_version, python, component}`` = 1."""

    def __init__(self, component: str) -> None:
        self.component = component

    def collect(self) -> Iterator[Any]:
        from api_schemas._version import __version__

        family = InfoMetricFamily("eigenscope_build", "Version of the running Eigenscope")
        family.add_metric(
            [],
            {
                "version": __version__,
                "api_version": "1",
                "python": platform.python_version(),
                "component": self.component,
            },
        )
        yield family


def forget_dead_processes(path: str) -> None:
    """Drop the live gauges of processes of this machine that are gone (a killed worker process never
    says so itself), so ``eigenscope_worker_processes`` counts the living."""
    from prometheus_client import multiprocess

    for entry in Path(path).glob("gauge_live*_*.db"):
        pid_text = entry.stem.rsplit("_", 1)[-1]
        if not pid_text.isdigit():
            continue
        try:
            os.kill(int(pid_text), 0)
        except ProcessLookupError:
            multiprocess.mark_process_dead(int(pid_text), path)
        except PermissionError:
            continue


def multiprocess_collector() -> Any | None:
    """A collector summing every process's metric files, in multiprocess mode; else None."""
    path = os.environ.get(MULTIPROC_ENV)
    if not path:
        return None
    from prometheus_client import multiprocess

    forget_dead_processes(path)
    return multiprocess.MultiProcessCollector(None, path=path)


class Metrics:
    """HTTP request metrics, upload and job counters, live stream metrics, job gauges and build info."""

    content_type = CONTENT_TYPE_LATEST

    def __init__(self, store: Store) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        made = {f.name: f.make(self.registry) for f in API_FAMILIES}
        self.requests = made["eigenscope_http_requests"]
        self.latency = made["eigenscope_http_request_duration_seconds"]
        self.uploaded_bytes = made["eigenscope_uploaded_bytes"]
        self.clips_rejected = made["eigenscope_clips_rejected"]
        self.jobs_created = made["eigenscope_jobs_created"]
        self.stream_sessions = made["eigenscope_stream_sessions"]
        self.stream_frames = made["eigenscope_stream_frames_received"]
        self.stream_dropped = made["eigenscope_stream_frames_dropped"]
        self.stream_latency = made["eigenscope_stream_result_latency_seconds"]
        self._extra = [_JobsCollector(store), BuildInfoCollector("api")]

    def render(self) -> bytes:
        shared = multiprocess_collector()
        # In multiprocess mode the worker of `eigenscope serve` writes to the same folder: its families
        # are this scrape's too.
        source, families = (
            (shared, API_FAMILIES + WORKER_FAMILIES) if shared else (_Chain(self.registry), API_FAMILIES)
        )
        registry = CollectorRegistry(auto_describe=False)
        registry.register(WithDefaults([source], families))
        for collector in self._extra:
            registry.register(collector)
        return bytes(generate_latest(registry))


class _Chain:
    """Another registry's metrics, as one collector."""

    def __init__(self, registry: CollectorRegistry) -> None:
        self.registry = registry

    def collect(self) -> Iterator[Any]:
        yield from self.registry.collect()
