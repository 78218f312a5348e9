"""Daemon reply latency and throughput against bare transports, and against a baseline tree.

Run: ``.venv/bin/python benchmarks/bench_daemon.py [--baseline DIR] [--rounds 6] [--n 3000]``
(``--cases udp,virtual,throughput,modbus`` picks parts). Prints a table and writes
``benchmarks/results/daemon.json``. Every comparison runs in this process, in interleaved rounds
whose order rotates each round, so a drift of the (shared) machine's load hits every case
alike: read the ratios, not the absolute numbers. The load average at start and end is
reported; a run whose load changed a lot is worth repeating.

* ``udp``: the daemon as a subprocess on ``udp_multicast`` (two processes, the interface-local
  IPv6 group), MCAP on, grid loaded; a reading is 3 raw frames → 4 answer frames; latency = last
  raw frame sent → status frame received at the controller, paced at ``--rate`` (1 kHz) by
  sleeping. Cases: ``echo`` (a bare echo answering with 4 frames built from the raw payloads),
  ``daemon`` (this tree), ``daemon_reloads`` (the same, 10 SIGHUP grid reloads spread over the
  measurement) and, with ``--baseline DIR``, ``baseline``: the daemon of another source tree
  (e.g. ``git archive main | tar -x -C DIR``; the benchmark links its folders as ``cmm_comp``)
  with the same configuration. Each daemon is measured in its steady state: after the first
  heartbeat the round waits (≤ ``--settle-max-s``) until the daemon and its children use < 5 %
  of a core (its start-up imports are not the reply path). Per round: p50, p99 and the CPU per
  reading of the daemon's process and of its process tree; per-round ratios daemon/baseline.
* ``virtual``: controller and daemon in one process on python-can's ``virtual`` bus: ``echo``,
  the daemon with MCAP off, on, and on with a grid carrying U (U sent, a fifth frame).
* ``throughput`` (``virtual``, one process, one GIL): ``virtual_raw``, the bus alone (3 frames
  sent and received, 4 answer frames sent and received per reading, one thread, no daemon: the
  ceiling this bus sets); unpaced floods of ``--flood`` readings (batches of 16, ≤ 512
  unanswered) to a bare batch echo and to the daemon with MCAP on and off,
  and ``sustained``: ``--sustain-n`` readings paced at ``--sustain-hz`` (10 s at 10 kHz) to the
  daemon with MCAP on; lost answers, answers missing from the MCAP file, drops per topic.
* ``modbus``: FC16 write of READING + FC3 read of ANSWER on 127.0.0.1, against a plain pymodbus
  server served the same way.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from cmm_comp.compensation.grid import CorrectionGrid  # noqa: E402
from cmm_comp.compensation.machine import Machine  # noqa: E402
from cmm_comp.daemon.can_send import send_batch  # noqa: E402
from cmm_comp.daemon.config import DaemonConfig  # noqa: E402
from cmm_comp.daemon.service import DaemonService  # noqa: E402
from cmm_comp.protocol import CanIds, RawAxis, encode_message  # noqa: E402
from cmm_comp.protocol import RawReading as RawReadingFD  # noqa: E402
from cmm_comp.protocol.can_ids import MessageKind  # noqa: E402
from cmm_comp.protocol.codes import NM_PER_MM, Axis, Direction, Status, nm3_from_mm  # noqa: E402
from cmm_comp.sim_controller.controller import CanController, RawReading  # noqa: E402
from cmm_comp.sim_controller.sim_machine import Environment  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "daemon.json"
GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"
IDS = CanIds()
STYLUS = [0.0, 0.0, -120.0]
PACKAGES = ("compensation", "protocol", "daemon", "sim_controller", "cli")
RELOADS = 10
QUIET_WINDOW_S, QUIET_CPU_FRACTION = 0.3, 0.05


# ----------------------------------------------------------------------------- bare echoes
def _answers(last: dict[int, bytes], raw_z: bytes) -> list[can.Message]:
    """The 3 axis frames + status frame a bare echo sends for a RAW_Z (payloads reused)."""
    out = [
        can.Message(
            arbitration_id=IDS.id_of(kind),
            is_extended_id=False,
            data=last.get(IDS.block_start + k, bytes(8))[:7] + bytes([k]),
        )
        for k, kind in enumerate(
            (MessageKind.CORRECTED_X, MessageKind.CORRECTED_Y, MessageKind.CORRECTED_Z)
        )
    ]
    status = IDS.id_of(MessageKind.CORRECTION_STATUS)
    return [
        *out,
        can.Message(arbitration_id=status, is_extended_id=False, data=raw_z[5:7] + bytes(6)),
    ]


def run_echo(bus: can.BusABC, stop: threading.Event, batch: bool = False) -> None:
    """Answer every RAW_Z frame (``batch``: drain what waits, send all answers at once)."""
    raw_z, own = IDS.id_of(MessageKind.RAW_Z), IDS.daemon_tx_ids()
    last: dict[int, bytes] = {}
    while not stop.is_set():
        msg = bus.recv(0.01)
        out: list[can.Message] = []
        while msg is not None:
            if msg.arbitration_id not in own:
                last[msg.arbitration_id] = bytes(msg.data)
                if msg.arbitration_id == raw_z:
                    out += _answers(last, last[raw_z])
            msg = bus.recv(0.0) if batch else None
        send_batch(bus, out, None)


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


@contextlib.contextmanager
def virtual_echo(channel: str, batch: bool) -> Iterator[None]:
    """A bare echo answering on the virtual bus ``channel`` in a thread."""
    stop = threading.Event()
    echo_bus = can.Bus(interface="virtual", channel=channel)
    t = threading.Thread(target=run_echo, args=(echo_bus, stop, batch))
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join()
        echo_bus.shutdown()


# ----------------------------------------------------------------------------- helpers
def readings(n: int, rng: np.random.Generator) -> list[RawReading]:
    pts = rng.uniform([20, 20, 20], [880, 1130, 380], (n, 3))
    return [RawReading(i & 0xFFFF, tuple(map(float, p))) for i, p in enumerate(pts)]


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
    ctl.stream(rs[:200], rate_hz, in_flight=1)
    answers = ctl.stream(rs[200:], rate_hz, in_flight=1)
    return [a.latency_us for a in answers], sum(a.status == "timeout" for a in answers)


def config(grid: Path, ch: str, mcap: str = "", send_u: bool = False) -> DaemonConfig:
    cfg = DaemonConfig(source="<bench>")
    cfg.grid.path = str(grid)
    cfg.grid.stylus_mm = STYLUS
    cfg.grid.allow_unsigned = True  # a grid built here, unsigned, for the example machine
    cfg.grid.allow_any_machine = True
    cfg.can.interface, cfg.can.channel, cfg.can.heartbeat_s = "virtual", ch, 1.0
    cfg.can.send_uncertainty = send_u
    cfg.mcap.path = mcap
    cfg.metrics.enabled = False
    cfg.temperatures.stale_s = 3600
    return cfg.check()


def interleaved(
    cases: list[str],
    rounds: int,
    one_round: Callable[[str], tuple[list[float], int]],
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Every case in ``rounds`` rounds, the order rotated each round; percentiles over the
    pooled latencies (``name``), per round (``name_per_round``), answers lost (``name_lost``);
    ``progress`` is told each round's number when it is done."""
    lat: dict[str, list[float]] = {c: [] for c in cases}
    out: dict[str, Any] = {"rounds": rounds, **{f"{c}_per_round": [] for c in cases}}
    lost = dict.fromkeys(cases, 0)
    for k in range(rounds):
        for name in cases[k % len(cases) :] + cases[: k % len(cases)]:
            values, n_lost = one_round(name)
            lat[name] += values
            out[f"{name}_per_round"].append(pct(values))
            lost[name] += n_lost
        if progress is not None:
            progress(k + 1)
        print(f"round {k + 1}/{rounds} done, load {os.getloadavg()[0]:.1f}", file=sys.stderr)
    for c in cases:
        out[c], out[f"{c}_lost"] = pct(lat[c]), lost[c]
    return out


