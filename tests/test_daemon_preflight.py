"""``cmm-comp daemon --check`` lists every problem at once; ``daemon init``; the stylus default.

* several independent problems (a bad value, a missing machine file, a grid signed by another
  key, a log folder that cannot be made, a port in use, a CAN bus that does not open) are all
  listed in one run, each once, the grid one saying the daemon would correct nothing;
* a CAN bus that does not open is named by interface and channel, with the hint to try
  ``virtual`` or ``udp_multicast``, by ``--check`` and by the running daemon;
* the stylus defaults to the grid's probe offset; a configured one that differs is used, and
  said by ``--check`` and at start. The oracle: the grid file's own vectorised correction at
  that stylus, in this process;
* ``daemon init`` writes a folder whose grid the daemon trusts, never overwrites, and leaves
  nothing behind when it refuses;
* a daemon without a grid says so on stderr at start and answers ``no_grid``.
"""

from __future__ import annotations

import io
import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_daemon_support import (
    NPL,
    channel,
    daemon_and_controller,
    npl_grid_path,
    send_temps,
    signing_key,
)

from cmm_comp.cli.daemon_check import NOT_CORRECTING
from cmm_comp.cli.daemon_init import InitError, init_daemon_dir
from cmm_comp.cli.main import main
from cmm_comp.compensation import Machine
from cmm_comp.compensation.grid import CorrectionGrid, generate_signing_key, sign_grid
from cmm_comp.daemon.config import DaemonConfig
from cmm_comp.daemon.grid_slot import load_grid
from cmm_comp.daemon.grid_trust import GridTrust
from cmm_comp.daemon.service import DaemonService
from cmm_comp.sim_controller.controller import RawReading

TEMPS_C = {"T_x": 20.5, "T_y": 20.5, "T_z": 20.5, "T_wp": 20.5}
POINT_MM = (450.0, 575.0, 200.0)


def _check(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, list[str], str]:
    code = main(["daemon", "--check", *argv])
    out = capsys.readouterr()
    return code, out.err.strip().splitlines(), out.out


def _theirs_signed(tmp_path: Path) -> Path:
    tmp_path.mkdir(parents=True, exist_ok=True)
    grid = tmp_path / "theirs.grid"
    grid.write_bytes(npl_grid_path().read_bytes())
    private, _ = generate_signing_key(tmp_path / "theirs")
    sign_grid(grid, private)
    return grid


def test_check_lists_every_problem_at_once(tmp_path, capsys) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, lines, out = _check(
            capsys,
            "--grid-path", str(_theirs_signed(tmp_path)),
            "--grid-machine", str(tmp_path / "missing.toml"),
            "--grid-public-key", str(signing_key()[1]),
            "--mcap-path", str(blocker / "logs"),
            "--metrics-port", str(port),
            "--can-interface", "virtual",
            "--can-heartbeat-s", "nan",
        )  # fmt: skip
    assert code == 2 and "1 problem" not in out
    joined = "\n".join(lines)
    assert "Traceback" not in joined
    expected = {
        "can.heartbeat_s = nan": 1,
        "grid.machine:": 1,  # the machine file (the binding check needs it: not repeated)
        "signed by key": 1,  # the signature, checked on its own
        "is not a folder": 1,  # the log folder
    }
    for text, n in expected.items():
        assert sum(text in line for line in lines) == n, (text, lines)
    assert sum(NOT_CORRECTING in line for line in lines) == 1
    assert len(lines) == 4, lines  # bus and port checks wait for a valid configuration
    # with the configuration valid, the port in use is listed too
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        code, lines, _ = _check(
            capsys,
            "--grid-path", str(_theirs_signed(tmp_path / "b")),
            "--grid-machine", str(NPL),
            "--grid-public-key", str(signing_key()[1]),
            "--metrics-port", str(taken.getsockname()[1]),
            "--can-interface", "virtual",
        )  # fmt: skip
    assert code == 2
    assert [("signed by key" in x, "cannot listen" in x) for x in lines] == [
        (True, False),
        (False, True),
    ], lines


