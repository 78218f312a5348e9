"""Shared fixtures: every test must leave no threads, sockets or child processes behind."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings

# CI runs property tests with a fixed seed sequence (a red CI must mean a regression, not a new
# random example); developers' runs keep exploring new examples (and add regressions as tests).
# No per-example deadline anywhere: how long one example takes depends on the machine's load
# (a 2-core runner beside a benchmark), not on the code under test; the suite must be
# deterministic under load (pytest-timeout still stops a hung test).
# One BLAS thread per process. pytest-xdist runs a worker per core; numpy's OpenBLAS would add
# a thread per core inside each, and on a loaded 2-core machine its threads spin waiting for
# each other: measured on tests/test_calibration_model.py + tests/test_reference_generator.py
# (one process, load ~5), 20.6 s of CPU and 31 s wall with the default, 7.5 s and 11 s with
# one thread. Set before numpy is first imported (numpy reads it when it loads its BLAS) and
# inherited by every subprocess a test starts (daemons, Dask workers: the same numbers as the
# test process computes); a value set by the caller wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
if "numpy" in sys.modules:  # loaded before this file (a plugin): limit the loaded library
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=int(os.environ["OPENBLAS_NUM_THREADS"]), user_api="blas")

settings.register_profile("ci", derandomize=True, print_blob=True, deadline=None)
settings.register_profile("dev", deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "dev")

ROOT = Path(__file__).resolve().parents[1]
REALDATA = ROOT.parent / "shared" / "realdata"
MCAP_TS = ROOT / "tests" / "mcap_ts"
REQUIRE_NODE = "CMM_COMP_REQUIRE_NODE"
"""Set to 1 (``.ci/run`` does): a missing node/npm or a failed ``npm ci`` fails the tests that
read logs with the TypeScript MCAP reader instead of skipping them."""


def _child_pids() -> set[int]:
    """Live child processes of this test process (Linux /proc; empty elsewhere).

    Read from each of this process's threads' ``/proc/PID/task/TID/children`` (the kernel's own
    list; a child of a thread that has exited is moved to another thread of the process), then
    zombies dropped: ~30 µs a call instead of ~2 ms for reading every process's ``stat`` (two
    calls per test, 1,881 tests: ~7 s of CPU a run). Kernels built without those files
    (``CONFIG_PROC_CHILDREN``) get the scan of every process."""
    me = os.getpid()
    tasks = Path(f"/proc/{me}/task")
    if not tasks.is_dir():
        return set()
    listed: set[int] = set()
    try:
        for task in tasks.iterdir():
            try:
                listed.update(int(pid) for pid in (task / "children").read_text().split())
            except FileNotFoundError:
                if (task / "stat").exists():  # the thread is alive: no children file here
                    raise
    except FileNotFoundError:
        return _child_pids_by_scan(me)
    return {pid for pid in listed if _state(Path(f"/proc/{pid}")) not in (None, "Z")}


def _state(entry: Path) -> str | None:
    """The process's state letter (``R``, ``S``, ``Z``, …), or None when it is gone."""
    try:
        return (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return None


def _child_pids_by_scan(me: int) -> set[int]:
    """:func:`_child_pids` by reading every process's ``stat`` (its parent and state)."""
    out: set[int] = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        state, ppid = fields[0], int(fields[1])
        if ppid == me and state != "Z":
            out.add(int(entry.name))
    return out


def pytest_sessionstart(session: pytest.Session) -> None:
    """Under pytest-xdist: the project's numba kernels compiled once for the whole run.

    The kernels' on-disk cache (numba's, in the sources' ``__pycache__`` of an editable
    install) is written by the first process that compiles them; on a fresh checkout (CI) every
    worker would otherwise compile the same kernels side by side (~30 s of CPU each) before
    either has written them. The workers share the compiling instead (tests/kernel_warmup.py:
    the grid's kernels in one worker while another compiles the virtual CMM's, each group under
    its own lock) and load from the cache what another compiled. Outside xdist nothing is done
    (one file's run compiles only what it uses)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if not worker:
        return
    from kernel_warmup import warm_up

    warm_up(worker)


@pytest.fixture(autouse=True)
def _no_leaked_processes() -> Iterator[None]:
    before = _child_pids()
    yield
    import time

    t0 = time.monotonic()
    while (leaked := _child_pids() - before) and time.monotonic() - t0 < 5.0:
        time.sleep(0.05)
    assert not leaked, f"test leaked child processes: {sorted(leaked)}"


@pytest.fixture(autouse=True, scope="session")
def _quiet_foxglove_log() -> Iterator[None]:
    """foxglove-sdk forwards its Rust log records to Python ``logging`` from the server's own
    threads (pyo3-log); making a record registers that thread as a ``threading._DummyThread``,
    which the leak check below would report although it is the SDK's runtime thread, alive for
    the process. The SDK's log is switched off for the suite (tests read its effects instead)."""
    import logging

    logger = logging.getLogger("foxglove")
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    yield
    logger.setLevel(level)


@pytest.fixture(autouse=True)
def _no_leaked_threads() -> Iterator[None]:
    before = {t.ident for t in threading.enumerate()}
    yield
    deadline = 2.0
    import time

    t0 = time.monotonic()
    while True:
        leaked = [
            t
            for t in threading.enumerate()
            if t.ident not in before and t.is_alive() and not t.name.startswith("numba")
        ]
        if not leaked or time.monotonic() - t0 > deadline:
            break
        time.sleep(0.02)
    assert not leaked, f"test leaked threads: {[t.name for t in leaked]}"


@pytest.fixture(scope="session")
def realdata_dir() -> Path:
    if not REALDATA.is_dir():
        pytest.skip(f"real data folder {REALDATA} is absent (a user's checkout has no ../shared)")
    return REALDATA


def _npm_ci_once(npm: str) -> str | None:
    """``npm ci`` in tests/mcap_ts unless its node_modules already holds exactly the locked
    packages (a stamp: the lock file's SHA-256, written after a successful ``npm ci``). Under an
    exclusive file lock: pytest-xdist's workers share the folder, and a second ``npm ci`` would
    delete node_modules under a reader of the first. None, or why it failed."""
    import fcntl
    import hashlib

    lock_sha = hashlib.sha256((MCAP_TS / "package-lock.json").read_bytes()).hexdigest()
    stamp = MCAP_TS / "node_modules" / ".cmm-comp-npm-ci"
    with open(MCAP_TS / ".npm-ci.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if stamp.is_file() and stamp.read_text() == lock_sha:
            return None
        try:
            done = subprocess.run(
                [npm, "ci", "--no-audit", "--no-fund", "--ignore-scripts"],
                cwd=MCAP_TS,
                capture_output=True,
                text=True,
                timeout=600,
            )
        except subprocess.TimeoutExpired:
            return f"npm ci in {MCAP_TS} took more than 600 s"
        if done.returncode != 0:
            return f"npm ci in {MCAP_TS} failed: {done.stderr.strip()[-500:]}"
        stamp.write_text(lock_sha)
    return None


@pytest.fixture(scope="session")
def mcap_ts() -> Callable[..., dict[str, Any]]:
    """``read(path, *count_keys)``: the file read by the official TypeScript MCAP reader
    (``@mcap/core``'s ``McapIndexedReader`` and ``McapStreamReader``, what Foxglove and
    Lichtblick use; pinned in ``tests/mcap_ts/package-lock.json``), as the JSON object
    ``tests/mcap_ts/read_mcap.mjs`` prints. ``npm ci`` installs the pinned packages once
    (:func:`_npm_ci_once`). Without node/npm or the npm registry the tests skip, saying why; with
    ``CMM_COMP_REQUIRE_NODE=1`` (the CI) they fail."""

    def unavailable(why: str) -> None:
        if os.environ.get(REQUIRE_NODE) == "1":
            pytest.fail(f"{why} ({REQUIRE_NODE}=1: the TypeScript reader check is required)")
        pytest.skip(why)

    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        unavailable("node and npm are needed to read logs with @mcap/core (not on PATH)")
    assert node is not None and npm is not None
    why_not = _npm_ci_once(npm)
    if why_not is not None:
        unavailable(why_not)

    def read(path: Path, *count_keys: str) -> dict[str, Any]:
        counts = [a for key in count_keys for a in ("--count", key)]
        out = subprocess.run(
            [node, "read_mcap.mjs", str(path), *counts],
            cwd=MCAP_TS,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert out.returncode == 0, out.stderr
        result: dict[str, Any] = json.loads(out.stdout)
        return result

    return read


class CountingBus:
    """A controller's bus that counts every frame sent through it, by id."""

    def __init__(self, bus: Any) -> None:
        self._bus = bus
        self.sent: Counter[int] = Counter()

    def send(self, msg: Any, timeout: float | None = None) -> None:
        self._bus.send(msg, timeout)
        self.sent[msg.arbitration_id] += 1

    def __getattr__(self, name: str) -> Any:
        return getattr(self._bus, name)


@dataclass(frozen=True)
class UdpSession:
    """A session of the daemon subprocess on ``udp_multicast`` (``udp_session``)."""

    mcap: Path
    """The session log (closed by SIGTERM: complete)."""
    sent: Counter[int]
    """Frames the controller sent, by CAN id, counted on its bus."""
    readings: int
    temperature_samples: int


@pytest.fixture(scope="session")
def udp_session(tmp_path_factory: pytest.TempPathFactory) -> UdpSession:
    """The daemon as a subprocess (its CLI, process writer) on ``udp_multicast``: one
    temperature sample per sensor, 300 readings (every fourth with a probing direction), all
    answered ``ok``; then SIGTERM (exit 0, the log finished)."""
    from test_daemon_support import daemon_subprocess, npl_grid_path

    from cmm_comp.sim_controller.controller import RawReading
    from cmm_comp.sim_controller.sim_machine import Environment

    tmp = tmp_path_factory.mktemp("udp-session")
    counting: list[CountingBus] = []

    def wrap(bus: Any) -> CountingBus:
        counting.append(CountingBus(bus))
        return counting[0]

    readings = 300
    temps = Environment().samples(0.0)
    with daemon_subprocess(tmp, npl_grid_path(), wrap_bus=wrap) as (proc, ctl, mcap, log):
        ctl.send_temperatures(temps)
        for seq in range(readings):
            probe = (0.0, 0.6, -0.8) if seq % 4 == 0 else None
            reading = RawReading(seq, (100.0 + seq, 500.0, 200.0), (1, 0, 0), probe)
            assert ctl.exchange(reading).status == "ok"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0, log.read_text()
    return UdpSession(mcap, counting[0].sent, readings, len(temps))
