""":class:`LiveProcessSink`: the live view with its server, encoding and scene in a child process,
fed through shared memory: the daemon pays a copy, never a thread, a lock with another thread's
long work, a system call or a wake-up.

Measured with the daemon (``benchmarks/bench_live.py --daemon``, docs/live.md). The first
process sender had a forwarder thread in the daemon that took the queue every 10 ms, pickled it
and wrote it to a pipe: that thread competed with the reply thread for the GIL (and, preempted
by the kernel while holding it, made the reply thread wait), woke 100 times a second with a
client or without, and the child it fed sent every one of 2000 messages a second to the
client (Foxglove on the same two cores). Now:

* the producers' side (:meth:`LiveProcessSink.log_many`, called in the daemon's bookkeeping
  after the replies are sent) drops a topic nobody watches at once (one byte of shared memory
  read: the process publishes which topics some client watches), else pickles the batch and
  copies it into a shared-memory ring (:mod:`.ring`) under a lock only the producers take;
  a full ring (the process stopped or starved) drops the batch, counted exactly;
* the process (:mod:`.child`, a fresh interpreter at ``SCHED_IDLE``) polls the ring at
  ``update_rate_hz`` on its own, decimates (:mod:`.decimate`), encodes and serves; it writes
  its counters, its errors and a heartbeat into the same shared memory;
* whoever asks for statistics (the daemon's housekeeping, once per ``metrics.period_s``)
  reads them there and finds out whether the process died or stalled (no loop for
  :data:`STALL_S`): reported once through ``on_error``, ``live_up`` 0 in the counters, and
  nothing more is pickled or copied until it runs again. No answer of the daemon waits for it.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, Self

from cmm_comp.compensation.errors import CmmCompError

from .decimate import DECIMATED_TOPICS, is_not_ok
from .ring import HEADER_BYTES, SharedRing, ring_bytes, shared_file
from .server import LiveStartError
from .settings import LiveSection
from .sink import CORRECTED, LATCHED_TOPICS, STREAMED_TOPICS, LiveSink, LiveStats

START_TIMEOUT_S = 20.0
"""How long :meth:`LiveProcessSink.start` waits for the child's server, s."""
STALL_S = 3.0
"""A child that has not looped for this long is reported as stalled (stopped, or starved of
CPU: it runs at ``SCHED_IDLE``), s."""
STOP = b"stop"
"""The parent's last message on the pipe."""
TOPIC_BITS: dict[str, int] = {topic: 1 << i for i, topic in enumerate(STREAMED_TOPICS)}
"""The bit of each streamed topic in the shared ``wanted`` mask."""
_LATCHED_BITS = sum(TOPIC_BITS[t] for t in LATCHED_TOPICS)
_DECIMATED_BITS = sum(TOPIC_BITS[t] for t in DECIMATED_TOPICS)
_CHILD_CODE = (
    "import sys\nfrom cmm_comp.daemon.live.child import child_entry\n"
    "child_entry(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))"
)
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
    """:class:`LiveSink`'s interface; the server and the encoding run in a child process.

    :param priority: the child's CPU priority, ``"idle"`` (``SCHED_IDLE``) or ``"normal"``.
    """

    def __init__(
        self,
        settings: LiveSection,
        on_error: Callable[[BaseException], None] | None = None,
        name: str = "cmm-comp",
        priority: str = "idle",
    ) -> None:
        super().__init__(settings, on_error, name)
        if priority not in ("idle", "normal"):
            raise ValueError(f"priority = {priority!r}; allowed: idle, normal")
        self._priority = priority
        self._proc: subprocess.Popen[bytes] | None = None
        self._conn: Any = None
        self._ring: SharedRing | None = None
        self._port = 0
        self._child: LiveStats = _EMPTY
        self._forwarded = 0
        self._predecimated = 0
        self._last_ns: dict[str, int] = {}
        self._last_bad_ns = 0
        self._gap_ns = int(1e9 / (settings.update_rate_hz * settings.max_per_update))
        self._parent_errors = 0
        self._down: str | None = None
        self._dead = False
        self._errors_seen = 0
        self._check_lock = threading.Lock()

    # ------------------------------------------------------------------ lifecycle
    def start(self, thread: bool = True) -> Self:
        """Start the child and wait for its server; :class:`LiveStartError` (one line) when
        it cannot listen or does not start. Nothing is left running then. (``thread`` is
        :class:`LiveSink`'s; no thread runs in the daemon here.)"""
        capacity = ring_bytes(self.settings.queue)
        try:
            shm_fd = shared_file(HEADER_BYTES + capacity)
        except OSError as exc:
            raise LiveStartError(f"live view: no shared memory ({exc})") from None
        self._conn, child_conn = multiprocessing.Pipe(duplex=True)
        fd = child_conn.fileno()
        try:
            self._ring = SharedRing(shm_fd, capacity, populate=True)
            self._proc = subprocess.Popen(
                [sys.executable, "-c", _CHILD_CODE, str(fd), str(shm_fd), str(capacity)],
                pass_fds=(fd, shm_fd),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
            )
        except OSError as exc:
            self._conn.close()
            if self._ring is not None:
                self._ring.close()
                self._ring = None
            raise LiveStartError(f"live view: cannot start its process ({exc})") from None
        finally:
            child_conn.close()
            os.close(shm_fd)  # both mappings stay valid
        try:
            self._conn.send_bytes(pickle.dumps((self.settings, self._name, self._priority)))
            kind, body = self._first_reply()
        except BaseException:
            self._abort()
            raise
        if kind != "ready":
            self._abort()
            raise LiveStartError(str(body))
        self._port = int(body)
        self._topics = frozenset(STREAMED_TOPICS)
        return self

    def _first_reply(self) -> tuple[str, Any]:
        if not self._conn.poll(START_TIMEOUT_S):
            raise LiveStartError(f"live view: its process did not start in {START_TIMEOUT_S} s")
        try:
            return pickle.loads(self._conn.recv_bytes())  # type: ignore[no-any-return]
        except (EOFError, OSError):
            code = self._reap(5.0)
            raise LiveStartError(
                f"live view: its process exited at start (exit code {code}); is foxglove-sdk "
                "installed (pip install 'cmm-comp[live]')?"
            ) from None

    def _abort(self) -> None:
        self._conn.close()
        self._reap(5.0)
        self._stopped = True
        if self._ring is not None:
            self._ring.close()
            self._ring = None

    def _reap(self, timeout_s: float) -> int | None:
        proc = self._proc
        if proc is None:
            return None
        try:
            return proc.wait(max(0.0, timeout_s))
        except subprocess.TimeoutExpired:
            proc.kill()
            return proc.wait()

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
        ring = self._ring
        if ring is None or self._stopped:
            return frozenset()
        return topics_of(ring.wanted())

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Let the child send what it holds and stop its server; reap it (killed if it has
        not ended within ``timeout_s``, s). True when all of it was in time. Idempotent."""
        with self._lock:
            if self._stopped:
                return True
            self._stopped = True  # no producer writes into the ring from now on
        deadline = time.monotonic() + timeout_s
        ok = True
        final: Any = None
        if self._proc is not None and self._proc.poll() is None:
            try:
                self._conn.send_bytes(STOP)
                while final is None and self._conn.poll(max(0.0, deadline - time.monotonic())):
                    kind, body = pickle.loads(self._conn.recv_bytes())
                    if kind == "stopped":
                        final = body
            except (EOFError, OSError):
                pass
            ok = final is not None
        code = self._reap(max(0.0, deadline - time.monotonic()) if ok else 0.0)
        with self._check_lock:
            if final is not None:
                self._take_status(final)
            elif not self._dead:
                self._went_down(f"live view: its process did not stop in time (exit {code})")
            self._dead = True
            self._lose_in_flight()
        if self._conn is not None:
            self._conn.close()
        if self._ring is not None:
            self._ring.close()
            self._ring = None
        return ok

    # ------------------------------------------------------------------ producers
    def log_many(self, topic: str, payloads: Sequence[Any], log_time_ns: int | None = None) -> int:
        """Offer ``payloads`` of ``topic`` (as :meth:`LiveSink.log_many`). A topic no client
        watches is counted and dropped at once. A batch of ``/cmm/raw`` or ``/cmm/corrected``
        less than ``1 / (update_rate_hz × max_per_update)`` after the last one taken (by log
        time) is counted as decimated and dropped (an answer not ``ok`` has a gate of its
        own, :meth:`_gate`): the child could not send more. Else the batch is pickled and copied into the shared ring
        (a full ring drops it, counted). Never blocks on the child."""
        n = len(payloads)
        bit = TOPIC_BITS.get(topic)
        if bit is None or not n or self._ring is None:
            return n if bit is None or self._ring is None else 0
        if self._stopped:
            return 0
        if self._down is not None or not (bit & (_LATCHED_BITS | self._ring.wanted())):
            with self._lock:
                self._offered += n
                self._idle += n
            return n
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        if bit & _DECIMATED_BITS and not self._gate(topic, payloads, log_time_ns):
            with self._lock:  # the child would decimate it: not even pickled
                self._offered += n
                self._predecimated += n
            return n
        try:
            data = pickle.dumps((topic, payloads, log_time_ns), protocol=pickle.HIGHEST_PROTOCOL)
            bad = 0
        except Exception:  # something not plain data in a payload: find it, keep the rest
            data, bad = self._picklable(topic, payloads, log_time_ns)
        with self._lock:
            self._offered += n
            self._parent_errors += bad
            if self._stopped or self._ring is None:
                self._idle += n - bad
            elif self._ring.write(data, n - bad):
                self._forwarded += n - bad
            else:
                self._dropped += n - bad
                self._dropped_by[topic] = self._dropped_by.get(topic, 0) + n - bad
        return n

    def _gate(self, topic: str, payloads: Sequence[Any], t_ns: int) -> bool:
        """True to hand over this batch of a decimated topic: the first one at least one gap
        (``1 / (update_rate_hz × max_per_update)``, by log time) after the last one taken;
        within a gap, a ``/cmm/corrected`` batch holding an answer not ok, if no such batch
        was taken within a gap either (so a blip always passes, a flood at most doubles)."""
        gap = self._gap_ns
        if not 0 < t_ns - self._last_ns.get(topic, 0) < gap:
            self._last_ns[topic] = t_ns
            return True
        if topic != CORRECTED or 0 < t_ns - self._last_bad_ns < gap:
            return False
        if any(map(is_not_ok, payloads)):
            self._last_bad_ns = t_ns
            return True
        return False

    def _picklable(self, topic: str, payloads: Sequence[Any], t_ns: int) -> tuple[bytes, int]:
        keep: list[Any] = []
        for p in payloads:
            try:
                pickle.dumps(p, protocol=pickle.HIGHEST_PROTOCOL)
            except Exception as exc:
                self._report(ValueError(f"live view: {topic} message not sent: {exc}"))
                continue
            keep.append(p)
        data = pickle.dumps((topic, keep, t_ns), protocol=pickle.HIGHEST_PROTOCOL)
        return data, len(payloads) - len(keep)

    def kick(self) -> None:
        """Nothing to wake: the child polls the ring at its own rate."""

    # ------------------------------------------------------------------ statistics, health
    def stats(self) -> LiveStats:
        """The daemon's counters merged with the child's (which lag ≤ 0.1 s while it runs;
        exact after :meth:`stop`). ``queue_len`` includes the ring. Also checks the child:
        a death or a stall is reported once (``on_error``) and ``up`` turns False."""
        self.check()
        with self._lock:
            offered, idle, dropped = self._offered, self._idle, self._dropped
            by_topic, forwarded = dict(self._dropped_by), self._forwarded
            errors, predecimated = self._parent_errors, self._predecimated
        c = self._child
        for topic, k in c.dropped_by_topic.items():
            by_topic[topic] = by_topic.get(topic, 0) + k
        return replace(
            c,
            offered=offered,
            not_encoded=idle + c.not_encoded,
            decimated=predecimated + c.decimated,
            dropped=dropped + c.dropped,
            encode_errors=errors + c.encode_errors,
            queue_len=max(0, forwarded - c.offered) + c.queue_len,
            dropped_by_topic=by_topic,
            up=self._down is None and self._ring is not None,
        )

    def check(self) -> None:
        """Read the child's status from shared memory and see whether it lives and loops."""
        ring = self._ring
        if ring is None or self._dead or not self._check_lock.acquire(blocking=False):
            return
        try:
            status = ring.status()
            if status is not None:
                self._take_status(status)
            code = self._proc.poll() if self._proc is not None else None
            if code is not None:
                self._dead = True
                self._down = None  # a stall seen before is superseded: report the death
                self._went_down(f"live view: its process ended (exit code {code})")
                self._lose_in_flight()
                return
            age_s = (time.monotonic_ns() - ring.heartbeat_ns()) / 1e9
            if age_s > STALL_S:
                self._went_down(
                    f"live view: its process has not run for {age_s:.1f} s (stopped, or "
                    "starved of CPU at idle priority); nothing is sent to it meanwhile"
                )
            elif self._down is not None:
                self._down = None
                self._report(LiveDownError("live view: its process runs again"))
        finally:
            self._check_lock.release()

    def _take_status(self, status: tuple[LiveStats, int, list[str]]) -> None:
        stats, n_errors, texts = status
        self._child = stats
        new = n_errors - self._errors_seen
        if new > len(texts):
            self._report(
                LiveChildError(f"live view: {new - len(texts)} more errors in its process")
            )
        for text in texts[max(0, len(texts) - new) :] if new > 0 else ():
            self._report(LiveChildError(text))
        self._errors_seen = n_errors

    def _went_down(self, why: str) -> None:
        if self._down is None:
            self._down = why
            self._report(LiveDownError(why))

    def _lose_in_flight(self) -> None:
        """The child is gone: what it never took from the ring is dropped (counted in
        ``dropped``, not per topic: the ring's records are not read back)."""
        with self._lock:
            lost = max(0, self._forwarded - self._child.offered)
            self._forwarded -= lost
            self._dropped += lost


def live_sink(
    settings: LiveSection,
    on_error: Callable[[BaseException], None] | None = None,
    name: str = "cmm-comp",
) -> LiveSink:
    """The sink ``settings.sender`` asks for, not started: :class:`LiveProcessSink`
    (``"process"``) or :class:`LiveSink` (``"thread"``)."""
    if settings.sender == "process":
        return LiveProcessSink(settings, on_error, name)
    return LiveSink(settings, on_error, name)
