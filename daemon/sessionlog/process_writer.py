""":class:`McapProcessLogger`, the daemon's session log: the JSON and MCAP work in a child
process (:mod:`..childproc`), off the reply path's interpreter and CPU.

The daemon's side of ``log`` / ``log_many`` pickles the batch (compact record tuples, small
dicts) and copies it into the shared-memory ring: no thread, no lock shared with a thread doing
long work, no system call, no wake-up. Under overload a batch that does not fit is dropped and
counted per topic; the frame topics (:data:`.logger.LOW_PRIORITY_TOPICS`) already once the
ring is half full, so answers and readings keep the other half.

The child (:func:`child_main`) writes straight from the ring into a
:class:`.writer.SessionWriter`: its writer thread runs at Linux ``SCHED_IDLE`` and polls the
ring every :data:`POLL_S`, so the JSON + MCAP + zstd work only takes CPU time no other task
wants; when :data:`HELP_HIGH` messages' worth of bytes wait (a machine loaded to 100 % starves
an idle thread) the main thread (normal priority) writes too. Either thread holds the lock
they share for at most :data:`BATCH` messages: a starved idle thread never holds it long. Counters, files and health reach the daemon
through the shared status block (``stats()``: ≤ :data:`REPORT_S` old while running, exact
after ``stop()``), errors through the pipe (``on_error`` in the watch thread).

``stop()`` sends the daemon's own drop counts with the stop request; the child reads what is
left in the ring, finishes the file (``session_end``, summary, indexes), reports and exits. If
the daemon dies (even SIGKILL) the child sees the pipe close, still reads the ring and finishes
the file: nothing the daemon had handed over is lost. See docs/mcap.md.
"""

from __future__ import annotations

import collections
import logging
import os
import pickle
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Unpack

from .. import memory
from ..childproc import ChildEnd, ChildProcess, ChildProcessError, portable
from ..osthread import expected_priority, lower_priority, name_os_thread
from ..ring import ring_bytes
from .encoding import Packer
from .logger import (
    LOW_PRIORITY_TOPICS,
    LoggerBase,
    LoggerStats,
    LogOptions,
    LogSettings,
    Payload,
)
from .writer import SessionWriter

_log = logging.getLogger(__name__)

WRITER_NAME = "cmm-comp daemon.sessionlog.process_writer"
"""The ``writer`` key of the files' ``session`` metadata."""
POLL_S = 0.01
"""The child reads the ring this often, s (bounds how long a message waits to be written)."""
REPORT_S = 0.1
"""The child publishes its counters at most this often while they change, s."""
BATCH = 32
"""Messages written per hold of the child's lock."""
HELP_HIGH, HELP_LOW = 8192, 1024
"""Ring backlog (in messages of :data:`MESSAGE_BYTES`) at which the child's main thread starts
writing itself, and until how many are left."""
MESSAGE_BYTES = 64
"""Ring bytes per message of ``queue_size``: the daemon logs batches of compact records, which
pickle to ~40-70 bytes a message."""
FILES_REPORTED = 64
"""Newest file names in each status (the daemon keeps the whole list)."""
_EMPTY = LoggerStats(0, 0, 0, 0, (), 0)


class McapWriterProcessError(ChildProcessError):
    """An error of the writer child that could not be passed on as its own exception type, its
    death, or a stop it did not finish in time."""


