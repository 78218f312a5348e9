"""The live view's child process (:class:`.process.LiveProcessSink`, started by
:mod:`..childproc`): the WebSocket server, the JSON encoding, the decimation and the scene, in
an interpreter of its own at ``SCHED_IDLE`` (set before anything starts, so the SDK's server
threads inherit it: they run only on CPU time nothing else wants).

Its loop runs ``update_rate_hz`` times a second (:data:`IDLE_PERIOD_S` while no client watches):
a heartbeat and the watched topics into the shared memory, the daemon's records from the ring
straight into the update of an ordinary :class:`LiveSink` (:meth:`LiveSink.tick`: decimate,
encode, send, scene), and
every :data:`STATUS_PERIOD_S` its status (:class:`LiveStats`); errors go to the daemon as
``warning`` events on the pipe, at most :data:`ERRORS_PER_S` a second (the next one says how
many were held back). It ends when the daemon asks, or when the daemon is gone.
"""

from __future__ import annotations

import logging
import pickle
import sys
import time
from collections.abc import Iterator
from dataclasses import replace

from ..childproc import ChildEnd
from ..events import Throttle
from ..osthread import lower_priority, name_os_thread
from .server import LiveStartError
from .sink import TOPIC_BITS, Batch, LiveSink, LiveStats

STATUS_PERIOD_S = 0.1
"""The child publishes its status this often, s."""
IDLE_PERIOD_S = 0.1
"""The child's loop period while no client watches anything (else ``1 / update_rate_hz``), s:
fewer wake-ups beside the daemon; a new subscriber is seen within it."""
ERRORS_PER_S = 10.0
"""Errors passed to the daemon per second at most (the rest are counted, and said)."""
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
    """The child's side of the ring: the daemon's records out of it, its status and errors
    back."""

    def __init__(self, end: ChildEnd, sink: LiveSink) -> None:
        self.end = end
        self.sink = sink
        self.taken = 0
        self.bad = 0
        self._errors = Throttle(1.0 / ERRORS_PER_S)

    def error(self, exc: BaseException) -> None:
        held = self._errors.passes()
        if held is not None:
            more = f" ({held} more errors before this one)" if held else ""
            self.end.send("warning", f"{str(exc)[:ERROR_TEXT_MAX]}{more}")

    def error_count(self) -> None:
        """Tell the daemon how many errors were held back at the end."""
        held = self._errors.flush()
        if held:
            self.end.send("warning", f"live view: {held} more errors in its process")

    def read(self) -> Iterator[Batch]:
        """The daemon's batches waiting in the ring (for :meth:`LiveSink.tick`)."""
        for n, data in self.end.ring.read():
            self.taken += n
            try:
                yield pickle.loads(data)
            except Exception as exc:  # cannot happen with the daemon's pickles; counted
                self.bad += n
                self.error(ValueError(f"live view: a record could not be read: {exc!r}"))

    def status(self) -> LiveStats:
        st = self.sink.stats()
        return replace(st, offered=self.taken, encode_errors=st.encode_errors + self.bad)

    def wanted(self) -> None:
        mask = 0
        for topic in self.sink.wanted_topics:
            mask |= TOPIC_BITS.get(topic, 0)
        self.end.ring.set_wanted(mask)


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
        feed = _Feed(end, sink)
        sink.start()
    except LiveStartError as exc:
        end.send("start_error", exc)
        return
    period_s = 1.0 / settings.update_rate_hz

    def tick() -> float:
        t0 = time.monotonic()
        feed.wanted()
        sink.tick(batches=feed.read())
        wait_s = period_s if sink.wanted_topics else max(period_s, IDLE_PERIOD_S)
        return max(0.0, wait_s - (time.monotonic() - t0))

    end.serve(sink.port, tick, feed.status, STATUS_PERIOD_S)
    if end.parent_alive:
        sink.tick(batches=feed.read())  # what the daemon wrote before it asked to stop
    sink.stop(5.0)
    feed.error_count()
    end.send("stopped", feed.status())
    end.close()
