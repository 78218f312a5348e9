"""Shared fixtures: every test must leave no threads, sockets or child processes behind."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import settings

# CI runs property tests with a fixed seed sequence (a red CI must mean a regression, not a new
# random example); developers' runs keep exploring new examples (and add regressions as tests).
# No per-example deadline anywhere: how long one example takes depends on the machine's load
# (a 2-core runner beside a benchmark), not on the code under test; the suite must be
# deterministic under load (pytest-timeout still stops a hung test).
settings.register_profile("ci", derandomize=True, print_blob=True, deadline=None)
settings.register_profile("dev", deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "dev")

ROOT = Path(__file__).resolve().parents[1]
REALDATA = ROOT.parent / "shared" / "realdata"


def _child_pids() -> set[int]:
    """Live child processes of this test process (Linux /proc; empty elsewhere)."""
    me = os.getpid()
    out: set[int] = set()
    proc = Path("/proc")
    if not proc.is_dir():
        return out
    for entry in proc.iterdir():
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


@pytest.fixture
def realdata_dir() -> Path:
    if not REALDATA.is_dir():
        pytest.skip(f"real data folder {REALDATA} is absent (a user's checkout has no ../shared)")
    return REALDATA