class McapProcessLogger(LoggerBase):
    """Log JSON messages to MCAP from a hot path; the writing happens in a child process.

    Arguments: see :class:`~.logger.LogSettings`; ``metadata``'s ``pid`` is the daemon's,
    ``writer_pid`` the child's. ``queue_size`` sizes the ring (:data:`MESSAGE_BYTES` a
    message: 6.4 MB at the default 100 000). Besides:

    :param on_error: called from the watch thread with every error the child meets (its own
        exception type when it pickles, else :class:`McapWriterProcessError`), with every
        message that could not be encoded (at most 10 a second; all are counted) and when the
        child dies unexpectedly.
    :raises: in the caller's thread, ValueError for bad settings, whatever the child raised on
        opening the first file (unwritable target), or :class:`..childproc.ChildProcessError`
        if it did not start within 60 s.
    """

    def __init__(
        self,
        target: str | os.PathLike[str],
        *,
        on_error: Callable[[BaseException], None] | None = None,
        **options: Unpack[LogOptions],
    ) -> None:
        meta = {"pid": str(os.getpid()), "writer": WRITER_NAME, **options.get("metadata", {})}
        settings = LogSettings.of(target, {**options, "metadata": meta})
        super().__init__(settings, on_error, "MCAP writer process")
        self._lock = threading.Lock()
        self._pack = Packer()
        self._capacity = ring_bytes(settings.queue_size, MESSAGE_BYTES)
        self._sent_by: dict[str, int] = {}
        self._drops_sent = 0
        self._child: dict[str, Any] = {"stats": _EMPTY, "healthy": True, "received": 0}
        self._files: list[Path] = []
        self._done = False
        self._proc = ChildProcess(
            f"{__name__}:child_main", settings, self._capacity, self._on_event, "mcap-writer"
        )
        self._take(self._proc.info)

    # ------------------------------------------------------------------ producers
    def log_many(
        self, topic: str, payloads: Sequence[Payload], log_time_ns: int | None = None
    ) -> int:
        """Hand ``payloads`` of ``topic`` over with one log time (integer ns; now if None):
        one pickle, one copy into the ring. Returns how many were taken: all, or none when
        the ring has no room for them (the frame topics: no room in its first half), stopped
        or failed (each counted as dropped)."""
        self._check(topic, payloads)
        n = len(payloads)
        if not n:
            return 0
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        limit = self._capacity // 2 if topic in LOW_PRIORITY_TOPICS else self._capacity
        if self._closed or self._proc.ring.used_bytes() >= limit:
            self._count_drop(topic, n)
            return 0
        drops = None
        if self._dropped != self._drops_sent:  # the file's counters include ours
            drops, self._drops_sent = self._dropped_snapshot(), self._dropped
        with self._lock:
            ok = not self._closed and self._proc.ring.write(
                self._pack((topic, payloads, log_time_ns, drops)), n
            )
            if ok:
                self._enqueued += n
                self._sent_by[topic] = self._sent_by.get(topic, 0) + n
        if not ok:
            self._count_drop(topic, n)
            if drops is not None:
                self._drops_sent = -1  # send them with the next batch taken
        return n if ok else 0

    def kick(self) -> None:
        """Nothing to wake: the child reads the ring at its own pace."""

    # ------------------------------------------------------------------ status
    def _take(self, status: Any) -> None:
        """Keep the child's newest status (and every file it names)."""
        if not status:
            return
        self._child = status
        for path in status["stats"].files:
            if path not in self._files:
                self._files.append(path)
        if not status["healthy"]:
            self._closed = True  # its writer failed: the hot path drops from now on

    def _on_event(self, kind: str, body: Any) -> None:
        if kind == "error":
            self._report(body)
            self._closed = True
        elif kind == "warning":
            self._report_quietly(body)
        elif kind == "lost":
            self._take(self._proc.ring.status())
            self._report(McapWriterProcessError(body))
            self._closed = True

    def _refresh(self) -> None:
        if not self._done:
            self._take(self._proc.ring.status())

    @property
    def healthy(self) -> bool:
        """True while the child runs and writes without error."""
        self._refresh()
        return (
            self._error is None
            and not self._done
            and self._proc.alive
            and bool(self._child["healthy"])
        )

    @property
    def files(self) -> tuple[Path, ...]:
        """Files the child has opened so far, in order."""
        self._refresh()
        return tuple(self._files)

    @property
    def child_pid(self) -> int:
        """Process id of the writer child."""
        return self._proc.pid

    def stats(self) -> LoggerStats:
        """The daemon's drops plus the child's last report (≤ :data:`REPORT_S` old while it
        runs; exact after ``stop()``). ``queue_len`` counts the ring too."""
        self._refresh()
        c: LoggerStats = self._child["stats"]
        dropped_by = self._dropped_snapshot()
        for topic, n in c.dropped_by_topic.items():
            dropped_by[topic] = dropped_by.get(topic, 0) + n
        in_ring = 0 if self._done else max(0, self._enqueued - self._child["received"])
        return replace(
            c,
            enqueued=self._enqueued,
            dropped=sum(dropped_by.values()),
            files=tuple(self._files),
            queue_len=in_ring + c.queue_len,
            dropped_by_topic=dropped_by,
        )

    # ------------------------------------------------------------------ lifecycle
    def stop(self, timeout_s: float = 5.0) -> bool:
        """Let the child write what it holds, finish the file and exit; reap it.

        Messages logged afterwards are dropped and counted. Returns True when the child
        finished within ``timeout_s`` (s); if not, it is killed (its file then ends at the
        last flush, like a crash). Idempotent.
        """
        with self._lock:
            if self._done:
                return True
            self._closed = True  # nothing more goes into the ring
        final = self._proc.stop(timeout_s, self._dropped_snapshot())
        if final is not None:
            self._take(final)
        elif not self._proc.lost:
            self._report(McapWriterProcessError("MCAP writer process did not finish in time"))
        self._done = True
        c: LoggerStats = self._child["stats"]
        for topic, sent in self._sent_by.items():  # handed over, neither written nor counted
            lost = sent - c.written_by_topic.get(topic, 0) - c.dropped_by_topic.get(topic, 0)
            if lost > 0:
                self._count_drop(topic, lost)
        self._proc.ring.close()
        return final is not None


# --------------------------------------------------------------------------- the child


def tune_malloc() -> bool:
    """glibc only (else nothing, False): a fixed mmap threshold (freed chunk buffers go back to
    the OS; glibc's dynamic threshold kept them in the heap: the child's RSS crept ~20 MiB/h
    at 1 kHz) and at most two malloc arenas (not one per thread)."""
    return memory.fix_mmap_threshold(memory.MMAP_THRESHOLD_BYTES, None) and memory.limit_arenas(2)


