"""A daemon running as its own process, and a controller in the test process talking to it over
``udp_multicast`` (no tests in here; used by test_daemon_init_docs and test_daemon_unprivileged).

:func:`controller_on` opens the controller's bus on the interface-local IPv6 group;
:func:`wait_ready` waits for the daemon's heartbeat to say ``ready`` (the process must stay
alive); :func:`check_answers` sends temperatures and readings and compares every answer with
the grid file evaluated in the test process (``CorrectionGrid.correct``, the vectorised path,
at the grid's probe offset): what a controller on the bus receives must be that, to the nm.
"""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import can
import numpy as np

from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.protocol.codes import DaemonState
from cmm_comp.sim_controller.controller import CanController, RawReading

MCAST_GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"
TEMPS_C = {"T_x": 20.5, "T_y": 20.5, "T_z": 20.5, "T_wp": 20.5}
SENSORS = {0: 20.5, 1: 20.5, 2: 20.5, 3: 20.5}
"""The default ``[temperatures] sensors`` map ids 0..3 to T_x, T_y, T_z, T_wp."""


@contextmanager
def controller_on(port: int) -> Iterator[CanController]:
    """A controller on the host-local ``udp_multicast`` group at ``port``."""
    bus = can.Bus(interface="udp_multicast", channel=MCAST_GROUP, port=port)
    try:
        with CanController(bus, answer_timeout_s=10.0) as ctl:
            yield ctl
    finally:
        bus.shutdown()


def wait_ready(ctl: CanController, proc: subprocess.Popen, log: Path, timeout_s: float) -> float:
    """Wait for a ``ready`` heartbeat; return the seconds it took. AssertionError (with the
    daemon's output) if the process ends or the time runs out."""
    t0 = time.monotonic()
    while ctl.heartbeat is None or ctl.heartbeat.state != DaemonState.READY:
        assert proc.poll() is None, f"daemon exited {proc.returncode}:\n{log.read_text()}"
        assert time.monotonic() - t0 < timeout_s, f"daemon not ready:\n{log.read_text()}"
        time.sleep(0.05)
    return time.monotonic() - t0


def check_answers(ctl: CanController, grid_path: Path, n: int = 20, seed: int = 3) -> int:
    """Send temperatures and ``n`` readings inside the grid's volume; every answer must be
    ``ok`` and equal the grid's own correction (1 nm). Returns the number checked."""
    grid = CorrectionGrid.load(grid_path)
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(grid.lower_mm), np.asarray(grid.upper_mm)
    pts = np.round(lo + (hi - lo) * rng.uniform(0.05, 0.95, (n, 3)), 4)
    probe = np.asarray(grid.metadata["probe_offset_mm"], float)
    expected, status = grid.correct(pts, probe, TEMPS_C)
    assert list(status) == ["ok"] * n
    ctl.send_temperatures(SENSORS)
    time.sleep(0.2)  # the daemon takes the samples before the first reading
    for i, p in enumerate(pts):
        answer = ctl.exchange(RawReading(1000 + i, (float(p[0]), float(p[1]), float(p[2]))))
        assert answer.status == "ok", answer
        assert answer.corrected_mm is not None
        np.testing.assert_allclose(answer.corrected_mm, expected[i], rtol=0, atol=1.01e-6)
    return n


def stop(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout_s: float = 30.0) -> int:
    """Signal the daemon and wait for its exit code (killed if it does not stop in time)."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
            raise AssertionError(f"daemon did not stop within {timeout_s} s") from None
    return int(proc.returncode)
