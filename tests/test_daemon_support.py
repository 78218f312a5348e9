"""Helpers shared by the daemon, sim, integration and replay tests (no tests in here).

The grid of ``examples/machines/npl-bridge.toml`` is built once per test process (~0.3 s) into
a temporary directory removed at exit, and signed with a test key made once per process
(:func:`signing_key`); :func:`base_config` trusts that key and binds the NPL machine.
"""

from __future__ import annotations

import atexit
import functools
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import can

from cmm_comp.compensation.grid import CorrectionGrid, generate_signing_key, sign_grid
from cmm_comp.compensation.machine import Machine
from cmm_comp.daemon.config import DaemonConfig
from cmm_comp.daemon.service import DaemonService
from cmm_comp.protocol.codes import DaemonState
from cmm_comp.sim_controller.controller import CanController

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"
STYLUS = [0.0, 0.0, -120.0]
MCAST_GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"
CENTRE_MM = (450.0, 575.0, 200.0)


@functools.cache
def _workdir() -> Path:
    path = Path(tempfile.mkdtemp(prefix="cmm-daemon-tests-"))
    atexit.register(shutil.rmtree, path, True)
    return path


@functools.cache
def npl_machine() -> Machine:
    return Machine.from_toml(NPL)


@functools.cache
def signing_key() -> tuple[Path, Path]:
    """``(private, public)`` PEM files of this test process's grid-signing key."""
    return generate_signing_key(_workdir() / "keys")


def build_signed_grid(path: Path, steps: tuple[int, int, int] = (19, 23, 16)) -> Path:
    """Build the NPL grid at ``path`` and sign it with :func:`signing_key`."""
    CorrectionGrid.build(npl_machine(), steps=steps).save(path)
    sign_grid(path, signing_key()[0])
    return path


@functools.cache
def npl_grid_path(steps: tuple[int, int, int] = (19, 23, 16)) -> Path:
    """Grid file of the NPL example machine (built once, signed with :func:`signing_key`)."""
    return build_signed_grid(_workdir() / f"npl-{steps[0]}x{steps[1]}x{steps[2]}.grid", steps)


def trust_toml() -> str:
    """``[grid]`` lines that trust :func:`signing_key` and bind the NPL machine."""
    return f'machine = "{NPL}"\npublic_key = "{signing_key()[1]}"\n'


def channel() -> str:
    """A fresh virtual-bus channel name."""
    return f"test-{uuid.uuid4().hex[:10]}"


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:
        s.bind(("::1", 0))
        return int(s.getsockname()[1])


def base_config(ch: str, grid: Path | None = None) -> DaemonConfig:
    """Virtual CAN on ``ch``, NPL grid, no Modbus, metrics on a free port, no MCAP."""
    cfg = DaemonConfig(source="<test>")
    cfg.grid.path = str(grid if grid is not None else npl_grid_path())
    cfg.grid.stylus_mm = list(STYLUS)
    cfg.grid.machine = str(NPL)
    cfg.grid.public_key = str(signing_key()[1])
    cfg.can.interface = "virtual"
    cfg.can.channel = ch
    cfg.metrics.port = 0
    return cfg


@contextmanager
def daemon_and_controller(
    cfg: DaemonConfig, **service_kwargs: object
) -> Iterator[tuple[DaemonService, CanController, can.BusABC]]:
    """Start a daemon on ``cfg.can.channel`` and a controller (with its raw bus) on it."""
    cfg.check()
    with DaemonService(
        cfg, events_stream=service_kwargs.pop("events_stream", None), **service_kwargs
    ) as d:  # type: ignore[arg-type]
        bus = can.Bus(interface="virtual", channel=cfg.can.channel)
        try:
            with CanController(bus, answer_timeout_s=10.0) as ctl:  # generous: load
                yield d, ctl, bus
        finally:
            bus.shutdown()


def write_udp_config(tmp: Path, port: int, grid: Path, mcap: Path, writer: str = "process") -> Path:
    """``tmp/daemon.toml``: udp_multicast on the interface-local group at ``port``, heartbeat
    every 50 ms, MCAP log ``mcap`` (flushed every 0.2 s) by ``writer``, metrics on a free port."""
    cfg = tmp / "daemon.toml"
    cfg.write_text(
        f"""
[grid]
path = "{grid}"
stylus_mm = {STYLUS}
{trust_toml()}[can]
interface = "udp_multicast"
channel = "{MCAST_GROUP}"
heartbeat_s = 0.05
[can.options]
port = {port}
[mcap]
path = "{mcap}"
flush_s = 0.2
writer = "{writer}"
[metrics]
port = 0
"""
    )
    return cfg


def start_daemon_cli(config: Path, log: Path) -> subprocess.Popen:
    """``cmm-comp daemon --config CONFIG`` as a subprocess, its output (events) to ``log``."""
    with open(log, "w") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "cmm_comp.cli", "daemon", "--config", str(config)],
            stdout=out,
            stderr=subprocess.STDOUT,
        )


@contextmanager
def daemon_subprocess(
    tmp: Path,
    grid: Path,
    writer: str = "process",
    wrap_bus: Callable[[can.BusABC], Any] = lambda bus: bus,
) -> Iterator[tuple[subprocess.Popen, CanController, Path, Path]]:
    """The daemon as a real subprocess (its CLI) on ``udp_multicast`` (a free port) logging to
    ``tmp/session.mcap``, and a controller on its own bus (``wrap_bus`` may wrap that bus, e.g.
    to count what the controller sends); yields ``(process, controller, mcap, daemon log)``
    once the daemon's heartbeat says ready. The process is killed if still running at exit."""
    port = free_udp_port()
    mcap = tmp / "session.mcap"
    cfg = write_udp_config(tmp, port, grid, mcap, writer)
    log = tmp / "daemon.log"
    proc = start_daemon_cli(cfg, log)
    bus = can.Bus(interface="udp_multicast", channel=MCAST_GROUP, port=port)
    try:
        with CanController(wrap_bus(bus), answer_timeout_s=10.0) as ctl:  # generous: load
            t0 = time.monotonic()
            while ctl.heartbeat is None or ctl.heartbeat.state != DaemonState.READY:
                assert proc.poll() is None, log.read_text()
                assert time.monotonic() - t0 < 60, f"daemon not ready: {log.read_text()}"
                time.sleep(0.05)
            yield proc, ctl, mcap, log
    finally:
        bus.shutdown()
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)


def send_temps(ctl: CanController, temp_C: float = 20.5) -> None:
    """One sample of each default sensor (0..3)."""
    ctl.send_temperatures({0: temp_C, 1: temp_C, 2: temp_C, 3: temp_C})


def test_os_thread_names_show_the_daemon_parts() -> None:
    """name_os_thread() names the OS thread (what top -H and perf show) after the Python one."""
    import sys
    import threading

    from cmm_comp.daemon.osthread import name_os_thread

    seen: list[str] = []

    def run() -> None:
        ok = name_os_thread()
        tid = threading.get_native_id()
        if ok:
            with open(f"/proc/self/task/{tid}/comm") as f:
                seen.append(f.read().strip())
        else:
            seen.append("")

    t = threading.Thread(target=run, name="can-endpoint-and-more")
    t.start()
    t.join()
    if sys.platform.startswith("linux"):
        assert seen == ["can-endpoint-an"]  # 15 bytes: the kernel's limit