# ----------------------------------------------------------------------------- virtual
def bench_virtual(grid: Path, u_grid: Path, rs: list[RawReading], args: Any, tmp: Path) -> dict:
    """echo, daemon MCAP off / on / on with U sent, on ``virtual`` (one process)."""
    chunk = rs[: 200 + max(1, args.n // args.rounds)]

    def one(name: str) -> tuple[list[float], int]:
        ch = f"bench-{uuid.uuid4().hex[:8]}"
        if name == "echo":
            with (
                virtual_echo(ch, False),
                can.Bus(interface="virtual", channel=ch) as bus,
                CanController(bus) as ctl,
            ):
                return measure(ctl, chunk, args.rate)
        mcap = "" if name == "daemon_no_mcap" else str(tmp / f"{ch}.mcap")
        cfg = config(u_grid if name.endswith("_u") else grid, ch, mcap, name.endswith("_u"))
        with (
            DaemonService(cfg, events_stream=None),
            can.Bus(interface="virtual", channel=ch) as bus,
            CanController(bus) as ctl,
        ):
            return measure(ctl, chunk, args.rate)

    return interleaved(["echo", "daemon_no_mcap", "daemon_mcap", "daemon_mcap_u"], args.rounds, one)


# ----------------------------------------------------------------------------- throughput
def raw_frames(rs: list[RawReading], fd: bool = False) -> list[can.Message]:
    """The 3 raw axis frames of each reading (``fd``: its one RAW_XYZ CAN FD frame), encoded
    once (the flood sends them as they are)."""
    if fd:
        return [encode_message(RawReadingFD(r.seq, nm3_from_mm(r.indicated_mm)), IDS) for r in rs]
    return [
        encode_message(RawAxis(axis, r.seq, round(pos * NM_PER_MM), Direction.UNKNOWN, True), IDS)
        for r in rs
        for axis, pos in zip(Axis, r.indicated_mm, strict=True)
    ]


def flood(
    bus: can.BusABC, frames: list[can.Message], rate_hz: float = 0.0, fd: bool = False
) -> dict[str, Any]:
    """Send the readings of ``frames`` (16 readings per batch, ≤ 512 unanswered), unpaced or
    paced at ``rate_hz`` readings/s (by sleeping); count status frames (``fd``: CORRECTED_XYZ
    frames, one a reading) in a receive thread."""
    per = 1 if fd else 3  # frames a reading
    n, window, chunk = len(frames) // per, 512, 16
    status_id = IDS.id_of(MessageKind.CORRECTED_XYZ if fd else MessageKind.CORRECTION_STATUS)
    status_byte = 17 if fd else 2
    got, statuses = [0], Counter[int]()
    cond, stop = threading.Condition(), threading.Event()

    def rx() -> None:
        while not stop.is_set():
            msg, k = bus.recv(0.01), 0
            while msg is not None:
                if msg.arbitration_id == status_id:
                    statuses[msg.data[status_byte]] += 1
                    k += 1
                msg = bus.recv(0.0)
            if k:
                with cond:
                    got[0] += k
                    cond.notify()

    thread = threading.Thread(target=rx, name="flood-rx")
    thread.start()
    t0, c0, i = time.perf_counter(), time.process_time(), 0
    try:
        while i < n:
            with cond:
                while i - got[0] >= window:
                    if not cond.wait(10.0):
                        raise RuntimeError(f"no answer for 10 s after {got[0]} of {n}")
            if rate_hz > 0 and (delay := t0 + i / rate_hz - time.perf_counter()) > 0:
                time.sleep(delay)
            j = min(n, i + chunk)
            send_batch(bus, frames[per * i : per * j], None)
            i = j
        with cond:
            while got[0] < n and cond.wait(10.0):
                pass
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        stop.set()
        thread.join()
    return {
        "readings": n,
        "lost": n - got[0],
        "readings_per_s": n / dt,
        "readings_per_cpu_s": n / cpu,
        "statuses": {Status(k).label: v for k, v in sorted(statuses.items())},
    }


def virtual_raw(frames: list[can.Message], fd: bool = False) -> dict[str, Any]:
    """python-can's ``virtual`` bus alone, no daemon, no thread, no wait: per batch of 16
    readings the controller's bus sends the 3 raw frames of each, a second bus receives them
    and sends 4 answer frames each, the first receives those. The bus's own cost (a copy of
    each frame per receiver, a ``queue.Queue`` put and get): the ceiling of any reader of 3 and
    writer of 4 frames a reading on this bus in one process. ``fd``: the CAN FD pair, one
    20-byte frame a reading and one 32-byte answer."""
    per, back = (1, 1) if fd else (3, 4)  # frames a reading, frames an answer
    n, chunk = len(frames) // per, 16
    ch = f"bench-{uuid.uuid4().hex[:8]}"
    answer = (
        [
            can.Message(
                arbitration_id=IDS.id_of(MessageKind.CORRECTED_XYZ), is_fd=True, data=bytes(32)
            )
        ]
        if fd
        else _answers({}, bytes(8))
    )
    lost = 0
    with (
        can.Bus(interface="virtual", channel=ch) as ctl,
        can.Bus(interface="virtual", channel=ch) as dev,
    ):
        t0, c0 = time.perf_counter(), time.process_time()
        for i in range(0, n, chunk):
            k = min(n, i + chunk) - i
            send_batch(ctl, frames[per * i : per * (i + k)], None)
            lost += sum(dev.recv(0.0) is None for _ in range(per * k))
            send_batch(dev, answer * k, None)
            lost += sum(ctl.recv(0.0) is None for _ in range(back * k))
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"readings": n, "lost": lost, "readings_per_s": n / dt, "readings_per_cpu_s": n / cpu}


def flood_one(name: str, grid: Path, n: int, rate_hz: float, tmp: Path) -> dict[str, Any]:
    """One flood of ``n`` readings (``rate_hz`` 0: unpaced) against the batch echo or the
    daemon (``daemon_no_mcap``: logging off), in this process; for the daemon, the MCAP log's
    own counts once it has stopped (every answer in the file? drops per topic)."""
    fd = name.endswith("_fd")  # the CAN FD pair (one frame a reading, one an answer)
    name = name.removesuffix("_fd")
    frames = raw_frames(readings(n, np.random.default_rng(2)), fd)
    if name == "virtual_raw":
        return virtual_raw(frames, fd)
    ch = f"bench-{uuid.uuid4().hex[:8]}"
    if name == "echo":
        with virtual_echo(ch, True), can.Bus(interface="virtual", channel=ch) as bus:
            return flood(bus, frames)
    path = "" if name == "daemon_no_mcap" else str(tmp / f"{ch}.mcap")
    cfg = config(grid, ch, path)
    cfg.can.fd = fd
    with (
        DaemonService(cfg, events_stream=None) as d,
        can.Bus(interface="virtual", channel=ch, fd=fd) as bus,
    ):
        CanController(bus).send_temperatures(Environment().samples(0.0))
        r = flood(bus, frames, rate_hz, fd)
    if d.logger is not None:  # stopped with the service: its counts are final
        st = d.logger.stats()
        r["mcap_dropped_by_topic"] = dict(st.dropped_by_topic)
        answered = r["readings"] - r["lost"]
        r["answers_not_logged"] = answered - st.written_by_topic.get("/cmm/corrected", 0)
        Path(path).unlink(missing_ok=True)
    return r


def bench_throughput(grid: Path, args: Any, tmp: Path, pythonpath: str) -> dict[str, Any]:
    """The floods, each in a fresh process (this tree's, or with ``pythonpath`` the
    baseline's: ``baseline_*`` cases), in 2 interleaved rounds; best round of each (the least
    disturbed) and all rounds."""
    cases = ["virtual_raw", "echo", "daemon_mcap", "daemon_no_mcap", "sustained"]
    if args.fd:  # the CAN FD pair: the bus alone, the daemon unpaced and paced
        cases += ["virtual_raw_fd", "daemon_mcap_fd", "sustained_fd"]
    if pythonpath:
        cases += ["baseline_daemon_mcap", "baseline_sustained"]
    runs: dict[str, list[dict[str, Any]]] = {c: [] for c in cases}
    for k in range(2):
        for name in cases[k % len(cases) :] + cases[: k % len(cases)]:
            case = name.removeprefix("baseline_")
            paced = case.startswith("sustained")
            one = case.replace("sustained", "daemon_mcap")
            cmd = [sys.executable, __file__, "--flood-one", one,
                   "--grid", str(grid), "--flood", str(args.sustain_n if paced else args.flood),
                   "--rate", str(args.sustain_hz if paced else 0.0)]  # fmt: skip
            env = {**os.environ, "PYTHONPATH": pythonpath} if name != case else None
            done = subprocess.run(
                cmd, env=env, cwd="/" if env else ROOT, capture_output=True, text=True, check=True
            )
            runs[name].append(json.loads(done.stdout.strip().splitlines()[-1]))
    out: dict[str, Any] = {}
    for name in cases:
        best = max(runs[name], key=lambda r: r["readings_per_s"])
        out[name] = {**best, "all_readings_per_s": [r["readings_per_s"] for r in runs[name]]}
        out[name]["all_readings_per_cpu_s"] = [r["readings_per_cpu_s"] for r in runs[name]]
        out[name]["all_lost"] = [r["lost"] for r in runs[name]]
    return out


# ----------------------------------------------------------------------------- udp_multicast
def baseline_path(tree: Path, tmp: Path) -> str:
    """A folder holding ``cmm_comp/<package>`` links to the folders of the source tree
    ``tree`` (the layout an install maps): what the baseline daemon imports."""
    pkg = tmp / "baseline" / "cmm_comp"
    pkg.mkdir(parents=True)
    for name in PACKAGES:
        (pkg / name).symlink_to((tree / name).resolve())
    return str(pkg.parent)


def check_imports(pythonpath: str, tree: Path) -> None:
    """The baseline's subprocess imports ``cmm_comp.daemon`` from ``tree``, not this tree."""
    code = "import cmm_comp.daemon as d, os; print(os.path.realpath(d.__file__))"
    env = {**os.environ, "PYTHONPATH": pythonpath}
    got = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd="/", capture_output=True, text=True, check=True
    ).stdout.strip()
    if not got.startswith(str(tree.resolve())):
        raise SystemExit(f"--baseline: the subprocess imported {got}, not {tree}")


