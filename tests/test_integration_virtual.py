"""Sim controller and daemon in one process on python-can ``virtual`` (and Modbus TCP on
127.0.0.1): E0 after compensation at least 10× smaller than before; the demo CLI's JSON."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys

import numpy as np
import pytest
from test_daemon_support import (
    NPL,
    ROOT,
    STYLUS,
    base_config,
    channel,
    npl_grid_path,
    npl_machine,
    signing_key,
)

from cmm_comp.cli.demo import SUMMARY_KEYS, run_demo
from cmm_comp.daemon.service import DaemonService
from cmm_comp.protocol import ControllerClient, ModbusExceptionError
from cmm_comp.sim_controller.modbus_controller import ModbusController
from cmm_comp.sim_controller.runner import build_program, evaluate, make_readings
from cmm_comp.sim_controller.sim_machine import Environment, SimulatedMachine


def test_demo_in_process_e0_ten_times_smaller(tmp_path) -> None:
    result = run_demo(grid_path=npl_grid_path(), mcap_path=tmp_path / "demo.mcap", n_random=100)
    assert result["readings"] == 210 + 125 + 100
    assert result["corrected"] == result["readings"]
    assert result["e0_before_um"] > 10.0
    assert result["e0_after_um"] * 10 <= result["e0_before_um"]
    assert result["random_rms_um"]["after"] * 10 <= result["random_rms_um"]["before"]
    assert result["controller_errors"] == []
    assert (tmp_path / "demo.mcap").stat().st_size > 0


def test_demo_cli_writes_summary_json(tmp_path) -> None:
    out = tmp_path / "summary.json"
    proc = subprocess.run(
        [sys.executable, "-m", "cmm_comp.cli", "demo", "--json", str(out), "--random", "50"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=100,
    )
    assert proc.returncode == 0, proc.stderr
    assert "E0 after compensation" in proc.stdout and "[demo]" in proc.stderr
    summary = json.loads(out.read_text())
    assert tuple(summary) == SUMMARY_KEYS
    assert set(summary["latency_us"]) == {"p50", "p99"}
    assert summary["readings"] == summary["corrected"] == 385
    assert summary["e0_after_um"] * 10 <= summary["e0_before_um"]


def test_modbus_tcp_e0_and_temperatures() -> None:
    cfg = base_config(channel())
    cfg.can.enabled = False
    cfg.modbus.enabled = True
    cfg.modbus.port = 0
    machine = npl_machine()
    rng = np.random.default_rng(3)
    program = build_program(
        machine.volume.lower_mm, machine.volume.upper_mm, rng, n_random=20, plate=False
    )
    env = Environment()
    indicated, readings = make_readings(
        SimulatedMachine(machine, STYLUS, None, rng), env, program.points
    )
    with DaemonService(cfg, events_stream=None) as d:
        assert d.modbus is not None and d.modbus.host == "127.0.0.1" and d.modbus.port > 0
        ctl = ModbusController(d.modbus.host, d.modbus.port)
        answers = ctl.run(readings, lambda i: env.samples(0.0) if i % 50 == 0 else {})
        assert d.temperatures.snapshot()[0].temp_C == pytest.approx(21.0)
    result = evaluate(program, indicated, answers)
    assert result["corrected"] == len(readings)
    assert result["e0_after_um"] * 10 <= result["e0_before_um"]


def test_modbus_rejects_bad_requests() -> None:
    cfg = base_config(channel())
    cfg.can.enabled = False
    cfg.modbus.enabled = True
    cfg.modbus.port = 0

    async def scenario(port: int) -> tuple[int, int, int]:
        async with ControllerClient("127.0.0.1", port) as client:
            await client.check_server()
            codes = []
            for op in (
                client.read_registers(50, 2),  # undefined address
                client.write_registers(300, [1]),  # ANSWER is read-only
                client.write_registers(112, [7]),  # direction code 7
            ):
                try:
                    await op
                except ModbusExceptionError as exc:
                    codes.append(exc.code)
            _answer, block = await client.read_output()
            return codes[0], codes[1] * 10 + codes[2], block.input_errors

    with DaemonService(cfg, events_stream=None) as d:
        assert d.modbus is not None
        addr, write_codes, input_errors = asyncio.run(scenario(d.modbus.port))
        assert addr == 2 and write_codes == 23 and input_errors == 3
        assert d.metrics.faults["modbus_rejected_request"] == 3


def test_examples_daemon_toml_checks_with_overrides(tmp_path) -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "cmm_comp.cli",
            "daemon",
            "--config",
            str(ROOT / "examples" / "daemon.toml"),
            "--grid-path",
            str(npl_grid_path()),
            "--grid-machine",
            str(NPL),
            "--grid-public-key",
            str(signing_key()[1]),
            # --check opens the bus, binds the metrics port and checks the log folder
            "--can-interface",
            "virtual",
            "--metrics-port",
            "0",
            "--mcap-path",
            str(tmp_path / "logs"),
            "--check",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert "sha256" in proc.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "cmm_comp.cli", "daemon", "--can-bitrate", "fast", "--check"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and "can.bitrate" in bad.stderr and "Traceback" not in bad.stderr
