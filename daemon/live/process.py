""":class:`LiveProcessSink`: the live view with its server, encoding and scene in a child process.

Measured with the daemon (``benchmarks/bench_live.py --daemon``, docs/live.md): a sender
*thread* that builds JSON and feeds the SDK's server shares the daemon's GIL, and with a client
subscribed it added ~0.8 ms to the reply latency's p99 at 1 kHz. As the session log does
(``sessionlog.process_writer``), this sink keeps only the cheap front half in the daemon:

* the producers' side is :class:`.sink.LiveSink`'s own (a topic nobody watches is counted and
  dropped at once; else one short lock and a bounded drop-oldest queue, exact counts);
* a forwarder thread (``live-forwarder``) takes the queue every 10 ms, pickles the batches
  (record tuples and small dicts: ~µs per batch) and sends them with one ``send_bytes`` over a
  duplex pipe; it also receives the child's reports: which topics some client watches (so
  the daemon keeps dropping the others at no cost), the counters, errors;
* the child (:mod:`.child`, a fresh interpreter at ``SCHED_IDLE``) runs an ordinary
  :class:`LiveSink`: its own GIL, and CPU time only when nothing else wants it.

A child that is starved or stopped lets the pipe fill; the forwarder then waits and the queue
in the daemon drops its oldest messages, counted. A child that dies is reported through
``on_error``; the daemon goes on, what arrives afterwards is counted as not encoded.
"""

from __future__ import annotations

import multiprocessing
import pickle
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, Self

from cmm_comp.compensation.errors import CmmCompError

from ..osthread import name_os_thread
from .child import STOP
from .server import LiveStartError
from .settings import LiveSection
from .sink import LATCHED_TOPICS, POLL_S, STREAMED_TOPICS, LiveSink, LiveStats

START_TIMEOUT_S = 20.0
"""How long :meth:`LiveProcessSink.start` waits for the child's server, s."""
_CHILD_CODE = (
    "import sys\nfrom cmm_comp.daemon.live.child import child_entry\nchild_entry(int(sys.argv[1]))"
)
_EMPTY = LiveStats(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)


