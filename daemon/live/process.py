""":class:`LiveProcessSink`: the daemon's live view. Its server, encoding and scene run in a
child process (:mod:`..childproc`, :mod:`.child`), fed through shared memory: the daemon pays a
copy, never a thread of its own doing the work, a lock with long work, a system call or a
wake-up (docs/live.md).

* the producers' side (:meth:`LiveProcessSink.log_many`, called in the daemon's bookkeeping
  after the replies are sent) drops a topic nobody watches at once (one byte of shared memory
  read: the process publishes which topics some client watches), else pickles the batch and
  copies it into the ring; a full ring (the process stopped or starved) drops the batch,
  counted exactly;
* the process polls the ring at ``update_rate_hz`` at ``SCHED_IDLE``, decimates (the one
  gate of the high-rate topics, :mod:`.decimate`), encodes and serves; it publishes its
  counters and a heartbeat in the shared memory, its errors as the MCAP writer's child does
  (events on the pipe, at most :data:`.child.ERRORS_PER_S` a second, the rest counted);
* whoever asks for statistics (the daemon's housekeeping, every ``metrics.period_s``) reads
  them there and finds out whether the process stalled (no loop for :data:`STALL_S`); its
  death is seen at once (the pipe closes). Either is reported once through ``on_error``,
  ``live_up`` turns 0 and nothing more is pickled or copied until it runs again.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, Self

from cmm_comp.compensation.errors import CmmCompError

from ..childproc import ChildProcess, ChildProcessError
from ..ring import ring_bytes
from ..sessionlog.encoding import Packer
from .server import LiveStartError
from .settings import LiveSection
from .sink import LATCHED_TOPICS, STREAMED_TOPICS, TOPIC_BITS, LiveSink, LiveStats

START_TIMEOUT_S = 20.0
"""How long :meth:`LiveProcessSink.start` waits for the child's server, s."""
STALL_S = 3.0
"""A child that has not looped for this long is reported as stalled (stopped, or starved of
CPU: it runs at ``SCHED_IDLE``), s."""
_LATCHED_BITS = sum(TOPIC_BITS[t] for t in LATCHED_TOPICS)
_EMPTY = LiveStats(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)


class LiveChildError(CmmCompError, RuntimeError):
    """A problem the live view's child process reported (its text), its death or a stall."""


class LiveDownError(LiveChildError):
    """The live view's process died, stalled, or runs again after a stall (a change of
    ``live_up``; the daemon writes it to ``/cmm/status`` too)."""


def topics_of(mask: int) -> frozenset[str]:
    """The topics of a ``wanted`` bit mask."""
    return frozenset(t for t, bit in TOPIC_BITS.items() if mask & bit)


