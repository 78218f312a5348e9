"""Structured event log: one JSON (or logfmt) line per event on stdout, rate-limited per kind.

    events = EventLog(sys.stdout, fmt="json")
    events.emit("grid_loaded", sha256="ab12…", path="/etc/cmm/machine.grid")
    -> {"ts":"2025-01-01T12:00:00.123456+00:00","level":"info","event":"grid_loaded",...}

An event kind that repeats faster than ``max_per_s`` (e.g. a flood of unknown CAN ids) is
suppressed; the next line of that kind carries ``suppressed=<n>``, so nothing is lost silently.
Thread-safe; writing never raises into the caller (a broken stdout is counted, not fatal).
"""

from __future__ import annotations

import json
import threading
import time
from datetime import UTC, datetime
from typing import Any, TextIO

LEVELS = {"debug": 10, "info": 20, "warning": 30, "error": 40}


def _logfmt_value(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    if text == "" or any(c in text for c in ' ="\n'):
        return json.dumps(text)
    return text


class Throttle:
    """At most one pass per key every ``interval_s`` (s; 0: every time); each pass tells how
    many of its key were held back since the one before. The daemon's one rate limit (event
    lines, Modbus log lines, the writer's and the live view's error reports); not thread-safe:
    callers that share one hold their own lock."""

    def __init__(self, interval_s: float) -> None:
        self.interval_s = interval_s
        self._last: dict[object, float] = {}
        self._held: dict[object, int] = {}

    def passes(self, key: object = None) -> int | None:
        """None when ``key`` is held back now (counted), else how many were held back before."""
        now = time.monotonic()
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self._held[key] = self._held.get(key, 0) + 1
            return None
        self._last[key] = now
        return self._held.pop(key, 0)

    def flush(self, key: object = None) -> int:
        """How many of ``key`` are held back now (the count starts again)."""
        return self._held.pop(key, 0)


class EventLog:
    """Write events as single lines to ``stream`` (None = discard).

    :param fmt: ``json`` or ``logfmt``.
    :param level: lowest level written (``debug`` … ``error``).
    :param max_per_s: lines per second allowed for each event kind.
    """

    def __init__(
        self,
        stream: TextIO | None,
        fmt: str = "json",
        level: str = "info",
        max_per_s: float = 20.0,
    ) -> None:
        if fmt not in ("json", "logfmt"):
            raise ValueError(f"log format {fmt!r}; allowed: json, logfmt")
        self._stream = stream
        self._fmt = fmt
        self._min_level = LEVELS[level]
        self._throttle = Throttle(1.0 / max_per_s if max_per_s > 0 else 0.0)
        self._lock = threading.Lock()

    def emit(self, event: str, level: str = "info", **fields: Any) -> None:
        """Write one event line (unless below the level or rate-limited)."""
        if LEVELS[level] < self._min_level or self._stream is None:
            return
        with self._lock:
            suppressed = self._throttle.passes(event)
            if suppressed is None:
                return
            record: dict[str, Any] = {
                "ts": datetime.now(UTC).isoformat(),
                "level": level,
                "event": event,
                **fields,
            }
            if suppressed:
                record["suppressed"] = suppressed
            if self._fmt == "json":
                line = json.dumps(record, default=str, separators=(",", ":"))
            else:
                line = " ".join(f"{k}={_logfmt_value(v)}" for k, v in record.items())
            try:
                self._stream.write(line + "\n")
                self._stream.flush()
            except (OSError, ValueError):  # a closed or broken stdout: the event is lost
                pass
