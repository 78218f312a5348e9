"""The one child-process mechanism of the daemon: the MCAP writer and the live view each run in
a fresh interpreter, fed through shared memory (:mod:`.ring`), off the reply path.

Parent side, :class:`ChildProcess`: starts ``python -c`` (exec, like the ``spawn`` start
method; never ``fork``: the daemon has threads) with one end of a duplex pipe and the shared
memory; sends the child its settings; waits for ``("ready", info)``. Then the daemon's
producers copy pickled batches into the ring (``ChildProcess.ring.write``: no thread, no system
call, no wake-up; a full ring refuses, the caller drops and counts; one writer at a time) and
the child reads them at its own pace. The child publishes its status (a pickled object) and a
heartbeat in the same shared memory (``ring.status()``, :meth:`ChildProcess.stalled`). The pipe
carries only rare events, child → parent: ``("error" | "warning", exception)``, the final
``("stopped", status)``; one parent thread (``<name>-watch``) waits on it in a system call and
wakes only for them, or when the child dies (EOF: reported once, with its exit code).

Child side, :class:`ChildEnd`: ignores SIGINT and SIGTERM (a Ctrl-C or a systemd stop reaches
the whole process group; the parent stops it through the pipe), maps the ring, reads its
settings. A child ends on ``("stop", last)`` from the parent, or when the pipe closes or its
parent changes (the daemon died, even by SIGKILL): it then finishes its work alone.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

from cmm_comp.compensation.errors import CmmCompError

from .osthread import name_os_thread
from .ring import HEADER_BYTES, SharedRing, shared_file

_log = logging.getLogger(__name__)

STOP = "stop"
"""Kind of the parent's last message: ``("stop", last)``."""


class ChildProcessError(CmmCompError, RuntimeError):
    """A child process did not start, or an error of it could not be passed on as itself."""


def portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a :class:`ChildProcessError` with its repr."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return ChildProcessError(repr(exc))
    return exc


def _send(conn: Connection, kind: str, body: Any) -> None:
    conn.send_bytes(pickle.dumps((kind, body), protocol=pickle.HIGHEST_PROTOCOL))


class ChildProcess:
    """Start and watch one child; see the module docstring.

    :param entry: ``"module:function"``; the child runs ``function(ChildEnd)``.
    :param settings: sent to the child first (pickled).
    :param capacity: ring bytes (a positive multiple of 16).
    :param on_event: called in the watch thread with ``(kind, body)`` of each event the child
        sends (``error``, ``warning``, or anything but ``stopped``), and ``("lost", text)``
        once when the pipe closes before ``stopped`` (the child died).
    :param start_timeout_s: how long to wait for ``ready``.
    :raises: the exception the child sent as ``("start_error", exc)``, or
        :class:`ChildProcessError` if it exited or stayed silent; nothing is left running.
    """

    def __init__(
        self,
        entry: str,
        settings: Any,
        capacity: int,
        on_event: Callable[[str, Any], None],
        name: str,
        start_timeout_s: float = 60.0,
    ) -> None:
        module, _, function = entry.partition(":")
        self.name = name
        self._on_event = on_event
        self.final: Any = None
        self.lost = False
        self._done = threading.Event()
        shm_fd = shared_file(HEADER_BYTES + capacity)
        self._conn, child_conn = multiprocessing.Pipe(duplex=True)
        fd = child_conn.fileno()
        code = (
            f"import sys\nfrom {module} import {function} as main\n"
            "from cmm_comp.daemon.childproc import ChildEnd\n"
            "main(ChildEnd(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])))"
        )
        try:
            self.ring = SharedRing(shm_fd, capacity, populate=True)
            args = [str(fd), str(shm_fd), str(capacity), str(os.getpid())]
            self._proc = subprocess.Popen(
                [sys.executable, "-c", code, *args],
                pass_fds=(fd, shm_fd),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
            )
        except BaseException:
            self._conn.close()
            raise
        finally:
            child_conn.close()
            os.close(shm_fd)  # both mappings stay valid
        try:
            self._conn.send_bytes(pickle.dumps(settings, protocol=pickle.HIGHEST_PROTOCOL))
            self.info = self._first_reply(start_timeout_s)
        except BaseException:
            self._conn.close()
            self.reap(5.0)
            self.ring.close()
            raise
        self.pid: int = self._proc.pid
        watch = f"{name.split()[0]}-watch"
        self._watch = threading.Thread(target=self._run, name=watch, daemon=True)
        self._watch.start()

    def _first_reply(self, timeout_s: float) -> Any:
        if not self._conn.poll(timeout_s):
            raise ChildProcessError(f"{self.name}: its process did not start in {timeout_s} s")
        try:
            kind, body = pickle.loads(self._conn.recv_bytes())
        except (EOFError, OSError):
            code = self.reap(5.0)
            raise ChildProcessError(
                f"{self.name}: its process exited at start (exit code {code})"
            ) from None
        if kind == "start_error":
            raise body
        return body

    def _run(self) -> None:
        name_os_thread()
        try:
            while True:
                kind, body = pickle.loads(self._conn.recv_bytes())
                if kind == "stopped":
                    self.final = body
                    return
                self._on_event(kind, body)
        except (EOFError, OSError):
            self.lost = True
            code = self.reap(0.5, kill=False)
            self._on_event("lost", f"{self.name}: its process ended (exit code {code})")
        except Exception as exc:  # a bug here must not pass silently
            _log.exception("%s: watch thread failed", self.name)
            self._on_event("error", exc)
        finally:
            self._done.set()

    # ------------------------------------------------------------------ the producers
    def stalled(self, limit_s: float) -> float | None:
        """Seconds since the child's last heartbeat when more than ``limit_s``, else None."""
        age_s = (time.monotonic_ns() - self.ring.heartbeat_ns()) / 1e9
        return age_s if age_s > limit_s else None

    @property
    def alive(self) -> bool:
        """True while the child runs and its pipe is open."""
        return not self.lost and self._proc.poll() is None

    # ------------------------------------------------------------------ stopping
    def stop(self, timeout_s: float, last: Any = None) -> Any:
        """Send ``("stop", last)``, wait (at most ``timeout_s``, s) for the child's final
        status, reap it (killed when late). Returns that status, or None."""
        deadline = time.monotonic() + timeout_s
        if not self._done.is_set():
            with contextlib.suppress(OSError):
                _send(self._conn, STOP, last)
            self._done.wait(max(0.0, deadline - time.monotonic()))
        self.reap(max(0.0, deadline - time.monotonic()) if self.final is not None else 0.0)
        self._conn.close()
        self._watch.join(1.0)
        return self.final

    def reap(self, timeout_s: float, kill: bool = True) -> int | None:
        """Wait up to ``timeout_s`` (s) for the child's exit, then kill it (``kill``); returns
        its exit code (None while it runs)."""
        try:
            return self._proc.wait(max(0.0, timeout_s))
        except subprocess.TimeoutExpired:
            if not kill:
                return None
        _log.error("%s: its process did not end in time: killed", self.name)
        self._proc.kill()
        try:
            return self._proc.wait(5.0)
        except subprocess.TimeoutExpired:  # pragma: no cover - a process stuck in the kernel
            return None