def test_a_grid_of_another_machine_and_unsigned_gives_both_reasons(tmp_path, capsys) -> None:
    other = tmp_path / "other.toml"
    other.write_text(NPL.read_text().replace('name = "npl-bridge"', 'name = "other"'))
    grid = tmp_path / "other.grid"
    CorrectionGrid.build(Machine.from_toml(other), steps=(5, 5, 4)).save(grid)
    code, lines, _ = _check(
        capsys,
        "--grid-path", str(grid), "--grid-machine", str(NPL),
        "--grid-public-key", str(signing_key()[1]), "--can-interface", "virtual",
        "--metrics-port", "0",
    )  # fmt: skip
    assert code == 2
    assert any("not signed" in x for x in lines) and any("built for machine" in x for x in lines)


def test_can_open_error_names_interface_and_channel(tmp_path, capsys) -> None:
    code, lines, _ = _check(
        capsys,
        "--grid-path", str(npl_grid_path()), "--grid-machine", str(NPL),
        "--grid-public-key", str(signing_key()[1]),
        "--can-interface", "socketcan", "--can-channel", "cmmnocan9", "--metrics-port", "0",
    )  # fmt: skip
    assert code == 2 and len(lines) == 1, lines
    for word in ("'socketcan'", "'cmmnocan9'", "--can-interface virtual", "udp_multicast"):
        assert word in lines[0]
    # the running daemon says the same in its can_error line
    cfg = DaemonConfig(source="<test>")
    cfg.can.interface, cfg.can.channel, cfg.metrics.enabled = "socketcan", "cmmnocan9", False
    events = io.StringIO()
    with DaemonService(cfg, events_stream=events) as d:
        assert d.can is not None and not d.can.connected
    lines = [json.loads(x) for x in events.getvalue().splitlines()]
    errors = [x["error"] for x in lines if x["event"] == "can_error"]
    assert errors and "'cmmnocan9'" in errors[0] and "--can-interface virtual" in errors[0]


def _one_answer(cfg: DaemonConfig, events: io.StringIO) -> tuple[float, float, float]:
    with daemon_and_controller(cfg, events_stream=events) as (_, ctl, _bus):
        send_temps(ctl)
        time.sleep(0.05)
        answer = ctl.exchange(RawReading(1, POINT_MM))
    assert answer.status == "ok" and answer.corrected_mm is not None, answer
    return answer.corrected_mm


def test_stylus_defaults_to_the_grid_probe_offset_and_a_different_one_is_said(capsys) -> None:
    grid = CorrectionGrid.load(npl_grid_path())
    probe = np.asarray(grid.metadata["probe_offset_mm"], float)
    assert np.any(probe != 0)  # else the default could not be told from zero
    cfg = DaemonConfig(source="<test>")
    cfg.grid.path, cfg.grid.machine = str(npl_grid_path()), str(NPL)
    cfg.grid.public_key = str(signing_key()[1])
    cfg.can.interface, cfg.can.channel, cfg.metrics.port = "virtual", channel(), 0
    events = io.StringIO()
    got = _one_answer(cfg, events)
    want, _ = grid.correct(np.array([POINT_MM]), probe, TEMPS_C)
    np.testing.assert_allclose(got, want[0], rtol=0, atol=1.01e-6)
    assert "stylus_differs" not in events.getvalue()
    loaded = [json.loads(x) for x in events.getvalue().splitlines() if "grid_loaded" in x]
    assert loaded[0]["stylus_mm"] == probe.tolist()

    other = [0.0, 10.0, -100.0]
    cfg.grid.stylus_mm, cfg.can.channel = other, channel()
    events = io.StringIO()
    got = _one_answer(cfg, events)
    want, _ = grid.correct(np.array([POINT_MM]), np.array(other), TEMPS_C)
    np.testing.assert_allclose(got, want[0], rtol=0, atol=1.01e-6)
    said = [json.loads(x) for x in events.getvalue().splitlines() if "stylus_differs" in x]
    assert len(said) == 1 and str(other) in said[0]["detail"]
    argv = ["--grid-path", cfg.grid.path, "--grid-machine", cfg.grid.machine]
    argv += ["--grid-public-key", cfg.grid.public_key, "--can-interface", "virtual"]
    code, lines, out = _check(capsys, *argv, "--metrics-port", "0", "--grid-stylus-mm", str(other))
    assert code == 0 and "1 warning" in out, out
    assert len(lines) == 1 and "differs from the probe offset" in lines[0]


