"""Prometheus metrics computed from the job table and the queue at scrape time, so that
every API replica reports the same numbers whatever process ran the bakes."""

from __future__ import annotations

from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import GaugeMetricFamily, HistogramMetricFamily

from jobs.queue import queue_depth
from jobs.store import JobStore

DURATION_BUCKETS = (1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0, 3600.0)


class _JobCollector:
    def __init__(self, store: JobStore, huey: Any):
        self.store, self.huey = store, huey

    def collect(self):
        jobs = GaugeMetricFamily("prtcore_jobs", "Bake jobs by state", labels=["state"])
        for state, n in self.store.counts().items():
            jobs.add_metric([state], n)
        yield jobs
        counts, total, seconds = self.store.duration_histogram(DURATION_BUCKETS)
        h = HistogramMetricFamily("prtcore_bake_duration_seconds",
                                  "Run time of succeeded bakes (first start to finish)")
        h.add_metric([], [(repr(b), c) for b, c in zip(DURATION_BUCKETS, counts, strict=True)]
                     + [("+Inf", total)], sum_value=seconds)
        yield h
        q = GaugeMetricFamily("prtcore_queue_depth", "Messages waiting in the queue")
        try:
            q.add_metric([], queue_depth(self.huey))
        except Exception:
            q.add_metric([], float("nan"))
        yield q


def render(store: JobStore, huey: Any) -> tuple[bytes, str]:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_JobCollector(store, huey))
    return generate_latest(registry), CONTENT_TYPE_LATEST