def child_main(end: ChildEnd) -> None:
    """The writer child: a :class:`.writer.SessionWriter` fed from the ring until the daemon
    asks to stop or is gone; see the module docstring. Exits the interpreter at once when done."""
    name_os_thread("mcap-child")
    tune_malloc()
    if end.settings is not None:
        _serve(end)
    end.close()
    # the file is finished and reported: exit at once. Interpreter finalization would have to
    # take the GIL, which a starved SCHED_IDLE writer thread may hold for seconds on a
    # saturated machine (seen: the parent had to kill a child that had finished its file)
    sys.stderr.flush()
    os._exit(0)


def _serve(end: ChildEnd) -> None:
    """Write the ring into a :class:`.writer.SessionWriter` until the daemon asks to stop or is
    gone, then finish the file and report ``stopped``."""
    settings: LogSettings = end.settings
    metadata = {
        **settings.metadata,
        "writer_pid": str(os.getpid()),
        "writer_priority": expected_priority("idle"),
    }
    errors: collections.deque[BaseException] = collections.deque()
    try:
        writer = SessionWriter.from_settings(replace(settings, metadata=metadata), errors.append)
    except BaseException as exc:
        end.send("start_error", portable(exc))
        return
    _ChildWriter(end, writer, errors).run()


class _ChildWriter:
    """The child's two writers of one file: an idle-priority thread that writes whenever the
    machine has a spare moment, and the main thread, which serves the pipe and helps while the
    ring's backlog is high; :attr:`lock` lets one of them at a time read the ring and write."""

    def __init__(
        self, end: ChildEnd, writer: SessionWriter, errors: collections.deque[BaseException]
    ) -> None:
        self.end, self.writer, self.errors = end, writer, errors
        self.lock = threading.Lock()
        self.done = threading.Event()
        self.received = 0
        self.current: collections.deque[tuple[str, Any, int]] = collections.deque()
        """The messages of the ring record being written (one record, taken whole)."""

    def step(self, limit: int = BATCH) -> int:
        """Write at most ``limit`` messages: the current record's, else the ring's next (lock
        held; short, so a starved idle thread never holds the lock long). 0: nothing waits."""
        if not self.current:
            for n, data in self.end.ring.read():
                topic, payloads, t_ns, drops = pickle.loads(data)
                if drops is not None:
                    self.writer.set_upstream_drops(drops)
                self.current.extend((topic, p, t_ns) for p in payloads)
                self.received += n
                break
        k = min(limit, len(self.current))
        for _ in range(k):
            self.writer.write(*self.current.popleft())
        return k

    def idle_writer(self) -> None:
        name_os_thread()
        took = lower_priority("idle")
        if took != expected_priority("idle"):
            _log.warning("MCAP writer priority idle not available: %s", took)
        while not self.done.is_set():
            with self.lock:
                n = 0 if self.done.is_set() else self.step()
                self.writer.tick()
            if not n:
                self.done.wait(POLL_S)

    def status(self) -> dict[str, Any]:
        st = self.writer.stats(upstream=False)  # the daemon adds its own drops
        st = replace(st, files=st.files[-FILES_REPORTED:])
        return {"stats": st, "healthy": self.writer.healthy, "received": self.received}

    def forward_errors(self) -> None:
        while self.errors:
            exc = self.errors.popleft()
            # the writer's error stops it; anything else (a message that could not be
            # encoded) is a warning: counted, recorded, the log goes on
            self.end.send("error" if exc is self.writer.error else "warning", portable(exc))

    def help_writer(self) -> float:
        """The main thread writes too while the ring's backlog is high (for at most
        :data:`REPORT_S`, then the loop reports and helps again)."""
        ring = self.end.ring
        if ring.backlog_bytes() > HELP_HIGH * MESSAGE_BYTES:
            until = time.monotonic() + REPORT_S
            while ring.backlog_bytes() > HELP_LOW * MESSAGE_BYTES:
                with self.lock:
                    if not self.step() or time.monotonic() > until:
                        break
        self.forward_errors()
        return POLL_S

    def run(self) -> None:
        threading.Thread(target=self.idle_writer, name="mcap-writer", daemon=True).start()
        last = None
        try:
            last = self.end.serve(self.status(), self.help_writer, self.status, REPORT_S)
        finally:
            # what the daemon handed over before it stopped (or died), written and the file
            # finished here, at this thread's normal priority: the writer thread at SCHED_IDLE
            # gets next to no CPU on a saturated machine (the daemon bounds the wait)
            self.done.set()
            with self.lock:
                while self.step(1 << 30):
                    pass
                if last is not None:
                    self.writer.set_upstream_drops(last)
                self.writer.stop()
            self.forward_errors()
            self.end.send("stopped", self.status())