class ChildEnd:
    """The child's side: the pipe, the ring, the settings, the parent's liveness."""

    def __init__(self, fd: int, shm_fd: int, capacity: int, parent_pid: int) -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        self.conn = Connection(fd)
        self.ring = SharedRing(shm_fd, capacity)
        os.close(shm_fd)
        self.parent_pid = parent_pid
        self.parent_alive = True
        try:
            self.settings: Any = pickle.loads(self.conn.recv_bytes())
        except (EOFError, OSError):
            self.parent_alive = False
            self.settings = None

    def send(self, kind: str, body: Any) -> None:
        """Send an event to the parent (nothing once it is gone)."""
        if self.parent_alive:
            try:
                _send(self.conn, kind, body)
            except OSError:
                self.parent_alive = False

    def stop_requested(self, timeout_s: float = 0.0) -> tuple[bool, Any]:
        """``(True, last)`` once the parent asked to stop or is gone (the pipe closed, or this
        process was re-parented); waits up to ``timeout_s`` (s) for the pipe."""
        try:
            if self.conn.poll(timeout_s):
                kind, body = pickle.loads(self.conn.recv_bytes())
                return kind == STOP, body
        except (EOFError, OSError):
            self.parent_alive = False
            return True, None
        if os.getppid() != self.parent_pid:  # the daemon died; the pipe is held elsewhere
            self.parent_alive = False
            return True, None
        return False, None

    def serve(
        self,
        ready: Any,
        tick: Callable[[], float],
        status: Callable[[], Any],
        status_period_s: float,
    ) -> Any:
        """The child's loop, for every child: a heartbeat, ``("ready", ready)`` to the parent,
        then rounds of ``tick()`` (one round of work; returns how long to wait for the parent
        after it, s), a heartbeat each, ``status()`` published at most every
        ``status_period_s`` (s); until the parent asks to stop or is gone. Returns the
        ``last`` of the stop request (None when the parent is gone)."""
        self.ring.beat(time.monotonic_ns())
        self.send("ready", ready)
        next_status = 0.0
        while True:
            t0 = time.monotonic()
            self.ring.beat(time.monotonic_ns())
            wait_s = tick()
            if t0 >= next_status:
                next_status = t0 + status_period_s
                self.publish(status())
            stop, last = self.stop_requested(wait_s)
            if stop:
                return last

    def publish(self, status: Any) -> bool:
        """Publish ``status`` in the shared memory; False when its pickle is too large."""
        return self.ring.set_status(pickle.dumps(status, protocol=pickle.HIGHEST_PROTOCOL))

    def close(self) -> None:
        self.conn.close()
