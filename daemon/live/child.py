"""The child process of :class:`.process.LiveProcessSink`: the WebSocket server, the JSON
encoding, the decimation and the scene of the live view, in an interpreter of their own.

Started as ``python -c`` (a fresh interpreter, never ``fork``: the daemon has threads) with one
end of a duplex pipe and the shared memory of :mod:`.ring`:

* pipe, parent → child: first ``(LiveSection, server name, priority)``, last :data:`STOP`;
  child → parent: ``("ready", port)`` or ``("start_error", text)`` once, ``("stopped",
  status)`` last. Nothing passes on the pipe while the view runs;
* shared memory: the daemon's records (ring), and from the child the topics some client
  watches, a heartbeat each loop, and every :data:`STATUS_PERIOD_S` its status
  ``(LiveStats, errors so far, the newest error texts)``.

The child lowers its CPU priority (``SCHED_IDLE``, else nice 19) before it starts anything, so
its loop and the SDK's server threads run only on CPU time nothing else wants. Its loop runs
``update_rate_hz`` times a second: read the ring, hand the records to an ordinary
:class:`LiveSink` (no thread of its own), :meth:`LiveSink.tick` (decimate, encode, send, scene).
It ignores SIGINT/SIGTERM (the daemon stops it through the pipe) and ends when the pipe closes
(the daemon died).
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import sys
import time
from dataclasses import replace
from multiprocessing.connection import Connection
from typing import Any

from ..osthread import lower_priority, name_os_thread
from .process import STOP, TOPIC_BITS
from .ring import SharedRing
from .server import LiveStartError
from .sink import LiveSink

STATUS_PERIOD_S = 0.1
"""The child publishes its status this often, s."""
IDLE_PERIOD_S = 0.1
"""The child's loop period while no client watches anything (else ``1 / update_rate_hz``), s:
fewer wake-ups beside the daemon; a new subscriber is seen within it."""
ERROR_TEXTS = 8
"""Newest error texts kept in the status (older ones are only counted)."""
ERROR_TEXT_MAX = 300
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


def child_entry(fd: int, shm_fd: int, capacity: int) -> None:
    """Child process entry (``python -c``): ``fd`` is its end of the pipe, ``shm_fd`` the
    shared memory (:mod:`.ring`, ``capacity`` ring bytes)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    name_os_thread("live-child")
    conn = Connection(fd)
    ring = SharedRing(shm_fd, capacity)
    os.close(shm_fd)
    try:
        settings, name, priority = pickle.loads(conn.recv_bytes())
    except (EOFError, OSError):
        conn.close()
        return
    lower_priority(priority)  # before any thread: the SDK's threads inherit it
    limit_sdk_log()
    try:
        child_main(conn, ring, settings, name)
    finally:
        conn.close()


def _send(conn: Connection, kind: str, body: Any) -> None:
    conn.send_bytes(pickle.dumps((kind, body), protocol=pickle.HIGHEST_PROTOCOL))


class _Feed:
    """The child's side of the ring: records into the sink, its status out."""

    def __init__(self, ring: SharedRing, sink: LiveSink) -> None:
        self.ring = ring
        self.sink = sink
        self.taken = 0
        self.bad = 0
        self.errors = 0
        self.texts: list[str] = []

    def error(self, exc: BaseException) -> None:
        self.errors += 1
        self.texts = [*self.texts[-(ERROR_TEXTS - 1) :], str(exc)[:ERROR_TEXT_MAX]]

    def read(self) -> None:
        for n, data in self.ring.read():
            self.taken += n
            try:
                topic, payloads, t_ns = pickle.loads(data)
            except Exception as exc:  # cannot happen with the daemon's pickles; counted
                self.bad += n
                self.error(ValueError(f"live view: a record could not be read: {exc!r}"))
                continue
            self.sink.log_many(topic, payloads, t_ns)

    def status(self) -> tuple[Any, int, list[str]]:
        st = self.sink.stats()
        st = replace(st, offered=self.taken, encode_errors=st.encode_errors + self.bad)
        return st, self.errors, list(self.texts)

    def publish(self) -> None:
        status = self.status()
        if not self.ring.set_status(pickle.dumps(status, protocol=pickle.HIGHEST_PROTOCOL)):
            self.ring.set_status(pickle.dumps((status[0], status[1], [])))

    def wanted(self) -> None:
        mask = 0
        for topic in self.sink.wanted_topics:
            mask |= TOPIC_BITS.get(topic, 0)
        self.ring.set_wanted(mask)


def child_main(conn: Connection, ring: SharedRing, settings: Any, name: str) -> None:
    """Run a :class:`LiveSink` fed from the ring until :data:`STOP` or the pipe closes."""
    feed: _Feed
    try:
        sink = LiveSink(settings, on_error=lambda exc: feed.error(exc), name=name)
        feed = _Feed(ring, sink)
        sink.start(thread=False)
    except LiveStartError as exc:
        _send(conn, "start_error", str(exc))
        return
    period_s = 1.0 / settings.update_rate_hz
    next_status = 0.0
    ring.beat(time.monotonic_ns())
    _send(conn, "ready", sink.port)
    parent_gone = False
    try:
        while True:
            t0 = time.monotonic()
            ring.beat(time.monotonic_ns())
            feed.wanted()
            feed.read()
            sink.tick()
            if t0 >= next_status:
                next_status = t0 + STATUS_PERIOD_S
                feed.publish()
            if conn.poll(0) and conn.recv_bytes() == STOP:
                break
            wait_s = period_s if sink.wanted_topics else max(period_s, IDLE_PERIOD_S)
            left = wait_s - (time.monotonic() - t0)
            if left > 0:
                time.sleep(left)
    except (EOFError, OSError):
        parent_gone = True  # the daemon is gone: nobody to report to
    finally:
        if not parent_gone:
            feed.read()  # what the daemon wrote before it asked to stop
        sink.stop(5.0)
    feed.publish()
    _send(conn, "stopped", feed.status())