def tree_cpu_s(pid: int) -> float:
    """CPU time of process ``pid`` and its living descendants, s."""
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        with contextlib.suppress(FileNotFoundError, ProcessLookupError):
            total += process_cpu_s(p)
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo += [int(c) for c in f.read().split()]
    return total


def process_cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` (all its threads), s (``/proc/PID/stat``)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def wait_quiet(pid: int, max_s: float) -> float:
    """Wait until ``pid`` and its children use < 5 % of a core over two 0.3 s windows (its
    start-up is over); at most ``max_s`` s. Returns the time waited, s."""
    t0, cpu, quiet = time.monotonic(), tree_cpu_s(pid), 0
    while time.monotonic() - t0 < max_s and quiet < 2:
        time.sleep(QUIET_WINDOW_S)
        now = tree_cpu_s(pid)
        quiet = quiet + 1 if now - cpu < QUIET_CPU_FRACTION * QUIET_WINDOW_S else 0
        cpu = now
    return time.monotonic() - t0


def measure_with_reloads(
    proc: subprocess.Popen[str], ctl: CanController, rs: list[RawReading], rate_hz: float
) -> tuple[list[float], int]:
    """:func:`measure` while :data:`RELOADS` SIGHUPs are sent, evenly over the paced part."""
    period_s = (len(rs) - 200) / rate_hz / (RELOADS + 1)
    done = threading.Event()

    def hup() -> None:
        time.sleep(200 / rate_hz + 0.05)  # after the warm-up
        for _ in range(RELOADS):
            if done.wait(period_s):
                return
            proc.send_signal(signal.SIGHUP)

    t = threading.Thread(target=hup)
    t.start()
    try:
        return measure(ctl, rs, rate_hz)
    finally:
        done.set()
        t.join()


def udp_round(
    name: str, grid: Path, rs: list[RawReading], args: Any, tmp: Path, extra: dict
) -> tuple[list[float], int]:
    """One udp_multicast round of case ``name`` (a subprocess); CPU per reading into ``extra``."""
    port = 46000 + (uuid.uuid4().int % 2000)
    env = {**os.environ, "PYTHONPATH": extra["pythonpath"]} if name == "baseline" else None
    if name == "echo":
        cmd = [sys.executable, __file__, "--echo-server", str(port)]
    else:
        cfgf = tmp / f"udp-{port}.toml"
        cfgf.write_text(
            f'[grid]\npath = "{grid}"\nstylus_mm = {STYLUS}\nallow_unsigned = true\n'
            f'allow_any_machine = true\n[can]\ninterface = "udp_multicast"\nchannel = "{GROUP}"\n'
            f"heartbeat_s = 0.05\n[can.options]\nport = {port}\n[metrics]\nenabled = false\n"
            f'[temperatures]\nstale_s = 3600.0\n[mcap]\npath = "{tmp / f"udp-{port}.mcap"}"\n'
        )
        cmd = [sys.executable, "-m", "cmm_comp.cli", "daemon", "--config", str(cfgf), "--log-level", "error"]  # fmt: skip
    proc = subprocess.Popen(
        cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd="/" if env else ROOT, env=env
    )  # fmt: skip
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
                        raise RuntimeError(f"{name}: the daemon exited with {proc.returncode}")
                    time.sleep(0.05)
                extra.setdefault("settle_s", {}).setdefault(name, []).append(
                    wait_quiet(proc.pid, args.settle_max_s)
                )
            if name == "daemon_reloads":
                return measure_with_reloads(proc, ctl, rs, args.rate)
            cpu0, tree0 = process_cpu_s(proc.pid), tree_cpu_s(proc.pid)
            out = measure(ctl, rs, args.rate)
            per = 1e6 / len(rs)
            cpu = extra.setdefault("cpu_us_per_reading", {}).setdefault(name, [])
            cpu.append((process_cpu_s(proc.pid) - cpu0) * per)
            tree = extra.setdefault("tree_cpu_us_per_reading", {}).setdefault(name, [])
            tree.append((tree_cpu_s(proc.pid) - tree0) * per)
            return out
    finally:
        if name == "echo" and proc.stdin is not None:
            proc.stdin.close()
        else:
            proc.terminate()
        try:
            proc.wait(120)  # a loaded machine: the MCAP writer child finishes the file first
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        if proc.stdout is not None:
            proc.stdout.close()


def bench_udp(
    grid: Path, rs: list[RawReading], args: Any, tmp: Path, pythonpath: str
) -> dict[str, Any]:
    """The udp_multicast cases in interleaved rounds; with a baseline (its ``pythonpath``),
    the per-round ratios daemon / baseline."""
    cases = ["echo", "daemon", "daemon_reloads"] + (["daemon_aa"] if args.aa else [])
    extra: dict[str, Any] = {"pythonpath": pythonpath}
    if pythonpath:
        cases.append("baseline")
    chunk = rs[: 200 + args.n]
    out = interleaved(cases, args.rounds, lambda c: udp_round(c, grid, chunk, args, tmp, extra))
    out.update({k: v for k, v in extra.items() if k != "pythonpath"})
    for other, tag in (("baseline", ""), ("daemon_aa", "aa_")):  # daemon / other, per round
        if other not in cases:
            continue
        for q in ("p50", "p99"):
            pairs = zip(out["daemon_per_round"], out[f"{other}_per_round"], strict=True)
            per = [d[q] / b[q] for d, b in pairs]
            out[f"{tag}{q}_ratio_per_round"] = per
            out[f"{tag}{q}_ratio_median"] = float(np.median(per))
            out[f"{tag}{q}_ratio_pooled"] = out["daemon"][q] / out[other][q]
    return out


# ----------------------------------------------------------------------------- Modbus
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
                regs = ReadingBlock.from_mm(i & 0xFFFF, (450.0 + i % 100, 575.0, 200.0))
                t0 = time.perf_counter()
                await client.write_registers(mm.READING_START, regs.to_registers(), device_id=1)
                rr = await client.read_holding_registers(
                    mm.OUTPUT_START, count=mm.OUTPUT_SIZE, device_id=1
                )
                lat.append((time.perf_counter() - t0) * 1e6)
                assert not check_seq or rr.registers[0] == i & 0xFFFF
            return lat[100:]
        finally:
            client.close()

    def bare() -> list[float]:
        """A plain pymodbus server with no action, served from its own thread and event loop
        (as the daemon's endpoint), the same client."""
        data = [(mm.READING_START, mm.READING_SIZE), (mm.OUTPUT_START, mm.OUTPUT_SIZE)]
        dev = SimDevice(
            1, simdata=[SimData(a, values=[0] * k, datatype=DataType.REGISTERS) for a, k in data]
        )
        ready, port_box, loop = threading.Event(), [], asyncio.new_event_loop()
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
    cfg = config(grid, "unused")
    cfg.can.enabled, cfg.modbus.enabled, cfg.modbus.port = False, True, 0
    with DaemonService(cfg, events_stream=None) as d:
        assert d.modbus is not None
        daemon_lat = asyncio.run(client_loop(d.modbus.port, True))
    b, dm = pct(bare_lat), pct(daemon_lat)
    return {"bare": b, "daemon": dm, "ratio_p50": dm["p50"] / b["p50"]}


# ----------------------------------------------------------------------------- main
def print_table(result: dict[str, Any]) -> None:
    print(f"{'case':<44} {'p50 µs':>8} {'p99 µs':>8} {'n':>6} lost")
    for part in ("udp", "virtual"):
        r = result.get(part, {})
        for name in ("echo", "daemon", "daemon_aa", "daemon_reloads", "baseline", "daemon_no_mcap", "daemon_mcap", "daemon_mcap_u"):  # fmt: skip
            if name in r:
                c = r[name]
                print(f"{part}: {name:<38} {c['p50']:>8.0f} {c['p99']:>8.0f} {c['n']:>6} {r[name + '_lost']}")  # fmt: skip
    u = result.get("udp", {})
    for tag, other in (("", "baseline"), ("aa_", "daemon_aa (A/A: the noise)")):
        for q in ("p50", "p99"):
            if f"{tag}{q}_ratio_median" in u:
                per = ", ".join(f"{v:.2f}" for v in u[f"{tag}{q}_ratio_per_round"])
                print(
                    f"udp daemon / {other} {q}: median {u[f'{tag}{q}_ratio_median']:.3f}× over "
                    f"rounds ({per}), pooled {u[f'{tag}{q}_ratio_pooled']:.3f}×"
                )
    for name, v in u.get("cpu_us_per_reading", {}).items():
        tree = np.median(u["tree_cpu_us_per_reading"][name])
        print(f"CPU per reading, {name}: {np.median(v):.0f} µs (with its children {tree:.0f} µs)")
    if "daemon_reloads" in u:
        print(f"p99 during {RELOADS} reloads / without: {u['daemon_reloads']['p99'] / u['daemon']['p99']:.2f}×")  # fmt: skip
    for name, r in result.get("throughput", {}).items():
        allr = ", ".join(f"{v:.0f}" for v in r["all_readings_per_s"])
        print(
            f"throughput {name:<16} best {r['readings_per_s']:>7.0f} readings/s (all {allr}), lost "
            f"{r['all_lost']}, answers not logged {r.get('answers_not_logged', '-')}"
        )
    tp = result.get("throughput", {})
    for name, r in tp.items():
        cpu = max(r["all_readings_per_cpu_s"])
        print(f"throughput {name:<16} per CPU second of its process: {cpu:>7.0f} readings")
    for name in ("daemon_mcap", "daemon_no_mcap") if "virtual_raw" in tp else ():
        best, cpu = tp[name]["readings_per_s"], max(tp[name]["all_readings_per_cpu_s"])
        print(
            f"throughput {name} / bare echo {best / tp['echo']['readings_per_s']:.2f}× "
            f"(per CPU s {cpu / max(tp['echo']['all_readings_per_cpu_s']):.2f}×), / the virtual "
            f"bus alone {best / tp['virtual_raw']['readings_per_s']:.2f}× (per CPU s "
            f"{cpu / max(tp['virtual_raw']['all_readings_per_cpu_s']):.2f}×)"
        )
    for fd, classic in (("daemon_mcap_fd", "daemon_mcap"), ("virtual_raw_fd", "virtual_raw")):
        if fd in tp and classic in tp:
            wall = tp[fd]["readings_per_s"] / tp[classic]["readings_per_s"]
            cpu = max(tp[fd]["all_readings_per_cpu_s"]) / max(tp[classic]["all_readings_per_cpu_s"])
            print(f"throughput {fd} / {classic} (classic frames), same run: wall {wall:.2f}×, per CPU s {cpu:.2f}×")  # fmt: skip
    if "modbus" in result:
        m = result["modbus"]
        print(f"Modbus p50 daemon {m['daemon']['p50']:.0f} / bare {m['bare']['p50']:.0f} µs: {m['ratio_p50']:.2f}×")  # fmt: skip
    print(f"load average at start {result['loadavg_start']}, at end {result['loadavg_end']}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default="udp,virtual,throughput,modbus", help="parts to run")
    ap.add_argument("--baseline", default="", help="a source tree to compare with over udp")
    ap.add_argument("--aa", action="store_true", help="udp: this daemon twice (A/A: the noise)")
    ap.add_argument("--n", type=int, default=3000, help="paced readings per udp round")
    ap.add_argument("--rate", type=float, default=1000.0, help="pace of the latency cases, Hz")
    ap.add_argument("--rounds", type=int, default=6, help="interleaved rounds")
    ap.add_argument("--flood", type=int, default=50_000, help="readings per unpaced flood")
    ap.add_argument("--sustain-hz", type=float, default=10_000.0, help="pace of 'sustained'")
    ap.add_argument("--sustain-n", type=int, default=100_000, help="readings of 'sustained'")
    ap.add_argument(
        "--fd", action="store_true", help="throughput: also the CAN FD pair (RAW_XYZ/CORRECTED_XYZ)"
    )
    ap.add_argument("--modbus-n", type=int, default=2000)
    ap.add_argument("--settle-max-s", type=float, default=20.0, help="udp: wait for quiet, s")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--echo-server", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--flood-one", help=argparse.SUPPRESS)
    ap.add_argument("--grid", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.echo_server:
        echo_main(args.echo_server)
        return 0
    if args.flood_one:
        with tempfile.TemporaryDirectory() as tmpd:
            r = flood_one(args.flood_one, args.grid, args.flood, args.rate, Path(tmpd))
        print(json.dumps(r))
        return 0
    parts = set(args.cases.split(","))
    sys.setswitchinterval(0.0005)  # as the daemon process (cli/daemon.py)
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    result: dict[str, Any] = {
        "machine": platform.node(),
        "python": platform.python_version(),
        "command": " ".join(sys.argv),
        "loadavg_start": os.getloadavg(),
    }
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        grid = tmp / "npl.grid"
        CorrectionGrid.build(machine, steps=machine.volume.steps).save(grid)
        rs = readings(args.n + 200, np.random.default_rng(1))
        pythonpath = ""
        if args.baseline:
            pythonpath = baseline_path(Path(args.baseline), tmp)
            check_imports(pythonpath, Path(args.baseline))
        if "udp" in parts:
            result["udp"] = bench_udp(grid, rs, args, tmp, pythonpath)
        if "virtual" in parts:
            from cmm_comp.compensation.uncertainty.grid_field import add_uncertainty

            u_grid = tmp / "npl-u.grid"
            g = CorrectionGrid.load(grid)
            add_uncertainty(g, machine, rng=np.random.default_rng(13), seed=13, trials=300).save(u_grid)  # fmt: skip
            result["virtual"] = bench_virtual(grid, u_grid, rs, args, tmp)
        if "throughput" in parts:
            result["throughput"] = bench_throughput(grid, args, tmp, pythonpath)
        if "modbus" in parts:
            result["modbus"] = bench_modbus(grid, args.modbus_n)
    result["loadavg_end"] = os.getloadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print_table(result)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