class LiveChildError(CmmCompError, RuntimeError):
    """A problem the live view's child process reported (its text), or its death."""


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
        self._port = 0
        self._child: LiveStats = _EMPTY
        self._forwarded = 0
        self._parent_errors = 0
        self._stop_deadline = float("inf")
        self._child_stopped = False

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Self:
        """Start the child and wait for its server; :class:`LiveStartError` (one line) when
        it cannot listen or does not start. Nothing is left running then."""
        self._conn, child_conn = multiprocessing.Pipe(duplex=True)
        fd = child_conn.fileno()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", _CHILD_CODE, str(fd)],
                pass_fds=(fd,),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
            )
        except OSError as exc:
            self._conn.close()
            raise LiveStartError(f"live view: cannot start its process ({exc})") from None
        finally:
            child_conn.close()
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
        self._wanted = LATCHED_TOPICS  # the child keeps the newest of these for new clients
        self._topics = frozenset(STREAMED_TOPICS)
        self._thread = threading.Thread(target=self._run, name="live-forwarder", daemon=True)
        self._thread.start()
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

    def _reap(self, timeout_s: float) -> int | None:
        proc = self._proc
        if proc is None:
            return None
        try:
            return proc.wait(timeout_s)
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

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Forward what is queued, let the child send it and stop its server, reap it (killed
        if it has not ended within ``timeout_s``, s). True when all of it was in time."""
        if self._stopped:
            return True
        self._stopped = True
        self._stop_deadline = time.monotonic() + timeout_s
        self._stopping.set()
        self._wake.set()
        ok = True
        if self._thread is not None:
            self._thread.join(max(0.0, self._stop_deadline - time.monotonic()))
            ok = not self._thread.is_alive()
        if self._proc is not None:
            try:
                self._proc.wait(max(0.0, self._stop_deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                ok = False
                self._proc.kill()
                self._proc.wait()
            ok &= self._child_stopped
        if self._thread is not None:
            self._thread.join(1.0)  # unblocked by the child's end
        if self._conn is not None:
            self._conn.close()
        return ok

    # ------------------------------------------------------------------ statistics
    def stats(self) -> LiveStats:
        """The daemon's counters merged with the child's (the child's lag ≤ 0.1 s while it
        runs; exact after :meth:`stop`). ``queue_len`` includes messages in the pipe."""
        with self._lock:
            offered, idle, dropped = self._offered, self._idle, self._dropped
            queued, by_topic = self._queued, dict(self._dropped_by)
        c = self._child
        in_flight = max(0, self._forwarded - c.offered)
        for topic, n in c.dropped_by_topic.items():
            by_topic[topic] = by_topic.get(topic, 0) + n
        return replace(
            c,
            offered=offered,
            not_encoded=idle + c.not_encoded,
            dropped=dropped + c.dropped,
            encode_errors=self._parent_errors + c.encode_errors,
            queue_len=queued + in_flight + c.queue_len,
            dropped_by_topic=by_topic,
        )

    # ------------------------------------------------------------------ forwarder thread
    def _run(self) -> None:
        name_os_thread()
        try:
            while True:
                self._wake.wait(POLL_S)
                self._wake.clear()
                stopping = self._stopping.is_set()
                self._receive()
                self._forward()
                if stopping:
                    self._conn.send_bytes(STOP)
                    self._await_stopped()
                    return
        except (OSError, EOFError, ValueError) as exc:  # the child died, the pipe closed
            self._child_lost(exc)

    def _receive(self, timeout_s: float = 0.0) -> None:
        conn = self._conn
        while conn.poll(timeout_s):
            kind, body = pickle.loads(conn.recv_bytes())
            if kind == "wanted":
                self._wanted = frozenset(body) | LATCHED_TOPICS
            elif kind == "stats":
                self._child = body
            elif kind == "error":
                self._report(LiveChildError(body))
            elif kind == "stopped":
                self._child_stopped = True
                return
            timeout_s = 0.0

    def _await_stopped(self) -> None:
        while not self._child_stopped:
            left = self._stop_deadline - time.monotonic()
            if left <= 0:
                return
            self._receive(min(left, 0.1))

    def _forward(self) -> None:
        with self._lock:
            if not self._batches:
                return
            batches, self._batches = list(self._batches), type(self._batches)()
            self._queued = 0
        try:
            data = pickle.dumps((batches, self._dropped), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # something not plain data in a payload: find it, keep the rest
            batches = self._picklable(batches)
            data = pickle.dumps((batches, self._dropped), protocol=pickle.HIGHEST_PROTOCOL)
        self._conn.send_bytes(data)
        self._forwarded += sum(len(p) for _, p, _ in batches)

    def _picklable(
        self, batches: list[tuple[str, Sequence[Any], int]]
    ) -> list[tuple[str, Sequence[Any], int]]:
        out: list[tuple[str, Sequence[Any], int]] = []
        for topic, payloads, t_ns in batches:
            keep: list[Any] = []
            for p in payloads:
                try:
                    pickle.dumps(p, protocol=pickle.HIGHEST_PROTOCOL)
                except Exception as exc:
                    self._parent_errors += 1
                    self._report(ValueError(f"live view: {topic} message not sent: {exc}"))
                    continue
                keep.append(p)
            if keep:
                out.append((topic, keep, t_ns))
        return out

    def _child_lost(self, exc: BaseException) -> None:
        """The child is gone: say so once, count what waits as dropped, stop taking more."""
        self._wanted = frozenset()
        if not self._stopping.is_set():
            code = self._proc.poll() if self._proc is not None else None
            self._report(LiveChildError(f"live view: its process ended ({exc!r}, exit {code})"))
        with self._lock:
            for topic, payloads, _ in self._batches:
                self._dropped += len(payloads)
                self._dropped_by[topic] = self._dropped_by.get(topic, 0) + len(payloads)
            self._batches.clear()
            self._queued = 0
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
