"""Prometheus metric families of the API and the workers, and the collectors both sides use.

With ``PROMETHEUS_MULTIPROC_DIR`` set (``eigenscope serve`` sets it for its API processes and its worker),
every process writes its counters and histograms to files there and a scrape sums them all
(``prometheus_client`` multiprocess mode): whichever process answers ``/metrics``, the numbers are the
service's. Without it the metrics are this process's.

Every family is declared once (:class:`Family`): the workers' here, in :data:`WORKER_FAMILIES`
(:class:`workers.metrics.WorkerMetrics` builds its metrics from it, and the API's ``/metrics`` shows them
too), the API's in :data:`service.metrics.API_FAMILIES`. Every one is in every scrape from the start
(:class:`WithDefaults`): a family no process has touched yet (in multiprocess mode only touched ones have
files) is shown with no sample, or at 0 when it has no labels. ``eigenscope_build_info`` names the version
(:class:`BuildInfoCollector`).
"""

from __future__ import annotations

import os
import platform
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    InfoMetricFamily,
    Metric,
)

_DURATION_BUCKETS = (0.25, 0.5, 1, 2, 3, 5, 8, 13, 20, 30, 60, 120, 300, 600, 1800)
_WAIT_BUCKETS = (0.01, 0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 30, 60, 300, 1800)
_STAGE_BUCKETS = (0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 30, 120)


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


class BuildInfoCollector:
    """``eigenscope_build_info{version, api_version, python, component}`` = 1."""

    def __init__(self, component: str) -> None:
        self.component = component

    def collect(self) -> Iterator[Any]:
        from backend.version import __version__

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
