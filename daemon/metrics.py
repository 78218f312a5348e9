"""Operational counters, the reply-latency histogram, and a Prometheus text endpoint.

:class:`Metrics` is what the hot path touches: ``count(name)``, ``answer(status_label,
latency_us)``, ``fault(kind)``; each is a dict update under one uncontended lock (well under
a microsecond). Every statistic is finite by construction: a latency that is not a finite
number ≥ 0 (or ``None``: an answer without a reply latency, e.g. a reading that never
completed) is counted apart and never enters the histogram; a quantile in the overflow bin is
the largest latency seen, not infinity; an empty histogram has no quantile (``None``). :class:`MetricsServer` serves ``GET /metrics`` (Prometheus text format 0.0.4)
from a tiny ``http.server`` thread bound to 127.0.0.1 by default; it is a context manager
with ``stop(timeout_s)``.
"""

from __future__ import annotations

import bisect
import http.server
import math
import threading
from collections.abc import Callable
from typing import Any

#: Histogram bin upper edges, µs: 5 µs steps to 200 µs, then roughly 10 % steps to 100 ms.
LATENCY_EDGES_US: tuple[float, ...] = tuple(
    [float(e) for e in range(5, 205, 5)]
    + [float(round(200 * 1.1**k)) for k in range(1, 66) if 200 * 1.1**k <= 100_000]
)


class LatencyHistogram:
    """Counts of latencies (µs) per bin; the last bin is everything above the top edge.
    Values that are not finite numbers ≥ 0 are counted in ``invalid``, not binned."""

    def __init__(self, edges_us: tuple[float, ...] = LATENCY_EDGES_US) -> None:
        self.edges_us = edges_us
        self.counts = [0] * (len(edges_us) + 1)
        self.total = 0
        self.sum_us = 0.0
        self.max_us = 0.0
        self.invalid = 0

    def add(self, latency_us: float) -> None:
        """Record one latency, µs (NaN, ±inf, negative: counted in ``invalid`` only)."""
        if not 0.0 <= latency_us < math.inf:  # False for NaN too
            self.invalid += 1
            return
        self.counts[bisect.bisect_left(self.edges_us, latency_us)] += 1
        self.total += 1
        self.sum_us += latency_us
        if latency_us > self.max_us:
            self.max_us = latency_us

    def quantile(self, q: float) -> float | None:
        """Approximate quantile (upper edge of the bin holding it; in the overflow bin the
        largest latency seen), µs; None when empty. Always finite."""
        if self.total == 0:
            return None
        target = q * self.total
        acc = 0
        for i, c in enumerate(self.counts):
            acc += c
            if acc >= target and c:
                return min(self.edges_us[i], self.max_us) if i < len(self.edges_us) else self.max_us
        return self.max_us

    def copy(self) -> LatencyHistogram:
        """An independent snapshot."""
        h = LatencyHistogram(self.edges_us)
        h.counts = list(self.counts)
        h.total, h.sum_us, h.max_us, h.invalid = self.total, self.sum_us, self.max_us, self.invalid
        return h


