"""The daemon as a real subprocess (its CLI) on ``udp_multicast`` with the interface-local IPv6
group: corrections, SIGHUP grid reload (a bad grid is refused), SIGTERM closes the MCAP file
cleanly, and after kill -9 the MCAP written before the kill reads back."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
from test_daemon_support import (
    STYLUS,
    build_signed_grid,
    daemon_subprocess,
    npl_grid_path,
    npl_machine,
)

from cmm_comp.cli.sessionlog.reader import read_messages
from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.protocol.codes import grid_id_from_sha256
from cmm_comp.sim_controller.controller import RawReading
from cmm_comp.sim_controller.runner import build_program, evaluate, make_readings, run_can
from cmm_comp.sim_controller.sim_machine import Environment, SimulatedMachine


def _wait(pred, timeout_s: float = 30.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if pred():
            return True
        time.sleep(0.02)
    return False


def test_subprocess_udp_multicast_reload_and_sigterm(tmp_path) -> None:
    grid = tmp_path / "machine.grid"
    grid.write_bytes(npl_grid_path().read_bytes())
    first_id = grid_id_from_sha256(CorrectionGrid.load(grid).sha256)
    machine = npl_machine()
    rng = np.random.default_rng(5)
    program = build_program(
        machine.volume.lower_mm, machine.volume.upper_mm, rng, 20, plate=False, repetitions=1
    )
    env = Environment()
    sim = SimulatedMachine(machine, STYLUS, None, rng)
    indicated, readings = make_readings(sim, env, program.points)
    with daemon_subprocess(tmp_path, grid) as (proc, ctl, mcap, log):
        assert ctl.heartbeat.grid_id == first_id
        answers = run_can(ctl, readings, env)
        result = evaluate(program, indicated, answers)
        assert result["corrected"] == len(readings), result["statuses"]
        assert result["e0_after_um"] * 10 <= result["e0_before_um"]
        assert ctl.ignored > 0  # our own frames came back and were ignored
        # SIGHUP with a new good grid: swapped atomically
        other = tmp_path / "other.grid"
        build_signed_grid(other, steps=(10, 12, 8))
        os.replace(other, grid)
        new_id = grid_id_from_sha256(CorrectionGrid.load(grid).sha256)
        proc.send_signal(signal.SIGHUP)
        # generous: the reload is built in a worker process started at low priority
        assert _wait(lambda: ctl.heartbeat.grid_id == new_id, 60), log.read_text()
        # SIGHUP with a bad grid: refused, the good one stays active
        grid.write_bytes(b"garbage")
        proc.send_signal(signal.SIGHUP)
        assert _wait(lambda: "grid_refused" in log.read_text(), 60)
        ctl.send_temperatures(env.samples(0.0))
        assert ctl.exchange(RawReading(999, (450.0, 575.0, 200.0))).status == "ok"
        assert ctl.heartbeat.grid_id == new_id
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(20) == 0
    res = read_messages(mcap)
    assert not res.truncated and res.error is None
    grids = [m.payload["sha256"] for m in res.messages if m.topic == "/cmm/grid"]
    assert len(grids) == 2 and grids[0] != grids[1]
    assert sum(m.topic == "/cmm/corrected" for m in res.messages) == len(readings) + 1
    events = [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]
    assert events[-1]["event"] == "stopped"


def _corrected_seqs(path: Path) -> list[int]:
    """Seqs of the ``/cmm/corrected`` records in the file as it is now (cut files too)."""
    if not path.exists():
        return []
    return [m.payload["seq"] for m in read_messages(path).messages if m.topic == "/cmm/corrected"]


def test_kill_9_mcap_reads_back(tmp_path) -> None:
    """kill -9 of the daemon: the writer child outlives the daemon and finishes the file (a
    writer thread in a killed process: tests/test_mcap_recover.py, cut files)."""
    with daemon_subprocess(tmp_path, npl_grid_path()) as (proc, ctl, mcap, _log):
        ctl.send_temperatures(Environment().samples(0.0))
        time.sleep(0.05)
        for seq in range(300):
            x = 100.0 + seq
            assert ctl.exchange(RawReading(seq, (x, 500.0, 200.0))).status == "ok"
        # the file on disk holds all 300 answers (flushed chunks): a kill cannot take them
        assert _wait(lambda: _corrected_seqs(mcap)[:300] == list(range(300)), 60.0)
        for seq in range(300, 320):  # these may be lost with the chunk in progress
            ctl.exchange(RawReading(seq, (100.0, 500.0, 200.0)))
        proc.kill()  # SIGKILL
        assert proc.wait(10) == -signal.SIGKILL
    # the orphaned child finishes the file (summary and all); generous: the child runs at
    # SCHED_IDLE, which a saturated CPU serves last
    assert _wait(lambda: "session_end" in dict(read_messages(mcap).metadata), 120.0)
    res = read_messages(mcap)
    assert not res.truncated
    seqs = [m.payload["seq"] for m in res.messages if m.topic == "/cmm/corrected"]
    assert seqs[:300] == list(range(300))