class LiveProcessSink(LiveSink):
    """:class:`LiveSink`'s interface for the daemon; the server and the encoding run in a child
    process at ``SCHED_IDLE``."""

    def __init__(
        self,
        settings: LiveSection,
        on_error: Callable[[BaseException], None] | None = None,
        name: str = "cmm-comp",
    ) -> None:
        super().__init__(settings, on_error, name)
        self._proc: ChildProcess | None = None
        self._port = 0
        self._child: LiveStats = _EMPTY
        self._forwarded = 0
        self._pack = Packer()
        self._down: str | None = None
        self._dead = False
        self._check_lock = threading.Lock()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Self:
        """Start the child and wait for its server; :class:`LiveStartError` (one line) when
        it cannot listen or does not start. Nothing is left running then."""
        try:
            self._proc = ChildProcess(
                "cmm_comp.daemon.live.child:child_main",
                (self.settings, self._name),
                ring_bytes(self.settings.queue),
                self._on_event,
                "live view",
                START_TIMEOUT_S,
            )
        except LiveStartError:
            self._stopped = True
            raise
        except (ChildProcessError, OSError) as exc:
            self._stopped = True
            raise LiveStartError(
                f"{exc}; is foxglove-sdk installed (pip install 'cmm-comp[live]')?"
            ) from None
        self._port = int(self._proc.info)
        self._topics = frozenset(STREAMED_TOPICS)
        return self

    @property
    def port(self) -> int:
        """The port the child's server listens on."""
        return self._port

    @property
    def child_pid(self) -> int | None:
        """The child process id (None before start)."""
        return self._proc.pid if self._proc is not None else None

    @property
    def wanted_topics(self) -> frozenset[str]:
        """The topics some client watches, as the child last published them."""
        if self._proc is None or self._stopped:
            return frozenset()
        return topics_of(self._proc.ring.wanted())

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Let the child send what it holds and stop its server; reap it (killed if it has
        not ended within ``timeout_s``, s). True when all of it was in time. Idempotent."""
        with self._lock:
            if self._stopped:
                return True
            self._stopped = True  # no producer writes into the ring from now on
        if self._proc is None:
            return True
        final = self._proc.stop(timeout_s)
        with self._check_lock:
            if final is not None:
                self._child = final
            elif not self._dead:
                self._went_down("live view: its process did not stop in time")
            self._dead = True
            self._lose_in_flight()
        self._proc.ring.close()
        return final is not None

    # ------------------------------------------------------------------ producers
    def log_many(self, topic: str, payloads: Sequence[Any], log_time_ns: int | None = None) -> int:
        """Offer ``payloads`` of ``topic`` (as :meth:`LiveSink.log_many`). A topic no client
        watches is counted and dropped at once; else the batch is pickled and copied into the
        shared ring (a full ring drops it, counted). Never blocks on the child."""
        n = len(payloads)
        bit = TOPIC_BITS.get(topic)
        proc = self._proc
        if bit is None or not n or proc is None:
            return n if bit is None or proc is None else 0
        if self._stopped:
            return 0
        if self._down is not None or not (bit & (_LATCHED_BITS | proc.ring.wanted())):
            with self._lock:
                self._offered += n
                self._idle += n
            return n
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        with self._lock:  # objects not plain data go as their repr: encode errors in the child
            self._offered += n
            if self._stopped:
                self._idle += n
            elif proc.ring.write(self._pack((topic, payloads, log_time_ns)), n):
                self._forwarded += n
            else:
                self._dropped += n
                self._dropped_by[topic] = self._dropped_by.get(topic, 0) + n
        return n

    # ------------------------------------------------------------------ statistics, health
    def stats(self) -> LiveStats:
        """The daemon's counters merged with the child's (which lag ≤ 0.1 s while it runs;
        exact after :meth:`stop`). ``queue_len`` includes the ring. Also checks the child:
        a stall is reported once (``on_error``) and ``up`` turns False."""
        self.check()
        with self._lock:
            offered, idle, dropped = self._offered, self._idle, self._dropped
            by_topic, forwarded = dict(self._dropped_by), self._forwarded
        c = self._child
        for topic, k in c.dropped_by_topic.items():
            by_topic[topic] = by_topic.get(topic, 0) + k
        return replace(
            c,
            offered=offered,
            not_encoded=idle + c.not_encoded,
            dropped=dropped + c.dropped,
            queue_len=max(0, forwarded - c.offered) + c.queue_len,
            dropped_by_topic=by_topic,
            up=self._down is None and not self._dead,
        )

    def check(self) -> None:
        """Read the child's status from shared memory and see whether it loops."""
        proc = self._proc
        if proc is None or self._dead or not self._check_lock.acquire(blocking=False):
            return
        try:
            status = proc.ring.status()
            if status is not None:
                self._child = status
            age_s = proc.stalled(STALL_S)
            if age_s is not None:
                self._went_down(
                    f"live view: its process has not run for {age_s:.1f} s (stopped, or "
                    "starved of CPU at idle priority); nothing is sent to it meanwhile"
                )
            elif self._down is not None:
                self._down = None
                self._report(LiveDownError("live view: its process runs again"))
        finally:
            self._check_lock.release()

    def _on_event(self, kind: str, body: Any) -> None:
        """The watch thread: the child's death (``lost``) as soon as its pipe closes."""
        if kind != "lost":
            self._report(LiveChildError(str(body)))
            return
        with self._check_lock:
            if self._dead:
                return
            # reported first (a stall seen before is superseded): whoever then sees
            # live_up 0 finds the death reported
            self._report(LiveDownError(str(body)))
            self._dead = True
            self._down = str(body)
            self._lose_in_flight()

    def _went_down(self, why: str) -> None:
        if self._down is None:
            self._report(LiveDownError(why))  # first, as for a death
            self._down = why

    def _lose_in_flight(self) -> None:
        """The child is gone: what it never took from the ring is dropped (counted in
        ``dropped``, not per topic: the ring's records are not read back)."""
        with self._lock:
            lost = max(0, self._forwarded - self._child.offered)
            self._forwarded -= lost
            self._dropped += lost
