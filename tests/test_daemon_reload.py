"""Grid reload off the reply path, untrusted reloads refused, rate-limited state lines.

No timing is asserted: a slow loader blocks on an event, and the test shows by ordering that
answers keep coming (from the old grid) while the reload is held, then come from the new grid.
State lines use a fake clock.
"""

from __future__ import annotations

import io
import json
import threading
import time
from pathlib import Path

from test_daemon_support import (
    CENTRE_MM,
    base_config,
    build_signed_grid,
    channel,
    daemon_and_controller,
    npl_grid_path,
    npl_machine,
    send_temps,
)

from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.daemon.grid_slot import LoadedGrid, load_grid
from cmm_comp.daemon.grid_trust import GridTrust
from cmm_comp.daemon.state import StateBoard
from cmm_comp.protocol.codes import DaemonState, grid_id_from_sha256
from cmm_comp.sim_controller.controller import RawReading


def _wait(pred, timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.01)
    return False


def test_answers_keep_flowing_while_a_slow_reload_is_prepared() -> None:
    first, second = npl_grid_path(), npl_grid_path((10, 12, 8))
    started, release = threading.Event(), threading.Event()
    calls: list[str] = []

    def slow_loader(path: str | Path, trust: GridTrust | None) -> LoadedGrid:
        calls.append(threading.current_thread().name)
        if len(calls) == 1:  # the start-up load
            return load_grid(path, trust)
        started.set()
        assert release.wait(60), "test never released the reload"
        return load_grid(second, trust)

    cfg = base_config(channel())
    with daemon_and_controller(cfg, grid_loader=slow_loader) as (d, ctl, _bus):
        send_temps(ctl)
        old_sha = d.grids.current.sha256
        assert ctl.exchange(RawReading(1, CENTRE_MM)).status == "ok"
        d.request_reload()  # what SIGHUP does; returns at once
        assert started.wait(30)
        answers = [ctl.exchange(RawReading(2 + i, CENTRE_MM)) for i in range(20)]
        # all answered, corrected by the old grid, while the reload is still held
        assert not release.is_set() and d.reloader.completed == 0
        assert [a.status for a in answers] == ["ok"] * 20
        assert d.grids.current.sha256 == old_sha
        assert calls[1] == "grid-reload"  # prepared in the reload thread, not the reply thread
        release.set()
        assert _wait(lambda: d.reloader.completed == 1)
        new_sha = d.grids.current.sha256
        assert new_sha != old_sha and new_sha == CorrectionGrid.load(second).sha256
        assert _wait(lambda: ctl.heartbeat.grid_id == grid_id_from_sha256(new_sha))
        assert ctl.exchange(RawReading(40, CENTRE_MM)).status == "ok"
    assert first != second


def test_reload_of_untrusted_grids_keeps_the_old_one(tmp_path: Path) -> None:
    events = io.StringIO()
    cfg = base_config(channel())
    with daemon_and_controller(cfg, events_stream=events) as (d, ctl, _bus):
        send_temps(ctl)
        good = d.grids.current.sha256
        unsigned = tmp_path / "unsigned.grid"
        CorrectionGrid.build(npl_machine(), steps=(5, 5, 4)).save(unsigned)
        assert not d.reload_grid(str(unsigned))
        assert d.grids.current.sha256 == good
        assert ctl.exchange(RawReading(1, CENTRE_MM)).status == "ok"
    refused = [
        json.loads(line) for line in events.getvalue().splitlines() if '"grid_refused"' in line
    ]
    assert len(refused) == 1 and "grid is not signed" in refused[0]["error"]
    assert refused[0]["active"] == good


def test_state_detail_repeats_are_rate_limited_with_a_count() -> None:
    """A stale sensor's age changes the detail every 0.1 s: one line when it starts, then at
    most one per repeat_s with the count of changes not reported, one when it clears."""
    now = [0.0]
    lines: list[tuple[DaemonState, str, int]] = []
    board = StateBoard(lambda s, d, r: lines.append((s, d, r)), repeat_s=10.0, clock=lambda: now[0])
    board.set_grid(True)
    board.set_phase(DaemonState.READY)
    assert lines == [(DaemonState.READY, "ready", 0)]
    changes = 0
    for step in range(300):  # 30 s of a stale sensor, checked every 0.1 s
        now[0] = 100.0 + 0.1 * step
        board.set_condition("temperatures", f"sensor 0 (T_x) unchanged for {10 + 0.1 * step:.1f} s")
        changes += 1
    now[0] += 0.1
    board.set_condition("temperatures", None)
    degraded = [line for line in lines if line[0] == DaemonState.DEGRADED]
    assert len(degraded) == 3  # at 100 s, 110 s, 120 s (129.9 s is within 10 s of 120 s)
    assert degraded[0][2] == 0 and "10.0 s" in degraded[0][1]
    assert lines[-1][0] == DaemonState.READY
    # every change is either reported or counted in the next line
    assert len(degraded) + sum(r for _s, _d, r in lines[1:]) == changes
    # a new kind of condition is reported at once, whatever the rate limit
    board.set_condition("temperatures", "sensor 0 (T_x) unchanged for 10.0 s")
    board.set_condition("can", "bus error")
    assert lines[-1][1].startswith("can: bus error") and lines[-1][2] == 0


