"""The child process of :class:`.process.LiveProcessSink`: the WebSocket server, the JSON
encoding and the scene of the live view, in an interpreter of their own.

Started as ``python -c`` (a fresh interpreter, never ``fork``: the daemon has threads) with one
end of a duplex pipe. Messages on it are pickled:

* parent → child: first ``(LiveSection, server name, priority)``, then
  ``([(topic, payloads, log_time_ns), …], dropped in the daemon so far)``, and finally
  :data:`STOP`;
* child → parent: ``("ready", port)`` or ``("start_error", text)`` once, then
  ``("wanted", [topics])`` whenever the subscriptions change, ``("stats", LiveStats)`` every
  0.1 s, ``("error", text)`` per problem, and ``("stopped", None)`` last.

The child lowers its CPU priority (``SCHED_IDLE``, else nice 19) before it starts any thread,
so the sender thread and the SDK's server threads run only on CPU time nothing else wants; it
ignores SIGINT/SIGTERM (the daemon's handler stops it through the pipe) and ends when the pipe
closes (the daemon died).
"""

from __future__ import annotations

import collections
import logging
import pickle
import signal
import sys
import time
from multiprocessing.connection import Connection
from typing import Any

from ..osthread import lower_priority, name_os_thread
from .server import LiveStartError
from .sink import LiveSink

STOP = b"stop"
"""The parent's last message."""
STATS_PERIOD_S = 0.1
POLL_S = 0.02


SDK_LOG_LINES_PER_S = 1.0
"""Lines of the SDK's own log the child writes per second at most (to stderr, the daemon's)."""


class RateLimit(logging.Filter):
    """Pass at most ``per_s`` records a second; the next one passed says how many were not.

    A client that vanishes without closing makes the SDK log one error per message sent to it
    until it notices ("Error sending message to client …: Broken pipe"): at 1 kHz, thousands of
    lines for the daemon's journal."""

    def __init__(self, per_s: float) -> None:
        super().__init__()
        self._interval_s = 1.0 / per_s
        self._next = 0.0
        self._suppressed = 0

    def filter(self, record: logging.LogRecord) -> bool:
        now = time.monotonic()
        if now < self._next:
            self._suppressed += 1
            return False
        self._next = now + self._interval_s
        if self._suppressed:
            record.msg = f"{record.getMessage()} ({self._suppressed} similar lines suppressed)"
            record.args = None
            self._suppressed = 0
        return True


def limit_sdk_log(per_s: float = SDK_LOG_LINES_PER_S) -> None:
    """Send the ``foxglove`` logger's warnings to stderr, at most ``per_s`` lines a second
    (this process only: the child's own logging)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("cmm-comp live view (foxglove-sdk): %(message)s"))
    handler.addFilter(RateLimit(per_s))
    logger = logging.getLogger("foxglove")
    logger.setLevel(logging.WARNING)
    logger.addHandler(handler)
    logger.propagate = False


def child_entry(fd: int) -> None:
    """Child process entry (``python -c``); ``fd`` is its end of the pipe."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    name_os_thread("live-child")
    conn = Connection(fd)
    try:
        settings, name, priority = pickle.loads(conn.recv_bytes())
    except (EOFError, OSError):
        conn.close()
        return
    lower_priority(priority)  # before any thread: the sender and the SDK's threads inherit it
    limit_sdk_log()
    try:
        child_main(conn, settings, name)
    finally:
        conn.close()


def _send(conn: Connection, kind: str, body: Any) -> None:
    conn.send_bytes(pickle.dumps((kind, body), protocol=pickle.HIGHEST_PROTOCOL))


def child_main(conn: Connection, settings: Any, name: str) -> None:
    """Run a :class:`LiveSink` fed from ``conn`` until :data:`STOP` or the pipe closes."""
    errors: collections.deque[BaseException] = collections.deque()
    try:
        sink = LiveSink(settings, on_error=errors.append, name=name).start()
    except LiveStartError as exc:
        _send(conn, "start_error", str(exc))
        return
    _send(conn, "ready", sink.port)
    wanted: frozenset[str] | None = None
    next_stats = 0.0
    try:
        while True:
            if sink.wanted_topics != wanted:
                wanted = sink.wanted_topics
                _send(conn, "wanted", sorted(wanted))
            while errors:
                _send(conn, "error", str(errors.popleft()))
            now = time.monotonic()
            if now >= next_stats:
                next_stats = now + STATS_PERIOD_S
                _send(conn, "stats", sink.stats())
            if not conn.poll(POLL_S):
                continue
            data = conn.recv_bytes()
            if data == STOP:
                break
            batches, sink.upstream_dropped = pickle.loads(data)
            for topic, payloads, t_ns in batches:
                sink.log_many(topic, payloads, t_ns)
    except (EOFError, OSError):
        return  # the daemon is gone: nobody to report to
    finally:
        sink.stop(5.0)
    while errors:
        _send(conn, "error", str(errors.popleft()))
    _send(conn, "stats", sink.stats())
    _send(conn, "stopped", None)
