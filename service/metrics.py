"""Prometheus metrics of the API (own registry, no global state), correct with several API processes.

With ``PROMETHEUS_MULTIPROC_DIR`` set (``eigenscope serve`` sets it for its API processes and its worker),
every process writes its counters and histograms to files there and a scrape sums them all
(``prometheus_client`` multiprocess mode): whichever process answers ``/metrics``, the numbers are the
service's. Without it the metrics are this process's.

``eigenscope_jobs{status}`` is read from the job store at scrape time; ``eigenscope_build_info`` names the
version.
"""

from __future__ import annotations

import logging
import os
import platform
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily, InfoMetricFamily

from service.store import Store

log = logging.getLogger(__name__)

JOB_STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")
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
        from eigenscope import __version__

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


def multiprocess_registry() -> CollectorRegistry | None:
    """A registry summing every process's metric files, in multiprocess mode; else None."""
    path = os.environ.get(MULTIPROC_ENV)
    if not path:
        return None
    from prometheus_client import multiprocess

    forget_dead_processes(path)
    registry = CollectorRegistry(auto_describe=False)
    multiprocess.MultiProcessCollector(registry, path=path)
    return registry


class Metrics:
    """HTTP request metrics, upload and job counters, job gauges and build info."""

    content_type = CONTENT_TYPE_LATEST

    def __init__(self, store: Store) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        self.requests = Counter(
            "eigenscope_http_requests",
            "HTTP requests by route template, method and status",
            ["method", "route", "status"],
            registry=self.registry,
        )
        self.latency = Histogram(
            "eigenscope_http_request_duration_seconds",
            "HTTP request duration by route template",
            ["method", "route"],
            registry=self.registry,
            buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60),
        )
        self.uploaded_bytes = Counter(
            "eigenscope_uploaded_bytes", "Bytes of accepted clips", registry=self.registry
        )
        self.clips_rejected = Counter(
            "eigenscope_clips_rejected", "Uploads rejected, by reason", ["code"], registry=self.registry
        )
        self.jobs_created = Counter("eigenscope_jobs_created", "Jobs created", registry=self.registry)
        self._extra = [_JobsCollector(store), BuildInfoCollector("api")]

    def render(self) -> bytes:
        registry = multiprocess_registry()
        if registry is None:
            registry = CollectorRegistry(auto_describe=False)
            registry.register(_Chain(self.registry))
        for collector in self._extra:
            registry.register(collector)
        return bytes(generate_latest(registry))


class _Chain:
    """Another registry's metrics, as one collector."""

    def __init__(self, registry: CollectorRegistry) -> None:
        self.registry = registry

    def collect(self) -> Iterator[Any]:
        yield from self.registry.collect()
