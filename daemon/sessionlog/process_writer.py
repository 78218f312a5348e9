"""MCAP session logger whose JSON and MCAP work runs in a child process (off the parent's GIL).

``McapProcessLogger`` has the public interface of :class:`.thread_writer.McapLogger` (both
implement :class:`.logger.SessionLogger`). In the
parent, ``log()`` only appends ``(topic, payload, log_time_ns)`` to a bounded deque (drop and
count when full, never block). A small forwarder thread pickles batches of up to
:data:`BATCH` messages and sends each batch with one ``Connection.send_bytes`` over a
``multiprocessing`` pipe to a child process started with the ``spawn`` method (never ``fork``:
the parent has threads). The child runs an ordinary :class:`McapLogger` (its own writer thread,
the same MCAP/JSON code) and reports its counters, files and errors back over the same duplex
pipe, so ``stats()``, ``error``, ``healthy``, ``files`` and ``on_error`` work in the parent.

Why: with the thread logger, the writer's ~10 µs of JSON + MCAP per message competes for the
GIL with the reply path of the same process. Here the parent pays ~0.1 µs per message (pickling
compact record tuples, in the forwarder thread) and the rest happens in another interpreter,
whose writer thread runs at ``SCHED_IDLE`` (``priority="idle"``): it only takes CPU time no
other task wants, so it never delays a reply; the child's main thread (normal priority) writes
itself when the backlog grows, so a fully loaded machine does not starve the log.

Shutdown: ``stop()`` forwards what is queued, sends a sentinel, and the child drains, finishes
the file (``session_end``, summary, indexes) and exits; the parent joins it. If the parent dies
(even SIGKILL) the child sees EOF on the pipe (or notices its parent changed) and still finishes
the file cleanly: only messages not yet forwarded (a few ms) are lost, and the file has its
summary — better than the thread logger, whose file is then cut. The child ignores SIGINT and
SIGTERM (a Ctrl-C or a systemd stop reaches the whole process group): the parent's handler calls
``stop()``, which is what ends the child; a child left alone ends at the parent's exit by EOF.
"""

from __future__ import annotations

import io
import logging
import multiprocessing
import numbers
import os
import pickle
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType

from ..osthread import name_os_thread
from .encoding import NotJson, safe_repr
from .logger import HotPathQueue, LoggerStats, LogSettings, QueuedMessage
from .schemas import TOPIC_SCHEMAS, TopicSchema
from .writer_child import STOP, McapWriterProcessError

_log = logging.getLogger(__name__)

BATCH = 64
"""Messages per pickled batch (pickling holds the parent's GIL ~0.4 µs per message)."""
_POLL_S = 0.01
"""Forwarder wake-up period when idle, s (bounds the extra latency of a message to the child)."""
_START_TIMEOUT_S = 60.0
"""How long the constructor waits for the child to open the first file, s."""
WRITER_NAME = "cmm-comp daemon.sessionlog.process_writer"
"""The ``writer`` key of the files' ``session`` metadata."""
# The child imports only what it runs (the writer modules, osthread, protocol.codes,
# compensation.errors, mcap): every package __init__ of the project loads its names lazily, so
# no grid, numpy, scipy, python-can or pymodbus is imported for nothing (~0.1 s start-up).
_CHILD_CODE = (
    "import os, sys\n"
    "from cmm_comp.daemon.sessionlog.writer_child import child_entry\n"
    "child_entry(int(sys.argv[1]), int(sys.argv[2]))\n"
    # the file is finished and reported: exit at once. Interpreter finalization would have
    # to take the GIL, which a starved SCHED_IDLE writer thread may hold for seconds on a
    # saturated machine (seen: the parent had to kill a child that had finished its file)
    "sys.stderr.flush()\n"
    "os._exit(0)"
)


def _child_argv(fd: int) -> list[str]:
    """The child's command line: the pipe fd and our pid."""
    return [sys.executable, "-c", _CHILD_CODE, str(fd), str(os.getpid())]


