"""Prometheus metrics of the API (own registry, no global state), correct with several API processes.

With ``PROMETHEUS_MULTIPROC_DIR`` set (``eigenscope serve`` sets it for its API processes and its worker),
every process writes its counters and histograms to files there and a scrape sums them all
(``prometheus_client`` multiprocess mode): whichever process answers ``/metrics``, the numbers are the
service's, the workers' families (:data:`backend.metrics.WORKER_FAMILIES`) included. Without it the
metrics are this process's.

The API's families are declared once, in :data:`API_FAMILIES`; every one is in every scrape from the start
(:class:`backend.metrics.WithDefaults`). ``eigenscope_jobs{status}`` is read from the job store at scrape
time; ``eigenscope_build_info`` names the version.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import GaugeMetricFamily

from backend.metrics import (
    WORKER_FAMILIES,
    BuildInfoCollector,
    Family,
    WithDefaults,
    multiprocess_collector,
)
from backend.store import Store

log = logging.getLogger(__name__)

JOB_STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")

_HTTP_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60)
_LATENCY_BUCKETS = (0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1, 1.5, 2, 3, 5, 10, 30)


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
