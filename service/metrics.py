"""``/metrics`` in Prometheus' text format.

HTTP requests are counted in the API process (by route template and status). Job figures
come from the job store at scrape time (a custom collector), so they are right whichever
process ran the jobs: jobs by status, the queue depth, the time spent in each stage, lease
expiries, live workers.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, SummaryMetricFamily
from prometheus_client.registry import Collector

from .jobs.store import Store

__all__ = ["Metrics"]


class _StoreCollector(Collector):
    def __init__(self, store: Store, live_within_s: float) -> None:
        self.store = store
        self.live_within_s = live_within_s

    def collect(self) -> Iterator[Any]:
        counts = self.store.count_by_status()
        jobs = GaugeMetricFamily("treesim_jobs", "Jobs in the store by status", labels=["status"])
        for status, n in counts.items():
            jobs.add_metric([status], n)
        yield jobs
        yield GaugeMetricFamily(
            "treesim_queue_depth", "Jobs waiting for a worker", value=counts.get("accepted", 0)
        )
        yield GaugeMetricFamily(
            "treesim_workers_alive",
            "Workers whose heartbeat is recent",
            value=len(self.store.live_workers(self.live_within_s)),
        )
        stages = SummaryMetricFamily(
            "treesim_stage_duration_seconds",
            "Time spent in each stage of successful jobs",
            labels=["process", "stage"],
        )
        expiries = CounterMetricFamily(
            "treesim_lease_expiries", "Running jobs whose worker stopped renewing the lease"
        )
        n_exp = 0
        for c in self.store.counters():
            if c["name"] == "stage_seconds":
                process, _, stage = c["label"].partition(":")
                stages.add_metric([process, stage], c["count"], c["total"])
            elif c["name"] == "lease_expiries":
                n_exp += int(c["count"])
        expiries.add_metric([], n_exp)
        yield stages
        yield expiries


class Metrics:
    """The app's own registry (one per app, so tests can build many apps)."""

    def __init__(self, store: Store, live_within_s: float) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "treesim_http_requests",
            "HTTP requests by route and status",
            ["method", "route", "status"],
            registry=self.registry,
        )
        self.latency = Histogram(
            "treesim_http_request_duration_seconds",
            "HTTP request latency by route",
            ["route"],
            registry=self.registry,
            buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30),
        )
        self.registry.register(_StoreCollector(store, live_within_s))

    def middleware(self, app: Any) -> Any:
        """A pure ASGI middleware counting requests (streamed bodies pass untouched)."""
        metrics = self

        async def wrapped(scope: dict[str, Any], receive: Any, send: Any) -> None:
            if scope["type"] != "http":
                await app(scope, receive, send)
                return
            status = [500]
            t0 = time.perf_counter()

            async def send_status(message: dict[str, Any]) -> None:
                if message["type"] == "http.response.start":
                    status[0] = message["status"]
                await send(message)

            try:
                await app(scope, receive, send_status)
            finally:
                path = route_template(scope)
                metrics.requests.labels(scope.get("method", ""), path, str(status[0])).inc()
                metrics.latency.labels(path).observe(time.perf_counter() - t0)

        return wrapped


_PARAM = re.compile(r"{(\w+)(?::\w+)?}")


def route_template(scope: dict[str, Any]) -> str:
    """The matched route's path template with its router's prefix (``/v1/jobs/{job_id}``),
    so that labels stay few; ``unmatched`` for a path no route took."""
    route = scope.get("route")
    template = getattr(route, "path", None)
    if not template:
        return "unmatched"
    params = scope.get("path_params") or {}
    try:
        rendered = _PARAM.sub(lambda m: str(params[m.group(1)]), template)
    except KeyError:
        return template
    path = scope.get("path", "")
    prefix = path[: len(path) - len(rendered)] if path.endswith(rendered) else ""
    return prefix + template