def test_init_writes_a_trusted_folder_and_never_overwrites(tmp_path) -> None:
    report = init_daemon_dir(tmp_path / "d", NPL, "virtual", steps=(6, 6, 4))
    cfg_text = report.config.read_text()
    assert 'interface = "virtual"' in cfg_text and "stylus_mm =" not in cfg_text.replace(
        "# stylus_mm", ""
    )
    trust = GridTrust(public_key=str(report.public_key), machine=str(report.machine))
    loaded = load_grid(report.grid, trust)
    assert loaded.signed_by == report.key_id and list(loaded.grid.steps) == [6, 6, 4]
    assert Machine.from_toml(report.machine).identity_sha256() == (
        Machine.from_toml(NPL).identity_sha256()
    )
    assert report.logs == tmp_path / "d" / "logs" and not report.logs.exists()
    before = {p: p.read_bytes() for p in (tmp_path / "d").rglob("*") if p.is_file()}
    with pytest.raises(
        InitError, match=r"already holds daemon\.toml, machine\.toml, machine\.grid"
    ):
        init_daemon_dir(tmp_path / "d", NPL, "virtual", steps=(6, 6, 4))
    assert {p: p.read_bytes() for p in (tmp_path / "d").rglob("*") if p.is_file()} == before


def test_init_refusals_leave_nothing(tmp_path) -> None:
    from cmm_comp.compensation.errors import MachineFileError

    with pytest.raises(InitError, match="give --can-channel"):
        init_daemon_dir(tmp_path / "a", NPL, "pcan")
    with pytest.raises(InitError, match="--can-option value"):
        init_daemon_dir(
            tmp_path / "b", NPL, "virtual", can_options={"x": {"y": 1}}, steps=(5, 5, 4)
        )
    with pytest.raises(MachineFileError):
        init_daemon_dir(tmp_path / "c", tmp_path / "no-such-machine.toml", "virtual")
    assert not any((tmp_path / n).exists() for n in ("a", "b", "c"))
    # a failure after the first files were written: they are removed again
    folder = tmp_path / "d"
    folder.mkdir()
    (folder / "keys").write_text("a file where the key folder goes")
    with pytest.raises(OSError):
        init_daemon_dir(folder, NPL, "virtual", steps=(5, 5, 4))
    assert sorted(p.name for p in folder.iterdir()) == ["keys"]


def test_init_cli_prints_the_start_command(tmp_path, capsys) -> None:
    folder = tmp_path / "mine"
    code = main(["daemon", "init", str(folder), "--machine", str(NPL), "--steps", "5", "5", "4",
                 "--can-interface", "udp_multicast", "--can-option", "port=43999"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert out.rstrip().endswith(
        f"start the daemon with:\n  cmm-comp daemon --config {folder}/daemon.toml"
    )
    text = (folder / "daemon.toml").read_text()
    assert 'channel = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"' in text and "port = 43999" in text
    assert (folder / "keys" / "grid-signing-key.pem").stat().st_mode & 0o777 == 0o600


def test_a_daemon_without_a_grid_says_so_at_start(tmp_path) -> None:
    argv = [sys.executable, "-m", "cmm_comp.cli", "daemon", "--can-interface", "virtual",
            "--metrics-port", "0"]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline() if proc.stderr is not None else ""
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    assert "NOT CORRECTING: grid.path is empty" in line and "no_grid" in line, line + err
    assert '"state":"no_grid"' in out