class _PlainPickler(pickle.Pickler):
    """Pickles plain data as usual (str, bytes, int, float, bool, None, tuple, list, dict, set
    take the C fast path and never reach :meth:`reducer_override`); numpy-like numbers become
    Python numbers; any other object becomes a :class:`.encoding.NotJson` holding its repr, so
    the child never imports a class and a bad payload still becomes an error record there."""

    def reducer_override(self, obj: Any) -> Any:
        if isinstance(obj, numbers.Integral) and not isinstance(obj, bool):
            return int, (int(obj),)
        if isinstance(obj, numbers.Real) and not isinstance(obj, bool):
            return float, (float(obj),)
        if isinstance(obj, type):
            return NotImplemented  # classes pickle by reference (NotJson itself)
        return NotJson, (safe_repr(obj),)


def _dumps(obj: Any) -> bytes:
    buf = io.BytesIO()
    _PlainPickler(buf, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    return buf.getvalue()


def pickle_batch(dropped_by_topic: dict[str, int], batch: list[QueuedMessage]) -> bytes:
    """The bytes sent to the child for one batch: ``(dropped_by_topic, batch)``. A message that
    cannot be pickled at all (nested too deep...) is replaced by a :class:`.encoding.NotJson`
    payload (the child writes its error record), never lost and never fatal."""
    try:
        return _dumps((dropped_by_topic, batch))
    except Exception:
        pass
    safe: list[tuple[str, Any, Any]] = []
    for topic, payload, t_ns in batch:
        try:
            _dumps((payload, t_ns))
            safe.append((topic, payload, t_ns))
        except Exception as exc:
            text = f"<not picklable: {type(exc).__name__}> {safe_repr(payload, 200)}"
            safe.append((topic, NotJson(text), t_ns if type(t_ns) is int else 0))
    return _dumps((dropped_by_topic, safe))


# --------------------------------------------------------------------------- parent side


class McapProcessLogger(HotPathQueue):
    """Log JSON messages to MCAP from a hot path; the writing happens in a child process.

    Same interface and arguments as :class:`.thread_writer.McapLogger` (the shared ones are
    :class:`~.logger.LogSettings`), except ``opener`` (a callable cannot be sent to the child);
    ``metadata``'s ``pid`` is the parent's, ``writer_pid`` the child's. Besides:

    :param on_error: called from the parent's forwarder thread with every error the child
        meets (its own exception type when it pickles, else :class:`McapWriterProcessError`),
        and when the child dies unexpectedly.
    :param priority: the child's CPU priority, ``idle`` (default: Linux ``SCHED_IDLE``, see
        :func:`.writer_child.lower_priority`) or ``normal``; what took effect is in the file's ``session``
        metadata (``writer_priority``).
    :raises: in the caller's thread, ValueError for bad settings, whatever the child's
        ``McapLogger`` raised on opening the first file (unwritable target), or
        :class:`McapWriterProcessError` if the child did not start within 60 s.
    """

    def __init__(
        self,
        target: str | os.PathLike[str],
        *,
        roll_bytes: int | None = None,
        roll_s: float | None = None,
        flush_period_s: float = 1.0,
        chunk_size: int = 256 * 1024,
        queue_size: int = 100_000,
        compression: CompressionType = CompressionType.ZSTD,
        fsync: bool = False,
        metadata: Mapping[str, str] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        schemas: Mapping[str, TopicSchema] = TOPIC_SCHEMAS,
        priority: str = "idle",
    ) -> None:
        if priority not in ("idle", "normal"):
            raise ValueError(f"priority={priority!r} must be 'idle' or 'normal'")
        settings = LogSettings(
            Path(target),
            roll_bytes,
            roll_s,
            flush_period_s,
            chunk_size,
            queue_size,
            compression,
            fsync,
            {"pid": str(os.getpid()), "writer": WRITER_NAME, **dict(metadata or {})},
            schemas,
        )
        super().__init__(settings, on_error, "MCAP writer process")
        self._sent = 0
        self._sent_by: dict[str, int] = {}
        self._child: dict[str, Any] = {
            "received": 0,
            "written": 0,
            "dropped": 0,
            "encode_errors": 0,
            "files": (),
            "queue_len": 0,
            "healthy": True,
            "dropped_by_topic": {},
            "encode_errors_by_topic": {},
            "written_by_topic": {},
            "flushed": 0,
        }
        self._done = False
        self._deadline = float("inf")
        # A fresh interpreter (exec, like the "spawn" start method; never fork: the parent has
        # threads), started without multiprocessing.Process so that the parent's __main__ is
        # not re-imported in the child. The duplex pipe is a multiprocessing.Pipe.
        self._conn, child_conn = multiprocessing.Pipe(duplex=True)
        try:
            fd = child_conn.fileno()
            self._proc = subprocess.Popen(
                _child_argv(fd),
                pass_fds=(fd,),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
            )
        except BaseException:
            self._conn.close()
            raise
        finally:
            child_conn.close()
        try:
            self._conn.send_bytes(pickle.dumps((settings, priority)))
            self._await_ready()
        except BaseException:
            self._conn.close()
            self._reap(5.0)
            raise
        self._proc_pid: int = self._proc.pid
        self._thread = threading.Thread(target=self._run, name="mcap-forwarder", daemon=True)
        self._thread.start()

    def _await_ready(self) -> None:
        if not self._conn.poll(_START_TIMEOUT_S):
            raise McapWriterProcessError(
                f"MCAP writer process did not start in {_START_TIMEOUT_S} s"
            )
        try:
            kind, body = pickle.loads(self._conn.recv_bytes())
        except EOFError:
            raise McapWriterProcessError(
                f"MCAP writer process exited at start (exit code {self._reap(5.0)})"
            ) from None
        if kind == "init_error":
            raise body
        self._child = body

    # ------------------------------------------------------------------ status (log(), error: HotPathQueue)

    @property
    def healthy(self) -> bool:
        """True while the forwarder and the child run without error."""
        return (
            self._error is None
            and self._thread.is_alive()
            and not self._done
            and bool(self._child["healthy"])
        )

    @property
    def files(self) -> tuple[Path, ...]:
        """Files the child has opened so far, in order."""
        return tuple(self._child["files"])

    @property
    def child_pid(self) -> int:
        """Process id of the writer child."""
        return self._proc_pid

    def stats(self) -> LoggerStats:
        """A snapshot of the counters: the parent's queue plus the child's last report (sent at
        most every 0.1 s while running; exact after ``stop()``)."""
        c = self._child
        dropped_by = self._dropped_snapshot()
        for topic, n in c["dropped_by_topic"].items():
            dropped_by[topic] = dropped_by.get(topic, 0) + int(n)
        return LoggerStats(
            enqueued=self._enqueued,
            written=int(c["written"]),
            dropped=sum(dropped_by.values()),
            encode_errors=int(c["encode_errors"]),
            files=tuple(c["files"]),
            queue_len=len(self._queue) + int(c["queue_len"]),
            dropped_by_topic=dropped_by,
            encode_errors_by_topic=dict(c["encode_errors_by_topic"]),
            written_by_topic=dict(c["written_by_topic"]),
            flushed=int(c["flushed"]),
        )

    # ------------------------------------------------------------------ lifecycle

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Forward what is queued, let the child finish the file and exit; join both.

        Safe from a signal handler in the main thread. Messages logged afterwards are dropped
        and counted. Returns True when the child finished within ``timeout_s`` (s); if not,
        the child is killed (its file then ends at the last flush, like a crash).
        """
        self._deadline = min(self._deadline, time.monotonic() + timeout_s)
        self._stopping.set()  # before _closed: the forwarder then forwards, not drops
        self._closed = True
        self._wake.set()
        if threading.current_thread() is not self._thread:
            # + the reaping after "done" (the forwarder waits 5 s for the exit, then kills)
            self._thread.join(max(0.0, self._deadline - time.monotonic()) + 12.0)
        return self._done and not self._thread.is_alive()

    # ------------------------------------------------------------------ forwarder thread

    def _handle(self, data: bytes) -> None:
        kind, body = pickle.loads(data)
        if kind == "error":
            self._report(body)
        elif kind == "warning":  # a message that could not be encoded: the log goes on
            self._report_quietly(body)
        else:
            self._child = body
            if kind == "done":
                self._done = True
            if not body["healthy"] and not self._closed:
                # the child's writer failed: keep the hot path cheap, drop from now on
                self._closed = True

    def _poll_child(self, timeout_s: float = 0.0) -> None:
        """Read every report waiting (waiting up to ``timeout_s`` for the first one)."""
        conn = self._conn
        while not self._done and conn.poll(timeout_s):
            self._handle(conn.recv_bytes())
            timeout_s = 0.0

    def _send_batch(self) -> int:
        queue = self._queue
        batch: list[QueuedMessage] = []
        try:
            while len(batch) < BATCH:
                batch.append(queue.popleft())
        except IndexError:
            pass
        if batch:
            if self._closed and not self._stopping.is_set():  # child failed: just count
                self._count_drops(batch)
            else:
                self._send(batch)
        return len(batch)

    def _send(self, batch: list[QueuedMessage]) -> None:
        """Send one batch with our drops so far (per topic; the child writes them into the
        file's counters and ``session_end``)."""
        try:
            self._conn.send_bytes(pickle_batch(self._dropped_snapshot(), batch))
        except BaseException:
            self._count_drops(batch)  # never reached the child: counted, not lost silently
            raise
        sent_by = self._sent_by
        for topic, _, _ in batch:
            sent_by[topic] = sent_by.get(topic, 0) + 1
        self._sent += len(batch)

    def _run(self) -> None:
        name_os_thread()
        try:
            while True:
                stopping = self._stopping.is_set()
                n = self._send_batch()
                self._poll_child()
                if stopping and not self._queue:
                    break
                if n >= BATCH:
                    time.sleep(0)  # yield the GIL between batches: the reply path comes first
                elif n == 0:
                    self._wake.wait(_POLL_S)
                    self._wake.clear()
            self._send([])  # our final drop counts, for the file's session_end
            self._conn.send_bytes(STOP)
            while not self._done:
                left = self._deadline - time.monotonic()
                if left <= 0:
                    break
                self._poll_child(min(left, 0.5))
        except (EOFError, OSError) as exc:
            try:
                code: int | None = self._proc.wait(0.5)
            except subprocess.TimeoutExpired:
                code = None
            self._report(
                McapWriterProcessError(f"MCAP writer process lost ({exc!r}, exit code {code})")
            )
            self._closed = True
        except BaseException as exc:
            self._report(exc)
            self._closed = True
        finally:
            self._finish_child()

    def _reap(self, timeout_s: float) -> int | None:
        """Wait up to ``timeout_s`` (s) for the child, then kill it; always reaped (no zombie)
        unless even the kill does not take effect within 5 s. Returns its exit code."""
        try:
            return self._proc.wait(max(0.0, timeout_s))
        except subprocess.TimeoutExpired:
            pass
        _log.error("MCAP writer process did not finish in time: killed")
        self._proc.kill()
        try:
            return self._proc.wait(5.0)
        except subprocess.TimeoutExpired:  # pragma: no cover - a process stuck in the kernel
            return None

    def _finish_child(self) -> None:
        """Join the child (kill it after the deadline) and account for lost messages."""
        if not self._done and self._proc.poll() is None and self._error is None:
            left = self._deadline - time.monotonic()
            if left <= 0:
                self._report(McapWriterProcessError("MCAP writer process did not finish in time"))
        self._reap(5.0 if self._done else self._deadline - time.monotonic())
        c = self._child
        # everything sent that the child neither wrote nor counted is lost: count it here
        written_by, dropped_by = c["written_by_topic"], c["dropped_by_topic"]
        for topic, sent in self._sent_by.items():
            lost = sent - int(written_by.get(topic, 0)) - int(dropped_by.get(topic, 0))
            if lost > 0:
                self._count_drop(topic, lost)
        self._closed = True
        self._drop_queue()
        self._conn.close()
