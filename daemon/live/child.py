"""The live view's child process (:class:`.process.LiveProcessSink`, started by
:mod:`..childproc`): the WebSocket server, the JSON encoding, the decimation and the scene, in
an interpreter of its own at ``SCHED_IDLE`` (set before anything starts, so the SDK's server
threads inherit it: they run only on CPU time nothing else wants).

Its loop runs ``update_rate_hz`` times a second (:data:`IDLE_PERIOD_S` while no client watches):
a heartbeat and the watched topics into the shared memory, the daemon's records from the ring
straight into the update of an ordinary :class:`LiveSink` (:meth:`LiveSink.tick`: decimate,
encode, send, scene; its own queue stays empty), and
every :data:`STATUS_PERIOD_S` its status ``(LiveStats, errors so far, the newest error
texts)``. It ends when the daemon asks, or when the daemon is gone.
"""

from __future__ import annotations

import logging
import pickle
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

from ..childproc import ChildEnd
from ..events import Throttle
from ..osthread import lower_priority, name_os_thread
from ..ring import SharedRing
from .server import LiveStartError
from .sink import TOPIC_BITS, Batch, LiveSink

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
        self._throttle = Throttle(1.0 / per_s)

    def filter(self, record: logging.LogRecord) -> bool:
        suppressed = self._throttle.passes()
        if suppressed:
            record.msg = f"{record.getMessage()} ({suppressed} similar lines suppressed)"
            record.args = None
        return suppressed is not None


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

    def read(self) -> Iterator[Batch]:
        """The daemon's batches waiting in the ring (for :meth:`LiveSink.tick`)."""
        for n, data in self.ring.read():
            self.taken += n
            try:
                yield pickle.loads(data)
            except Exception as exc:  # cannot happen with the daemon's pickles; counted
                self.bad += n
                self.error(ValueError(f"live view: a record could not be read: {exc!r}"))

    def status(self) -> tuple[Any, int, list[str]]:
        st = self.sink.stats()
        st = replace(st, offered=self.taken, encode_errors=st.encode_errors + self.bad)
        return st, self.errors, list(self.texts)

    def publish(self, end: ChildEnd) -> None:
        status = self.status()
        if not end.publish(status):
            end.publish((status[0], status[1], []))

    def wanted(self) -> None:
        mask = 0
        for topic in self.sink.wanted_topics:
            mask |= TOPIC_BITS.get(topic, 0)
        self.ring.set_wanted(mask)


def child_main(end: ChildEnd) -> None:
    """Run a :class:`LiveSink` fed from the ring until the daemon asks to stop or is gone."""
    name_os_thread("live-child")
    if end.settings is None:
        return
    settings, name = end.settings
    lower_priority("idle")  # before any thread: the SDK's threads inherit it
    limit_sdk_log()
    feed: _Feed
    try:
        sink = LiveSink(settings, on_error=lambda exc: feed.error(exc), name=name)
        feed = _Feed(end.ring, sink)
        sink.start()
    except LiveStartError as exc:
        end.send("start_error", exc)
        return
    period_s = 1.0 / settings.update_rate_hz
    next_status = 0.0
    end.ring.beat(time.monotonic_ns())
    end.send("ready", sink.port)
    while True:
        t0 = time.monotonic()
        end.ring.beat(time.monotonic_ns())
        feed.wanted()
        sink.tick(batches=feed.read())
        if t0 >= next_status:
            next_status = t0 + STATUS_PERIOD_S
            feed.publish(end)
        wait_s = period_s if sink.wanted_topics else max(period_s, IDLE_PERIOD_S)
        stop, _ = end.stop_requested(max(0.0, wait_s - (time.monotonic() - t0)))
        if stop:
            break
    if end.parent_alive:
        sink.tick(batches=feed.read())  # what the daemon wrote before it asked to stop
    sink.stop(5.0)
    feed.publish(end)
    end.send("stopped", feed.status())
    end.close()
