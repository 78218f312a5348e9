"""Replay: re-correct a logged session offline (same grid: equal to what was sent within the
1 nm wire resolution; another grid: the differences are reported) and re-send it to a daemon."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import can
import numpy as np
import pytest
from test_daemon_support import base_config, channel, daemon_and_controller, npl_grid_path

from cmm_comp.daemon.sessionlog.replay import ReplayError, replay_offline, replay_to_bus
from cmm_comp.sim_controller.controller import RawReading


@pytest.fixture
def session(tmp_path):
    cfg = base_config(channel())
    cfg.mcap.path = str(tmp_path / "s.mcap")
    rng = np.random.default_rng(1)
    pts = rng.uniform([20, 20, 20], [880, 1130, 380], (60, 3))
    with daemon_and_controller(cfg) as (_d, ctl, _bus):
        ctl.send_temperatures({0: 21.0, 1: 21.5, 2: 20.5, 3: 19.5})
        time.sleep(0.02)
        for i, p in enumerate(pts):
            assert ctl.exchange(RawReading(i, tuple(p), travel_dir=(1, -1, 0))).status == "ok"
        ctl.exchange(RawReading(60, (2000.0, 10.0, 10.0)))  # outside the volume
    return tmp_path / "s.mcap"


def test_replay_same_grid_matches(session) -> None:
    report = replay_offline(session)
    assert report.readings == 61 and report.compared == 60
    assert report.max_abs_diff_um < 0.002  # 1 nm quantisation on the wire
    assert report.status_agree == 61
    assert report.grid_sha256 == report.session_grid_sha256


def test_replay_other_grid_reports_differences(session, tmp_path) -> None:
    coarse = npl_grid_path((5, 5, 4))
    report = replay_offline(session, coarse)
    assert report.grid_sha256 != report.session_grid_sha256
    assert report.compared == 60 and report.max_abs_diff_um > 0.01
    out = tmp_path / "r.json"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "cmm_comp.cli",
            "replay",
            str(session),
            "--grid",
            str(coarse),
            "--json",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert "max |replayed − sent|" in proc.stdout
    assert json.loads(out.read_text())["compared"] == 60


def test_replay_errors_name_the_problem(tmp_path) -> None:
    with pytest.raises(ReplayError, match="no MCAP file"):
        replay_offline(tmp_path / "nothing.mcap")


def test_replay_to_bus_reaches_a_running_daemon(session) -> None:
    cfg = base_config(channel())
    with daemon_and_controller(cfg) as (d, _ctl, _bus):
        bus = can.Bus(interface="virtual", channel=cfg.can.channel)
        try:
            sent = replay_to_bus(session, bus, speed=0)
        finally:
            bus.shutdown()
        assert sent >= 61 * 3 + 4
        t0 = time.monotonic()
        while d.metrics.answered < 61 and time.monotonic() - t0 < 5:
            time.sleep(0.01)
        assert d.metrics.answers.get("ok") == 60
        assert d.metrics.answers.get("outside_volume") == 1
