"""Daemon end-to-end latency and throughput vs bare transports between the same endpoints.

Run: ``.venv/bin/python benchmarks/bench_daemon.py [--n 6000] [--rounds 6] [--sustained 100000]``
(``--only-virtual`` for a quick look). Prints a table and writes ``benchmarks/results/daemon.json``.
Every comparison runs in the same process and the same minute against a bare peer on the same
transport, so read the differences and ratios, not absolute numbers (the machine is shared):

* CAN ``virtual`` (two threads, one process; the cases in interleaved rounds) and
  ``udp_multicast`` (two processes, the interface-local IPv6 group; the daemon logs MCAP with
  its default writer): a reading is 3 raw frames → 4 answer frames. The bare echo answers with
  4 frames built from the raw payloads (no decoding, no correction); the daemon decodes,
  assembles, corrects with the grid, answers, then logs. Latency = last raw frame sent → status
  frame received at the controller, paced at 1 kHz, µs.
* MCAP logging on vs off (virtual): logging must not add to the reply latency; with the
  default child-process writer (``[mcap] writer = "process"``, ``writer_priority = "idle"``:
  JSON and MCAP off the daemon's GIL, at SCHED_IDLE) and with the writer thread
  (``writer = "thread"``) for comparison.
* Sustained readings/s over ``--sustained`` readings (virtual, unpaced, bounded in flight) and
  how many were lost.
* Modbus TCP on 127.0.0.1: one reading = FC16 write of READING + FC3 read of ANSWER; the bare
  baseline is the same two requests against a plain pymodbus ``SimDevice`` without any action,
  served like the daemon's endpoint from its own thread and event loop.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import platform
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from cmm_comp.compensation.grid import CorrectionGrid  # noqa: E402
from cmm_comp.compensation.machine import Machine  # noqa: E402
from cmm_comp.daemon.config import DaemonConfig  # noqa: E402
from cmm_comp.daemon.service import DaemonService  # noqa: E402
from cmm_comp.protocol import CanIds  # noqa: E402
from cmm_comp.protocol.can_ids import MessageKind  # noqa: E402
from cmm_comp.sim_controller.controller import CanController, RawReading  # noqa: E402
from cmm_comp.sim_controller.sim_machine import Environment  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "daemon.json"
GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"
IDS = CanIds()
STYLUS = [0.0, 0.0, -120.0]


# ----------------------------------------------------------------------------- bare echo
def run_echo(bus: can.BusABC, stop: threading.Event) -> None:
    """Answer every RAW_Z frame with 3 axis frames + a status frame (payload bytes reused)."""
    raw_z = IDS.id_of(MessageKind.RAW_Z)
    own = IDS.daemon_tx_ids()
    out_ids = [
        IDS.id_of(k)
        for k in (MessageKind.CORRECTED_X, MessageKind.CORRECTED_Y, MessageKind.CORRECTED_Z)
    ]
    status_id = IDS.id_of(MessageKind.CORRECTION_STATUS)
    last: dict[int, bytes] = {}
    while not stop.is_set():
        msg = bus.recv(0.01)
        if msg is None or msg.arbitration_id in own:
            continue
        last[msg.arbitration_id] = bytes(msg.data)
        if msg.arbitration_id == raw_z:
            seq = last[raw_z][5:7]
            for k, cid in enumerate(out_ids):
                data = last.get(IDS.block_start + k, bytes(8))
                bus.send(
                    can.Message(
                        arbitration_id=cid, is_extended_id=False, data=data[:7] + bytes([k])
                    )
                )
            bus.send(
                can.Message(arbitration_id=status_id, is_extended_id=False, data=seq + bytes(6))
            )


def echo_main(port: int) -> None:
    """Subprocess entry: bare echo on udp_multicast until stdin closes."""
    stop = threading.Event()
    with can.Bus(interface="udp_multicast", channel=GROUP, port=port) as bus:
        t = threading.Thread(target=run_echo, args=(bus, stop))
        t.start()
        print("ready", flush=True)
        sys.stdin.read()
        stop.set()
        t.join()


# ----------------------------------------------------------------------------- helpers
def readings(n: int, rng: np.random.Generator) -> list[RawReading]:
    pts = rng.uniform([20, 20, 20], [880, 1130, 380], (n, 3))
    return [
        RawReading(i & 0xFFFF, (float(p[0]), float(p[1]), float(p[2]))) for i, p in enumerate(pts)
    ]


def pct(values: list[float]) -> dict[str, float]:
    a = np.array([v for v in values if np.isfinite(v)])
    return {
        "p50": float(np.percentile(a, 50)),
        "p99": float(np.percentile(a, 99)),
        "n": int(a.size),
    }


def measure(ctl: CanController, rs: list[RawReading], rate_hz: float) -> tuple[list[float], int]:
    """Latencies (µs) of ``rs`` after a 200-reading warm-up, and how many got no answer."""
    ctl.send_temperatures(Environment().samples(0.0))
    time.sleep(0.02)
    warm = ctl.stream(rs[:200], rate_hz, in_flight=1)
    del warm
    answers = ctl.stream(rs[200:], rate_hz, in_flight=1)
    lost = sum(a.status == "timeout" for a in answers)
    return [a.latency_us for a in answers], lost


def config(
    grid: Path, interface: str, ch: str, mcap: str = "", port: int = 0, writer: str = "process"
) -> DaemonConfig:
    cfg = DaemonConfig(source="<bench>")
    cfg.grid.path = str(grid)
    cfg.grid.stylus_mm = STYLUS
    cfg.can.interface = interface
    cfg.can.channel = ch
    cfg.can.heartbeat_s = 1.0
    if port:
        cfg.can.options = {"port": port}
    cfg.mcap.path = mcap
    cfg.mcap.writer = writer
    cfg.metrics.enabled = False
    cfg.temperatures.stale_s = 3600
    return cfg.check()


# ----------------------------------------------------------------------------- cases
VIRTUAL_CASES = (  # name, MCAP on, writer
    ("echo", False, ""),
    ("daemon_no_mcap", False, "process"),
    ("daemon_mcap", True, "process"),  # the default writer
    ("daemon_mcap_thread", True, "thread"),
)


def _virtual_round(
    name: str, mcap: bool, writer: str, grid: Path, rs: list[RawReading], rate_hz: float, tmp: Path
) -> tuple[list[float], int]:
    ch = f"bench-{uuid.uuid4().hex[:8]}"
    if name == "echo":
        stop = threading.Event()
        echo_bus = can.Bus(interface="virtual", channel=ch)
        t = threading.Thread(target=run_echo, args=(echo_bus, stop))
        t.start()
        try:
            with can.Bus(interface="virtual", channel=ch) as bus, CanController(bus) as ctl:
                return measure(ctl, rs, rate_hz)
        finally:
            stop.set()
            t.join()
            echo_bus.shutdown()
    path = str(tmp / f"{ch}.mcap") if mcap else ""
    with (
        DaemonService(config(grid, "virtual", ch, path, writer=writer), events_stream=None),
        can.Bus(interface="virtual", channel=ch) as bus,
        CanController(bus) as ctl,
    ):
        return measure(ctl, rs, rate_hz)


def interleaved(
    cases: list[str], rounds: int, one_round: Callable[[str], tuple[list[float], int]]
) -> dict[str, Any]:
    """Run every case in ``rounds`` interleaved rounds (order rotated every round, so a drift
    of the machine's load hits every case alike); percentiles over the pooled latencies."""
    lat: dict[str, list[float]] = {name: [] for name in cases}
    lost: dict[str, int] = dict.fromkeys(cases, 0)
    for k in range(rounds):
        shift = k % len(cases)
        for name in cases[shift:] + cases[:shift]:
            values, n_lost = one_round(name)
            lat[name] += values
            lost[name] += n_lost
    out: dict[str, Any] = {"rounds": rounds}
    for name in cases:
        out[name] = pct(lat[name])
        out[f"{name}_lost"] = lost[name]
    return out


def bench_virtual(
    grid: Path, rs: list[RawReading], rate_hz: float, tmp: Path, rounds: int = 3
) -> dict[str, Any]:
    """The :data:`VIRTUAL_CASES` in interleaved rounds (:func:`interleaved`)."""
    chunk = rs[: 200 + max(1, (len(rs) - 200) // rounds)]
    spec = {name: (mcap, writer) for name, mcap, writer in VIRTUAL_CASES}
    return interleaved(
        list(spec),
        rounds,
        lambda name: _virtual_round(name, *spec[name], grid, chunk, rate_hz, tmp),
    )


def bench_sustained(grid: Path, n: int, tmp: Path) -> dict[str, Any]:
    ch = f"bench-{uuid.uuid4().hex[:8]}"
    rs = readings(n, np.random.default_rng(2))
    with DaemonService(
        config(grid, "virtual", ch, str(tmp / "sustained.mcap")), events_stream=None
    ) as d:
        with (
            can.Bus(interface="virtual", channel=ch) as bus,
            CanController(bus, answer_timeout_s=5.0) as ctl,
        ):
            ctl.send_temperatures(Environment().samples(0.0))
            time.sleep(0.02)
            t0 = time.perf_counter()
            answers = ctl.stream(rs, 0, in_flight=32)
            dt = time.perf_counter() - t0
        assert d.logger is not None
        mcap_dropped = d.logger.stats().dropped
    ok = sum(a.status == "ok" for a in answers)
    return {
        "readings": n,
        "answered_ok": ok,
        "lost": n - sum(a.status != "timeout" for a in answers),
        "readings_per_s": n / dt,
        "mcap_dropped": mcap_dropped,
        "statuses": dict(Counter(a.status for a in answers)),
    }


UDP_CASES = {  # name: extra daemon config (TOML)
    "daemon_no_mcap": "",
    "daemon": '[mcap]\npath = "{mcap}"\n',  # the production layout: MCAP on, default writer
}


def bench_udp(
    grid: Path,
    rs: list[RawReading],
    rate_hz: float,
    tmp: Path,
    cases: tuple[str, ...] = ("echo", "daemon_no_mcap", "daemon"),
    extra: dict[str, str] | None = None,
    rounds: int = 3,
) -> dict[str, Any]:
    """``echo`` and the daemon variants of :data:`UDP_CASES` (or ``extra``: name → TOML), in
    interleaved rounds (:func:`interleaved`)."""
    chunk = rs[: 200 + max(1, (len(rs) - 200) // rounds)]
    return interleaved(
        list(cases),
        rounds,
        lambda name: _udp_round(name, grid, chunk, rate_hz, tmp, extra),
    )


def _udp_round(
    name: str,
    grid: Path,
    rs: list[RawReading],
    rate_hz: float,
    tmp: Path,
    extra: dict[str, str] | None,
) -> tuple[list[float], int]:
    variants = {**UDP_CASES, **(extra or {})}
    port = 46000 + (uuid.uuid4().int % 2000)
    if name == "echo":
        cmd = [sys.executable, __file__, "--echo-server", str(port)]
    else:
        cfgf = tmp / f"udp-{port}.toml"
        cfgf.write_text(
            f'[grid]\npath = "{grid}"\nstylus_mm = {STYLUS}\n'
            f'[can]\ninterface = "udp_multicast"\nchannel = "{GROUP}"\nheartbeat_s = 0.05\n'
            f"[can.options]\nport = {port}\n[metrics]\nenabled = false\n"
            f"[temperatures]\nstale_s = 3600.0\n"
            + variants[name].format(mcap=tmp / f"udp-{port}.mcap")
        )
        cmd = [
            sys.executable,
            "-m",
            "cmm_comp.cli",
            "daemon",
            "--config",
            str(cfgf),
            "--log-level",
            "error",
        ]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        with (
            can.Bus(interface="udp_multicast", channel=GROUP, port=port) as bus,
            CanController(bus) as ctl,
        ):
            t0 = time.monotonic()
            if name == "echo":
                assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
            else:
                while ctl.heartbeat is None and time.monotonic() - t0 < 60:
                    if proc.poll() is not None:
                        raise RuntimeError(f"daemon exited with {proc.returncode} at start")
                    time.sleep(0.05)
                if ctl.heartbeat is None:
                    raise RuntimeError("daemon sent no heartbeat within 60 s")
            return measure(ctl, rs, rate_hz)
    finally:
        if name == "echo":
            assert proc.stdin is not None
            proc.stdin.close()
        else:
            proc.terminate()
        proc.wait(20)
        if proc.stdout is not None:
            proc.stdout.close()


def bench_modbus(grid: Path, n: int) -> dict[str, Any]:
    from pymodbus.client import AsyncModbusTcpClient
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    from cmm_comp.protocol import ReadingBlock, TemperatureSlot
    from cmm_comp.protocol import modbus_map as mm

    async def client_loop(port: int, check_seq: bool) -> list[float]:
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2)
        await client.connect()
        try:
            for sensor in range(4):
                slot = TemperatureSlot(sensor, 21000, True, 1)
                await client.write_registers(slot.address, slot.to_registers(), device_id=1)
            lat = []
            for i in range(n):
                regs = ReadingBlock.from_mm(
                    i & 0xFFFF, (450.0 + i % 100, 575.0, 200.0)
                ).to_registers()
                t0 = time.perf_counter()
                await client.write_registers(mm.READING_START, regs, device_id=1)
                rr = await client.read_holding_registers(
                    mm.OUTPUT_START, count=mm.OUTPUT_SIZE, device_id=1
                )
                lat.append((time.perf_counter() - t0) * 1e6)
                if check_seq:
                    assert rr.registers[0] == i & 0xFFFF
            return lat[100:]
        finally:
            client.close()

    def bare() -> list[float]:
        """A plain pymodbus server with no action, served from its own thread and event loop —
        the same architecture as the daemon's Modbus endpoint — and the same client."""
        import threading

        dev = SimDevice(
            1,
            simdata=[
                SimData(
                    mm.READING_START, values=[0] * mm.READING_SIZE, datatype=DataType.REGISTERS
                ),
                SimData(mm.OUTPUT_START, values=[0] * mm.OUTPUT_SIZE, datatype=DataType.REGISTERS),
            ],
        )
        ready, port_box = threading.Event(), []
        loop = asyncio.new_event_loop()
        stop = asyncio.Event()

        async def serve() -> None:
            server = ModbusTcpServer(dev, address=("127.0.0.1", 0))
            await server.serve_forever(background=True)
            port_box.append(server.transport.sockets[0].getsockname()[1])
            ready.set()
            await stop.wait()
            await server.shutdown()

        thread = threading.Thread(target=loop.run_until_complete, args=(serve(),), daemon=True)
        thread.start()
        ready.wait(5)
        try:
            return asyncio.run(client_loop(port_box[0], False))
        finally:
            loop.call_soon_threadsafe(stop.set)
            thread.join(5)
            loop.close()

    bare_lat = bare()
    cfg = config(grid, "virtual", "unused")
    cfg.can.enabled = False
    cfg.modbus.enabled = True
    cfg.modbus.port = 0
    with DaemonService(cfg, events_stream=None) as d:
        assert d.modbus is not None
        daemon_lat = asyncio.run(client_loop(d.modbus.port, True))
    b, dm = pct(bare_lat), pct(daemon_lat)
    return {"bare": b, "daemon": dm, "ratio_p50": dm["p50"] / b["p50"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=6000, help="paced readings per latency case")
    ap.add_argument("--rate", type=float, default=1000.0, help="pace of latency cases, Hz")
    ap.add_argument("--rounds", type=int, default=6, help="interleaved rounds of the virtual cases")
    ap.add_argument("--sustained", type=int, default=100_000)
    ap.add_argument("--modbus-n", type=int, default=2000)
    ap.add_argument("--echo-server", type=int, help=argparse.SUPPRESS)
    ap.add_argument(
        "--only-virtual",
        action="store_true",
        help="run only the virtual-bus latency cases (quick check; prints, writes no JSON)",
    )
    args = ap.parse_args()
    if args.echo_server:
        echo_main(args.echo_server)
        return 0
    sys.setswitchinterval(0.0005)  # same as the daemon process (cli/daemon.py)
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        grid = tmp / "npl.grid"
        CorrectionGrid.build(machine, steps=machine.volume.steps).save(grid)
        rs = readings(args.n + 200, np.random.default_rng(1))
        print("virtual …", file=sys.stderr)
        virt = bench_virtual(grid, rs, args.rate, tmp, args.rounds)
        if args.only_virtual:
            for name in ("echo", "daemon_no_mcap", "daemon_mcap", "daemon_mcap_thread"):
                r = virt[name]
                print(f"{name:<22} p50 {r['p50']:7.0f}  p99 {r['p99']:7.0f}  n {r['n']}")
            return 0
        print("udp_multicast …", file=sys.stderr)
        udp = bench_udp(grid, rs, args.rate, tmp, rounds=max(1, args.rounds // 2))
        print(f"sustained {args.sustained} …", file=sys.stderr)
        sus = bench_sustained(grid, args.sustained, tmp)
        print("modbus …", file=sys.stderr)
        mb = bench_modbus(grid, args.modbus_n)
    result = {
        "machine": platform.node(),
        "python": platform.python_version(),
        "rate_hz": args.rate,
        "virtual": virt,
        "udp_multicast": udp,
        "sustained_virtual": sus,
        "modbus": mb,
        "targets": {
            "virtual_p50_over_echo_us": virt["daemon_mcap"]["p50"] - virt["echo"]["p50"],
            "virtual_p99_over_echo_us": virt["daemon_mcap"]["p99"] - virt["echo"]["p99"],
            "udp_p50_over_echo_us": udp["daemon"]["p50"] - udp["echo"]["p50"],
            "udp_p99_over_echo_us": udp["daemon"]["p99"] - udp["echo"]["p99"],
            "udp_mcap_p50_cost_us": udp["daemon"]["p50"] - udp["daemon_no_mcap"]["p50"],
            "udp_mcap_p99_cost_us": udp["daemon"]["p99"] - udp["daemon_no_mcap"]["p99"],
            "mcap_p50_cost_us": virt["daemon_mcap"]["p50"] - virt["daemon_no_mcap"]["p50"],
            "mcap_p99_cost_us": virt["daemon_mcap"]["p99"] - virt["daemon_no_mcap"]["p99"],
            "mcap_thread_p50_cost_us": virt["daemon_mcap_thread"]["p50"]
            - virt["daemon_no_mcap"]["p50"],
            "mcap_thread_p99_cost_us": virt["daemon_mcap_thread"]["p99"]
            - virt["daemon_no_mcap"]["p99"],
            "modbus_ratio_p50": mb["ratio_p50"],
        },
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    rows = [
        ("virtual: bare echo", virt["echo"]),
        ("virtual: daemon, MCAP off", virt["daemon_no_mcap"]),
        ("virtual: daemon, MCAP on (default)", virt["daemon_mcap"]),
        ("virtual: daemon, MCAP on, thread writer", virt["daemon_mcap_thread"]),
        ("udp_multicast: bare echo", udp["echo"]),
        ("udp_multicast: daemon (subprocess), MCAP off", udp["daemon_no_mcap"]),
        ("udp_multicast: daemon (subprocess), MCAP on", udp["daemon"]),
        ("Modbus TCP: bare pymodbus write+read", mb["bare"]),
        ("Modbus TCP: daemon write+read", mb["daemon"]),
    ]
    print(f"{'case':<46} {'p50 µs':>8} {'p99 µs':>8} {'n':>6}")
    for name, r in rows:
        print(f"{name:<46} {r['p50']:>8.0f} {r['p99']:>8.0f} {r['n']:>6}")
    t = result["targets"]
    print(
        f"\ndaemon − echo: virtual p50 {t['virtual_p50_over_echo_us']:+.0f} µs, p99 "
        f"{t['virtual_p99_over_echo_us']:+.0f} µs; udp_multicast p50 {t['udp_p50_over_echo_us']:+.0f} µs, "
        f"p99 {t['udp_p99_over_echo_us']:+.0f} µs (targets +150 / +500)"
    )
    print(
        f"MCAP (process writer, default) on − off, p50/p99: {t['mcap_p50_cost_us']:+.0f} / "
        f"{t['mcap_p99_cost_us']:+.0f} µs (target: +0); thread writer: "
        f"{t['mcap_thread_p50_cost_us']:+.0f} / {t['mcap_thread_p99_cost_us']:+.0f} µs"
    )
    print(
        f"MCAP on − off over udp_multicast (daemon subprocess), p50/p99: "
        f"{t['udp_mcap_p50_cost_us']:+.0f} / {t['udp_mcap_p99_cost_us']:+.0f} µs (target: +0)"
    )
    print(f"Modbus daemon/bare p50: {t['modbus_ratio_p50']:.2f}× (target ≤ 2)")
    print(
        f"sustained: {sus['readings']} readings, {sus['readings_per_s']:.0f} readings/s, "
        f"lost {sus['lost']}, MCAP dropped {sus['mcap_dropped']}"
    )
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
