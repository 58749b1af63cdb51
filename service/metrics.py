"""Prometheus metrics of one app instance (own registry, no global state)."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily

from service.store import Store

log = logging.getLogger(__name__)

JOB_STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")


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
    """HTTP request metrics, upload and job counters, and job gauges."""

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
        self.registry.register(_JobsCollector(store))

    def render(self) -> bytes:
        return bytes(generate_latest(self.registry))
