"""Grid loading in a worker process: a reload never holds the reply path's interpreter lock.

Reading a grid, checking its trust and building its interpolation tables takes 60 ms to over
a second of CPU, much of it inside compiled calls that hold Python's GIL for tens of ms; in a
thread of the daemon that shows up directly in the reply latency. :class:`ProcessGridLoader`
runs :func:`.grid_slot.load_grid` (the same checks, the same code) in one worker process
(``python -m cmm_comp.daemon.grid_worker``, started on the first reload, kept for the next ones,
at Linux ``SCHED_IDLE``, nice 19 where that is missing) and returns the built, checked :class:`.grid_slot.LoadedGrid`
(pickled: ~2 ms to unpickle a 19×23×16 grid). A worker that dies is reported as a refused
reload (the old grid stays) and replaced on the next one; it exits when its stdin closes (the
daemon stopped or died).

Protocol on the worker's stdin/stdout: frames of an 8-byte little-endian length and a pickle;
requests ``(path, GridTrust | None)``, answers ``("ok", LoadedGrid)`` or ``("refused", message)``;
the request ``None`` (a ping) is answered ``("ready", None)``: the worker's imports are done.
"""

from __future__ import annotations

import contextlib
import pickle
import select
import struct
import subprocess
import sys
import threading
from pathlib import Path
from typing import IO, Any

from .grid_slot import GridLoadError, LoadedGrid, load_grid
from .grid_trust import GridTrust
from .osthread import set_worker_priority

_LENGTH = struct.Struct("<Q")  # frame length, bytes


def _send(fh: IO[bytes], obj: Any) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    fh.write(_LENGTH.pack(len(data)))
    fh.write(data)
    fh.flush()


def _recv(fh: IO[bytes]) -> Any:
    head = fh.read(_LENGTH.size)
    if len(head) < _LENGTH.size:
        raise EOFError("grid worker pipe closed")
    (size,) = _LENGTH.unpack(head)
    data = fh.read(size)
    if len(data) < size:
        raise EOFError("grid worker pipe closed mid-frame")
    return pickle.loads(data)


_WORKER_CODE = (  # the priority first, so the grid code is imported at it too
    "import sys\n"
    "from cmm_comp.daemon.osthread import set_worker_priority\n"
    "set_worker_priority(sys.argv[1])\n"
    "from cmm_comp.daemon.grid_worker import main\n"
    "sys.exit(main())"
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
        self._priority = "idle"
        self._stopped = False
        self._ready = False  # the worker answered a ping: its imports are done
        self._ping_sent = False  # a ping is unanswered (its answer precedes any other)
        self.idle_grace_s = idle_grace_s
        self.escalations = 0
        """Reloads that had to be redone at normal priority (the machine was saturated)."""

    def _worker(self, priority: str) -> subprocess.Popen[bytes]:
        if self._proc is not None and (self._proc.poll() is not None or self._priority != priority):
            self._end(self._proc, 1.0)
            self._proc = None
        if self._proc is None:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", _WORKER_CODE, priority],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
            )
            self._priority = priority
            self._ready = self._ping_sent = False
        return self._proc

    def prewarm(self, wait_s: float = 0.0) -> bool:
        """Start the worker now (it imports the grid code at low priority, so the first reload
        does not wait for that). With ``wait_s`` > 0, wait (at most that long, s) until its
        imports are done — before the daemon serves, so that ~0.6 s of CPU never runs beside
        the first answers. True when the worker is known ready."""
        with self._lock:
            if self._stopped:
                return False
            proc = self._worker("idle")
            if wait_s <= 0.0 or self._ready:
                return self._ready
            assert proc.stdin is not None and proc.stdout is not None
            try:
                if not self._ping_sent:
                    _send(proc.stdin, None)
                    self._ping_sent = True
                ready, _, _ = select.select([proc.stdout], [], [], wait_s)
                if ready:
                    self._ready = _recv(proc.stdout)[0] == "ready"
                    self._ping_sent = False
            except (OSError, EOFError, pickle.UnpicklingError, ValueError):
                self._end(proc, 1.0)
                self._proc = None
                self._ping_sent = False
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
        proc = self._worker(priority)
        assert proc.stdin is not None and proc.stdout is not None
        try:
            _send(proc.stdin, (str(path), trust))
            if self._ping_sent:  # first the answer to a ping prewarm() stopped waiting for
                if grace_s is not None and not select.select([proc.stdout], [], [], grace_s)[0]:
                    return "starved", None
                _recv(proc.stdout)
                self._ping_sent = False
            if grace_s is not None:
                ready, _, _ = select.select([proc.stdout], [], [], grace_s)
                if not ready:
                    return "starved", None
            kind, value = _recv(proc.stdout)
        except (OSError, EOFError, pickle.UnpicklingError, ValueError) as exc:
            self._end(proc, 1.0)
            self._proc = None
            raise GridLoadError(
                f"{path}: the grid loader process failed ({exc}); old grid kept"
            ) from None
        return str(kind), value

    @staticmethod
    def _end(proc: subprocess.Popen[bytes], timeout_s: float) -> bool:
        if proc.stdin is not None:
            with contextlib.suppress(OSError):
                proc.stdin.close()
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
        return True

    def stop(self, timeout_s: float = 5.0) -> bool:
        """End the worker (it exits when its stdin closes; killed after ``timeout_s``)."""
        self._stopped = True
        with self._lock:  # after the load in progress, if any
            proc, self._proc = self._proc, None
        return True if proc is None else self._end(proc, timeout_s)


def main() -> int:
    """Worker process (argument: ``idle`` or ``normal``): answer load requests until stdin
    closes."""
    # the priority was set before the imports (_WORKER_CODE); run as a module, set it here
    if __name__ == "__main__":
        set_worker_priority(sys.argv[1] if len(sys.argv) > 1 else "idle")
    requests, answers = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # a stray print must not corrupt the answer stream
    while True:
        try:
            request = _recv(requests)
        except EOFError:
            return 0
        if request is None:  # a ping: the imports are done
            _send(answers, ("ready", None))
            continue
        path, trust = request
        try:
            answer: tuple[str, Any] = ("ok", load_grid(path, trust))
        except GridLoadError as exc:
            answer = ("refused", str(exc))
        except Exception as exc:  # a refusal with the reason, never a dead worker
            answer = ("refused", f"{path}: grid loader failed: {exc!r}")
        _send(answers, answer)


if __name__ == "__main__":
    sys.exit(main())