def _policy(pid: int) -> int:
    """Scheduling policy of process ``pid`` (field 41 of /proc/PID/stat; 5 = SCHED_IDLE)."""
    with open(f"/proc/{pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[38])


def test_sighup_reload_is_built_in_a_worker_process(tmp_path: Path) -> None:
    """The default reload path: the grid is read, verified and built in another process (its
    pid differs from ours), then swapped; an untrusted file is refused there the same way."""
    import os

    grid = tmp_path / "machine.grid"
    grid.write_bytes(npl_grid_path().read_bytes())
    cfg = base_config(channel(), grid)
    with daemon_and_controller(cfg) as (d, ctl, _bus):
        send_temps(ctl)
        old = d.grids.current.sha256
        build_signed_grid(tmp_path / "new.grid", (10, 12, 8))
        os.replace(tmp_path / "new.grid", grid)
        d.request_reload()
        assert _wait(lambda: d.reloader.completed == 1, 120)
        assert d.reloader.errors == []
        new = d.grids.current
        assert new.sha256 != old and new.sha256 == CorrectionGrid.load(grid).sha256
        assert new.loaded_by_pid not in (0, os.getpid())
        if hasattr(os, "SCHED_IDLE"):  # the worker never competes with the reply path
            # the worker kept for the next reload (the one that loaded, or after a starved
            # load redone at nice 19 on a saturated machine, a fresh idle one)
            loader = d._process_loader
            assert loader is not None and loader._proc is not None
            assert _wait(lambda: _policy(loader._proc.pid) == os.SCHED_IDLE, 60)
        send_temps(ctl)  # fresh temperatures: a slow reload on a busy machine outlasts stale_s
        assert ctl.exchange(RawReading(1, CENTRE_MM)).status == "ok"
        CorrectionGrid.build(npl_machine(), steps=(5, 5, 4)).save(grid)  # unsigned
        d.request_reload()
        assert _wait(lambda: d.reloader.completed == 2, 120)
        assert d.grids.current.sha256 == new.sha256
        send_temps(ctl)
        assert ctl.exchange(RawReading(2, CENTRE_MM)).status == "ok"


def test_a_starved_idle_worker_is_replaced_by_one_at_normal_priority() -> None:
    """A grace of 0 s: the idle worker (just started, still importing) cannot have answered,
    so the reload is redone at normal priority and succeeds; the worker then kept for the next
    reload is an idle one again."""
    import os

    from cmm_comp.daemon.grid_worker import IDLE_GRACE_S, ProcessGridLoader

    loader = ProcessGridLoader(idle_grace_s=0.0)
    try:
        loaded = loader(npl_grid_path(), None)
        assert loader.escalations == 1
        assert loaded.sha256 == CorrectionGrid.load(npl_grid_path()).sha256
        assert loaded.loaded_by_pid not in (0, os.getpid())
        loader.idle_grace_s = IDLE_GRACE_S
        again = loader(npl_grid_path(), None)  # idle, or redone again on a saturated machine
        assert again.sha256 == loaded.sha256 and loader.escalations in (1, 2)
        assert loader._proc is not None and loader._proc.pid != loaded.loaded_by_pid
        if hasattr(os, "SCHED_IDLE"):
            pid = loader._proc.pid
            assert _wait(lambda: _policy(pid) == os.SCHED_IDLE, 60)
    finally:
        loader.stop(10.0)


def test_prewarmed_worker_is_ready_and_its_ping_never_shifts_the_answers() -> None:
    """The daemon waits at start until the reload worker has imported the grid code (a ping
    answered ``ready``); a ping prewarm() stopped waiting for (a wait of ~0) is drained before
    the first reload's answer, which is then the grid asked for, not the ping's ``ready``."""
    from cmm_comp.daemon.grid_worker import ProcessGridLoader

    want = CorrectionGrid.load(npl_grid_path()).sha256
    waited = ProcessGridLoader(idle_grace_s=120.0)
    try:
        # a machine saturated by the other tests may starve the SCHED_IDLE worker: retried
        assert _wait(lambda: waited.prewarm(5.0), 120)
        assert waited(npl_grid_path(), None).sha256 == want
        assert waited(npl_grid_path(), None).sha256 == want
    finally:
        waited.stop(10.0)
    hurried = ProcessGridLoader(idle_grace_s=120.0)
    try:
        assert hurried.prewarm(1e-6) in (False, True)  # the ping is most likely still pending
        assert hurried(npl_grid_path(), None).sha256 == want
        assert hurried(npl_grid_path(), None).sha256 == want
    finally:
        hurried.stop(10.0)
