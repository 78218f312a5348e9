"""Grid loading in a worker process: a reload never holds the reply path's interpreter lock.

Reading a grid, checking its trust and building its interpolation tables takes 60 ms to over
a second of CPU, much of it inside compiled calls that hold Python's GIL for tens of ms; in a
thread of the daemon that shows up directly in the reply latency. :class:`ProcessGridLoader`
runs :func:`.grid_slot.load_grid` (the same checks, the same code) in one worker process
(a fresh interpreter, started on the first reload, kept for the next ones, at Linux
``SCHED_IDLE``, nice 19 where that is missing) and returns the built, checked :class:`.grid_slot.LoadedGrid`
(pickled: ~2 ms to unpickle a 19×23×16 grid). A worker that dies is reported as a refused
reload (the old grid stays) and replaced on the next one; it exits when its end of the pipe
closes (the daemon stopped or died).

Protocol over a ``multiprocessing`` pipe (pickles): requests ``(path, GridTrust | None)``,
answers ``("ok", LoadedGrid)`` or ``("refused", message)``; the request ``None`` (a ping) is
answered ``("ready", None)``: the worker's imports are done.
"""

from __future__ import annotations

import multiprocessing
import pickle
import subprocess
import sys
import threading
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from .grid_slot import GridLoadError, LoadedGrid, load_grid
from .grid_trust import GridTrust

_WORKER_CODE = (  # the priority first, so the grid code is imported at it too
    "import sys\n"
    "from cmm_comp.daemon.osthread import lower_priority\n"
    "lower_priority(sys.argv[1])\n"
    "from cmm_comp.daemon.grid_worker import main\n"
    "sys.exit(main(int(sys.argv[2])))"
)
IDLE_GRACE_S = 3.0
"""How long a reload may wait for the ``SCHED_IDLE`` worker before it is redone by a worker at
normal priority, s (a machine loaded to 100 % gives a SCHED_IDLE process ~0.3 % of a core, and
nice 19 is little better against many busy tasks: a reload must finish)."""


class ProcessGridLoader:
    """A ``loader(path, trust) -> LoadedGrid`` that does the work in a worker process.

    The worker runs at Linux ``SCHED_IDLE`` (:func:`.osthread.lower_priority`), so it only uses
    CPU time nothing else wants. A reload it has not answered within ``idle_grace_s`` (a
    saturated machine starves it, and an unprivileged process cannot leave SCHED_IDLE) is
    redone by a fresh worker at normal priority, which the next reload replaces by an idle one
    again.
    Thread-safe (one load at a time); ``stop(timeout_s)`` ends the worker.
    """

    def __init__(self, idle_grace_s: float = IDLE_GRACE_S) -> None:
        self._lock = threading.Lock()
        self._proc: subprocess.Popen[bytes] | None = None
        self._conn: Connection | None = None
        self._priority = "idle"
        self._stopped = False
        self._ready = False  # the worker answered a ping: its imports are done
        self._ping_sent = False  # a ping is unanswered (its answer precedes any other)
        self.idle_grace_s = idle_grace_s
        self.escalations = 0
        """Reloads that had to be redone at normal priority (the machine was saturated)."""

    def _worker(self, priority: str) -> Connection:
        if self._proc is not None and (self._proc.poll() is not None or self._priority != priority):
            self._end(1.0)
        if self._proc is None or self._conn is None:
            ours, theirs = multiprocessing.Pipe()
            fd = theirs.fileno()
            try:
                self._proc = subprocess.Popen(
                    [sys.executable, "-c", _WORKER_CODE, priority, str(fd)],
                    pass_fds=(fd,),
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,  # a stray print never reaches the event log
                )
            except BaseException:
                ours.close()
                raise
            finally:
                theirs.close()
            self._conn = ours
            self._priority = priority
            self._ready = self._ping_sent = False
        return self._conn

    def prewarm(self, wait_s: float = 0.0) -> bool:
        """Start the worker now (it imports the grid code at low priority, so the first reload
        does not wait for that). With ``wait_s`` > 0, wait (at most that long, s) until its
        imports are done — before the daemon serves, so that ~0.6 s of CPU never runs beside
        the first answers. True when the worker is known ready."""
        with self._lock:
            if self._stopped:
                return False
            conn = self._worker("idle")
            if wait_s <= 0.0 or self._ready:
                return self._ready
            try:
                if not self._ping_sent:
                    conn.send(None)
                    self._ping_sent = True
                if conn.poll(wait_s):
                    self._ready = conn.recv()[0] == "ready"
                    self._ping_sent = False
            except (OSError, EOFError, pickle.UnpicklingError, ValueError):
                self._end(1.0)
            return self._ready

    def __call__(self, path: str | Path, trust: GridTrust | None) -> LoadedGrid:
        with self._lock:
            if self._stopped:
                raise GridLoadError(f"{path}: the daemon is stopping; reload not done")
            kind, value = self._ask("idle", path, trust, self.idle_grace_s)
            if kind == "starved":  # redo it where it gets CPU, then back to idle next time
                self.escalations += 1
                kind, value = self._ask("normal", path, trust, None)
                if not self._stopped:
                    self._worker("idle")  # the next one: its imports happen while idle
        if kind == "ok" and isinstance(value, LoadedGrid):
            return value
        raise GridLoadError(str(value))

    def _ask(
        self, priority: str, path: str | Path, trust: GridTrust | None, grace_s: float | None
    ) -> tuple[str, Any]:
        """One request to a worker at ``priority``; ``("starved", None)`` when no answer
        began within ``grace_s`` (s; None: wait as long as it takes)."""
        conn = self._worker(priority)
        try:
            conn.send((str(path), trust))
            if self._ping_sent:  # first the answer to a ping prewarm() stopped waiting for
                if not conn.poll(grace_s):
                    return "starved", None
                conn.recv()
                self._ping_sent = False
            if not conn.poll(grace_s):
                return "starved", None
            kind, value = conn.recv()
        except (OSError, EOFError, pickle.UnpicklingError, ValueError) as exc:
            self._end(1.0)
            raise GridLoadError(
                f"{path}: the grid loader process failed ({exc}); old grid kept"
            ) from None
        return str(kind), value

    def _end(self, timeout_s: float) -> bool:
        """End the worker: its pipe closed (it exits), killed after ``timeout_s`` (s)."""
        proc, conn, self._proc, self._conn = self._proc, self._conn, None, None
        self._ping_sent = False
        if conn is not None:
            conn.close()
        if proc is not None:
            try:
                proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return True

    def stop(self, timeout_s: float = 5.0) -> bool:
        """End the worker (it exits when its pipe closes; killed after ``timeout_s``)."""
        self._stopped = True
        with self._lock:  # after the load in progress, if any
            return self._end(timeout_s)


def main(fd: int) -> int:
    """Worker process (the priority was set before the imports, :data:`_WORKER_CODE`): answer
    load requests on the pipe ``fd`` until it closes (the daemon stopped or died: an EOF, or a
    reset when it left an answer unread)."""
    conn = Connection(fd)
    try:
        while True:
            request = conn.recv()
            if request is None:  # a ping: the imports are done
                conn.send(("ready", None))
                continue
            path, trust = request
            try:
                answer: tuple[str, Any] = ("ok", load_grid(path, trust))
            except GridLoadError as exc:
                answer = ("refused", str(exc))
            except Exception as exc:  # a refusal with the reason, never a dead worker
                answer = ("refused", f"{path}: grid loader failed: {exc!r}")
            conn.send(answer)
    except (EOFError, OSError):
        return 0