class Metrics:
    """Counters since start (readings, answers by status, faults by kind) and latencies."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.counters: dict[str, int] = {}
        self.answers: dict[str, int] = {}
        self.faults: dict[str, int] = {}
        self.latency = LatencyHistogram()
        self._period = LatencyHistogram()

    def count(self, name: str, n: int = 1) -> None:
        """Add ``n`` to counter ``name`` (e.g. ``readings``, ``frames_rx``)."""
        with self._lock:
            self.counters[name] = self.counters.get(name, 0) + n

    def fault(self, kind: str, n: int = 1) -> None:
        """Count a fault of ``kind`` (e.g. ``unknown_id``, ``bad_length``, ``bus_error``)."""
        with self._lock:
            self.faults[kind] = self.faults.get(kind, 0) + n

    def answer(self, status_label: str, latency_us: float | None) -> None:
        """Count one answer with its status and reply latency, µs; ``None`` for an answer
        without a reply latency (a reading that never completed, answered when it expired):
        counted in ``answers_<status>`` and ``answers_without_latency``, not in the histogram."""
        with self._lock:
            self.answers[status_label] = self.answers.get(status_label, 0) + 1
            if latency_us is None:
                c = self.counters
                c["answers_without_latency"] = c.get("answers_without_latency", 0) + 1
                return
            self.latency.add(latency_us)
            self._period.add(latency_us)

    def readings_answered(self, answers: list[tuple[str, float, bool]]) -> None:
        """Answered readings, each ``(status_label, latency_us, warning)``, under one lock:
        counts ``readings``, each answer with its status and latency (µs) and, if ``warning``,
        ``correction_warnings``."""
        with self._lock:
            c, by_status = self.counters, self.answers
            c["readings"] = c.get("readings", 0) + len(answers)
            latency, period = self.latency, self._period
            for label, latency_us, warning in answers:
                if warning:
                    c["correction_warnings"] = c.get("correction_warnings", 0) + 1
                by_status[label] = by_status.get(label, 0) + 1
                latency.add(latency_us)
                period.add(latency_us)

    def get(self, name: str) -> int:
        """Counter value (0 if never counted)."""
        return self.counters.get(name, 0)

    @property
    def answered(self) -> int:
        """Answers sent, all statuses."""
        return sum(self.answers.values())

    @property
    def not_ok(self) -> int:
        """Answers whose status was not ``ok``."""
        return sum(v for k, v in self.answers.items() if k != "ok")

    def snapshot(self, reset_period: bool = False) -> dict[str, Any]:
        """Counters as a JSON-friendly dict (the /cmm/counters payload); optionally start a
        new histogram period."""
        with self._lock:
            period = self._period
            if reset_period:
                self._period = LatencyHistogram()
            counters = dict(self.counters)
            counters.update({f"answers_{k}": v for k, v in self.answers.items()})
            counters.update({f"faults_{k}": v for k, v in self.faults.items()})
            if self.latency.invalid:
                counters["latency_invalid"] = self.latency.invalid
        p50, p99 = period.quantile(0.5), period.quantile(0.99)
        out: dict[str, Any] = {
            "counters": counters,
            "latency_edges_us": [0.0, *period.edges_us],
            "latency_counts": period.counts[:-1],
            "latency_over_top": period.counts[-1],
        }
        if p50 is not None and p99 is not None:
            out["latency_p50_us"] = p50
            out["latency_p99_us"] = p99
            out["latency_max_us"] = period.max_us
        return out

    def prometheus(self, extra: dict[str, float] | None = None) -> str:
        """Prometheus text exposition of everything, plus ``extra`` gauges."""
        with self._lock:
            counters = dict(self.counters)
            answers = dict(self.answers)
            faults = dict(self.faults)
            hist = self.latency.copy()
        lines = [
            "# HELP cmm_comp_events_total Daemon events since start, by kind.",
            "# TYPE cmm_comp_events_total counter",
        ]
        lines += [f'cmm_comp_events_total{{kind="{k}"}} {v}' for k, v in sorted(counters.items())]
        lines += [
            "# HELP cmm_comp_answers_total Answers sent, by status.",
            "# TYPE cmm_comp_answers_total counter",
        ]
        lines += [f'cmm_comp_answers_total{{status="{k}"}} {v}' for k, v in sorted(answers.items())]
        lines += [
            "# HELP cmm_comp_faults_total Input and transport faults, by kind.",
            "# TYPE cmm_comp_faults_total counter",
        ]
        lines += [f'cmm_comp_faults_total{{kind="{k}"}} {v}' for k, v in sorted(faults.items())]
        lines += [
            "# HELP cmm_comp_reply_latency_us Last input frame to answer sent, microseconds.",
            "# TYPE cmm_comp_reply_latency_us histogram",
        ]
        acc = 0
        for edge, c in zip(hist.edges_us, hist.counts, strict=False):
            acc += c
            lines.append(f'cmm_comp_reply_latency_us_bucket{{le="{edge:g}"}} {acc}')
        lines.append(f'cmm_comp_reply_latency_us_bucket{{le="+Inf"}} {hist.total}')
        lines.append(f"cmm_comp_reply_latency_us_sum {hist.sum_us:.1f}")
        lines.append(f"cmm_comp_reply_latency_us_count {hist.total}")
        for name, value in sorted((extra or {}).items()):
            lines += [f"# TYPE {name} gauge", f"{name} {value:g}"]  # Prometheus takes NaN/Inf
        return "\n".join(lines) + "\n"


class MetricsServer:
    """``GET /metrics`` on ``host:port`` (port 0 = any free port), served by one thread.

    :param render: returns the exposition text (called per request, from the server thread).
    """

    def __init__(self, render: Callable[[], str], host: str = "127.0.0.1", port: int = 0) -> None:
        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                if self.path.split("?")[0] not in ("/metrics", "/"):
                    self.send_error(404, "only /metrics")
                    return
                body = render().encode()
                self.send_response(200)
                self.send_header("Content-Type", "text/plain; version=0.0.4; charset=utf-8")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: Any) -> None:
                pass  # the daemon's own event log covers operations

        self._httpd = http.server.HTTPServer((host, port), Handler)
        bound = self._httpd.server_address
        self.host = bound[0].decode() if isinstance(bound[0], bytes) else str(bound[0])
        self.port = int(bound[1])
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.1}, name="metrics-http"
        )
        self._thread.daemon = True
        self._thread.start()

    @property
    def url(self) -> str:
        """Full URL of the endpoint."""
        return f"http://{self.host}:{self.port}/metrics"

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Stop serving and close the socket; True if the thread ended within ``timeout_s``."""
        if self._thread.is_alive():
            self._httpd.shutdown()
            self._thread.join(timeout_s)
        self._httpd.server_close()
        return not self._thread.is_alive()

    def __enter__(self) -> MetricsServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
