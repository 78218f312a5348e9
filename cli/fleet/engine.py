"""Run a fleet's sessions on Dask: the cluster, a bounded window of tasks, progress, timings.

:func:`dask_client` gives a :class:`distributed.Client` on a ``LocalCluster`` of ``workers``
processes with one thread each (the diagnosis is CPU-bound Python/numpy: threads would share one
interpreter) or on the scheduler at ``address``; before any work every worker's code fingerprint
must equal the client's (:func:`.tasks.code_fingerprint`), else the results and their keys would
not belong together.

:func:`run_jobs` keys each session (hashing its inputs just before it is needed), skips those
already stored, and keeps at most ``window`` tasks submitted at a time; each result is stored as
it arrives (:class:`.store.ResultStore`) and released, so the client holds the window, never the
fleet. A session whose task fails (a bad file: the task's own one-line error; or an exception,
a killed worker) is reported with its path and the run goes on.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from cmm_comp.compensation.errors import CmmCompError

from .discover import Job
from .store import ResultStore
from .tasks import code_fingerprint, worker_fingerprint

__all__ = [
    "DaskMissing",
    "FleetRun",
    "LazyClient",
    "Progress",
    "dask_client",
    "import_distributed",
    "run_jobs",
]

INSTALL_HINT = (
    "cmm-comp fleet runs on Dask's distributed scheduler, which is not installed: "
    "pip install 'cmm-comp[fleet]' (dask and distributed 2026.8.0)"
)
WORKER_WAIT_S = 60.0
"""How long a run on ``--scheduler`` waits for its first worker, s."""


class DaskMissing(CmmCompError, RuntimeError):
    """``distributed`` cannot be imported (the message says how to install it)."""


def import_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise DaskMissing(INSTALL_HINT) from None
    return distributed


@contextlib.contextmanager
def dask_client(workers: int | None, address: str | None) -> Iterator[Any]:
    """A client on a new LocalCluster (``workers`` processes × 1 thread; default 2) or on the
    scheduler at ``address``; workers checked (module docstring); closed on exit."""
    distributed = import_distributed()
    with contextlib.ExitStack() as stack:
        if address:
            client = stack.enter_context(distributed.Client(address, timeout="15s"))
            try:
                client.wait_for_workers(1, timeout=WORKER_WAIT_S)
            except TimeoutError:
                raise RuntimeError(
                    f"scheduler {address}: no worker joined within {WORKER_WAIT_S:.0f} s"
                ) from None
        else:
            import dask

            # the workers' statistical profiler (a thread sampling every 10 ms) is for the
            # dashboard we do not start: off, it costs a quarter less CPU per second of a run
            with dask.config.set({"distributed.worker.profile.enabled": False}):
                local = distributed.LocalCluster(
                    n_workers=workers or 2,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    # no dashboard; its HTTP server (health) on a free port, not 8787
                    scheduler_kwargs={"dashboard_address": ":0"},
                    silence_logs=logging.ERROR,
                )
            cluster = stack.enter_context(local)
            client = stack.enter_context(distributed.Client(cluster))
        mine = code_fingerprint()
        for worker, info in client.run(worker_fingerprint).items():
            if info["fingerprint"] != mine:
                raise RuntimeError(
                    f"worker {worker} runs other cmm-comp code than this client "
                    f"({info['python']}: fingerprint {info['fingerprint'][:12]}, here "
                    f"{mine[:12]}): install the same version everywhere"
                )
        yield client


class Progress:
    """``label: done/total (cached, failed) elapsed, ETA`` on stderr: rewritten in place on a
    terminal, else one line per ``every_s`` seconds and at the end; silent when ``quiet``."""

    def __init__(self, label: str, total: int, quiet: bool = False, every_s: float = 10.0):
        self.label, self.total, self.quiet, self.every_s = label, total, quiet, every_s
        self.t0 = time.perf_counter()
        self.last = -1e9
        self.tty = sys.stderr.isatty()

    def update(self, done: int, cached: int, failed: int, final: bool = False) -> None:
        if self.quiet:
            return
        now = time.perf_counter()
        if not final and now - self.last < (0.2 if self.tty else self.every_s):
            return
        self.last = now
        elapsed = now - self.t0
        ran = done - cached
        rate = ran / elapsed if elapsed > 0 else 0.0
        left = self.total - done
        eta = f", about {left / rate:.0f} s left" if rate > 0 and left and not final else ""
        text = (
            f"{self.label}: {done}/{self.total} sessions ({cached} stored before, {failed} "
            f"failed), {elapsed:.1f} s{eta}"
        )
        if self.tty:
            print(f"\r{text}\x1b[K", end="\n" if final else "", file=sys.stderr, flush=True)
        else:
            print(text, file=sys.stderr, flush=True)


@dataclass
class FleetRun:
    """What a run did: keys per session path, failures, counts and timings (s)."""

    keys: dict[str, str] = field(default_factory=dict)
    failed: list[dict[str, str]] = field(default_factory=list)
    ran: int = 0
    cached: int = 0
    wall_s: float = 0.0
    compute_s: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)
    workers: int = 0
    """Worker threads serving the run: the most seen at its start or its end."""
    wait_s: float = 0.0
    """Time the client spent waiting for a result (the rest of ``wall_s`` is its own work:
    hashing inputs, storing results)."""

    def stats(self) -> dict[str, Any]:
        """The ``run`` section of OUT: counts, wall, Σ compute, and the overhead per session
        (wall × workers − Σ compute in the tasks) / sessions run."""
        busy = sum(self.compute_s)
        out: dict[str, Any] = {
            "sessions_run": self.ran,
            "stored_before": self.cached,
            "failed": len(self.failed),
            "workers": self.workers,
            "wall_s": round(self.wall_s, 4),
            "task_compute_s": round(busy, 4),
            "task_cpu_s": round(sum(self.cpu_s), 4),
        }
        if self.ran:
            overhead = (self.wall_s * self.workers - busy) / self.ran
            out["overhead_per_session_s"] = round(overhead, 4)
            out["compute_per_session_s"] = round(busy / self.ran, 4)
            out["client_per_session_s"] = round((self.wall_s - self.wait_s) / self.ran, 5)
        return out


def _fail(run: FleetRun, job: Job, error: str, say: Callable[[str], None]) -> None:
    run.failed.append({"machine": job.machine, "path": job.path, "error": error})
    say(f"{job.path}: {error}")


class LazyClient:
    """The client of :func:`dask_client`, started on first use (a run whose sessions are all
    stored starts no cluster); a context manager closing it."""

    def __init__(self, workers: int | None, address: str | None) -> None:
        self.workers, self.address = workers, address
        self._stack = contextlib.ExitStack()
        self._client: Any = None

    def get(self) -> Any:
        if self._client is None:
            self._client = self._stack.enter_context(dask_client(self.workers, self.address))
        return self._client

    def __enter__(self) -> LazyClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()


def run_jobs(
    client: LazyClient,
    jobs: Sequence[Job],
    task: Callable[..., dict[str, Any]],
    key_of: Callable[[Job], str],
    store: ResultStore,
    *,
    still_valid: Callable[[dict[str, Any]], bool] = lambda _entry: True,
    window: int | None = None,
    progress: Progress | None = None,
    say: Callable[[str], None] = lambda _line: None,
) -> FleetRun:
    """Run ``task(*job.args)`` for every job not stored yet (module docstring)."""
    distributed = import_distributed()
    run = FleetRun()
    limit = window or 3
    todo = iter(jobs)
    inflight: dict[Any, Job] = {}
    done = 0
    pending: Any = None
    t0 = time.perf_counter()
    dask: Any = None
    exhausted = False
    while True:
        while not exhausted and len(inflight) < limit:
            job = next(todo, None)
            if job is None:
                exhausted = True
                break
            if job.problem:
                _fail(run, job, job.problem, say)
                done += 1
                continue
            key = run.keys[job.path] = key_of(job)
            entry = store.get(key)
            if entry is not None and still_valid(entry):
                run.cached += 1
                done += 1
                continue
            if dask is None:  # first session to run: start (or join) the cluster
                dask = client.get()
                run.workers = sum(dask.nthreads().values())
                limit = window or 2 * max(run.workers, 1) + 1
                pending = distributed.as_completed(with_results=True, raise_errors=False)
                t0 = time.perf_counter()  # timings from a running cluster
            future = dask.submit(task, *job.args, pure=False)
            inflight[future] = job
            pending.add(future)
        if not inflight:
            break
        t_wait = time.perf_counter()
        future, result = next(pending)  # results gathered in the background
        run.wait_s += time.perf_counter() - t_wait
        job = inflight.pop(future)
        if future.status == "error" or isinstance(result, BaseException):
            exc = result[1] if isinstance(result, tuple) else result
            # the task's own errors are answers: this is a crash, a killed worker, a cancel
            _fail(run, job, f"task failed: {type(exc).__name__}: {exc}", say)
        else:
            _take(run, job, result, store, say)
        future.release()
        done += 1
        if progress is not None:
            progress.update(done, run.cached, len(run.failed))
    run.wall_s = time.perf_counter() - t0
    if dask is not None:  # workers that joined a remote scheduler during the run count too
        run.workers = max(run.workers, sum(dask.nthreads().values()))
    if progress is not None:
        progress.update(done, run.cached, len(run.failed), final=True)
    return run


def _take(
    run: FleetRun, job: Job, result: dict[str, Any], store: ResultStore, say: Callable[[str], None]
) -> None:
    run.ran += 1
    run.compute_s.append(float(result["compute_s"]))
    run.cpu_s.append(float(result["cpu_s"]))
    for warning in result.get("warnings", []):
        say(f"{job.path}: warning: {warning}")
    if not result["ok"]:
        _fail(run, job, str(result["error"]), say)
        return
    entry = {
        "kind": task_kind(result),
        "machine": job.machine,
        "path": job.path,
        "json": result["json"],
        "compute_s": result["compute_s"],
        "cpu_s": result["cpu_s"],
    }
    if "grid_file_sha256" in result:
        entry["grid_file_sha256"] = result["grid_file_sha256"]
    store.put(run.keys[job.path], entry)


def task_kind(result: dict[str, Any]) -> str:
    """``replay`` or ``diagnose`` (the replay task reports the grid file it used)."""
    return "replay" if "grid_file_sha256" in result else "diagnose"
