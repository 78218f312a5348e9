"""Daemon end-to-end latency and throughput vs bare transports between the same endpoints.

Run: ``.venv/bin/python benchmarks/bench_daemon.py [--n 6000] [--rounds 6] [--flood 50000]``
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
* Reloads: ``daemon_reloads`` is the ``udp_multicast`` daemon case with 10 SIGHUP grid reloads
  spread over its measurement; its p99 against ``daemon``'s in the same rounds (target ≤ 2×).
* Throughput (``virtual``, controller and daemon in one process, i.e. one GIL): an unpaced
  flood of ``--flood`` readings (frames sent in batches, at most 512 readings unanswered),
  readings/s until the last status frame, for a bare echo that drains and batch-sends like the
  daemon, the daemon with MCAP on and off; and ``sustained``: ``--sustain-n`` readings paced
  at ``--sustain-hz`` (10 s at 10 kHz) to the daemon with MCAP on. Reported per case: lost
  answers, answers missing from the MCAP file and the log's drops per topic (read from the
  log's own exact counters once it has stopped); ratios daemon/echo in the same process.
* ``--before-tree``: the udp_multicast rounds also run an older tree's daemon (MCAP on): the
  reply latency now against before, same run, interleaved. ``--only-before`` runs just that
  (echo, now, before, and ``--other-tree NAME=DIR`` daemons) for ``--rounds`` rounds of ``--n``
  readings and reports per-round ratios (their spread is the noise), the latency each daemon
  reports in its status frames (reading complete → status encoded: no transport, steadier) and
  CPU per reading (of the daemon process, and with its children);
  ``benchmarks/results/daemon_before.json``. A tree folder holds ``cmm_comp/<package>`` links
  to a ``git worktree`` of the commit.
* Every udp_multicast daemon case measures its steady state: after the first heartbeat it waits
  (``--settle-max-s``, 20 s at most) until the daemon and its children use < 5 % of a core over
  two 0.3 s windows. A daemon's first seconds are start-up (the grid-reload worker imports the
  grid code at SCHED_IDLE, ~0.6 s of CPU), not its reply path: measured right after the
  heartbeat they raised the reply p50 ~1.5× (``--settle-max-s 0`` measures them).
* Uncertainty (issue 13): ``daemon_mcap_u`` is ``daemon_mcap`` with the grid carrying U (the
  same grid plus the virtual CMM's covariances) and ``[can] send_uncertainty`` on (U computed
  per reading, a fifth frame sent), in the same interleaved rounds, for latency and for the
  unpaced flood; ``--only-uncertainty`` runs just these two cases and writes
  ``benchmarks/results/daemon_uncertainty.json``.
* Modbus TCP on 127.0.0.1: one reading = FC16 write of READING + FC3 read of ANSWER; the bare
  baseline is the same two requests against a plain pymodbus ``SimDevice`` without any action,
  served like the daemon's endpoint from its own thread and event loop.
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
from cmm_comp.protocol.can_ids import MessageKind  # noqa: E402
from cmm_comp.protocol.codes import NM_PER_MM, Axis, Direction, Status  # noqa: E402
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


@contextlib.contextmanager
def virtual_echo(
    channel: str, echo: Callable[[can.BusABC, threading.Event], None]
) -> Iterator[None]:
    """``echo`` (:func:`run_echo` or :func:`run_batch_echo`) answering on the virtual bus
    ``channel`` in a thread for the duration of the block."""
    stop = threading.Event()
    echo_bus = can.Bus(interface="virtual", channel=channel)
    t = threading.Thread(target=echo, args=(echo_bus, stop))
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


def measure(
    ctl: CanController,
    rs: list[RawReading],
    rate_hz: float,
    internal_us: list[float] | None = None,
) -> tuple[list[float], int]:
    """Latencies (µs) of ``rs`` after a 200-reading warm-up, and how many got no answer;
    with ``internal_us``, appends the latency each answer's status frame reports (the daemon's
    own, from the frame completing the reading to the status frame's encoding, µs)."""
    ctl.send_temperatures(Environment().samples(0.0))
    time.sleep(0.02)
    warm = ctl.stream(rs[:200], rate_hz, in_flight=1)
    del warm
    answers = ctl.stream(rs[200:], rate_hz, in_flight=1)
    lost = sum(a.status == "timeout" for a in answers)
    if internal_us is not None:
        internal_us += [float(a.daemon_latency_us) for a in answers if a.status != "timeout"]
    return [a.latency_us for a in answers], lost


def config(
    grid: Path, interface: str, ch: str, mcap: str = "", port: int = 0, writer: str = "process"
) -> DaemonConfig:
    cfg = DaemonConfig(source="<bench>")
    cfg.grid.path = str(grid)
    cfg.grid.stylus_mm = STYLUS
    cfg.grid.allow_unsigned = True  # a grid built here, unsigned, for the example machine
    cfg.grid.allow_any_machine = True
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
    ("daemon_mcap_u", True, "process"),  # grid carrying U, U sent (a fifth frame)
    ("daemon_mcap_u_nosend", True, "process"),  # grid carrying U, U computed and logged only
)
U_GRID: Path | None = None
"""The benchmark grid carrying U (set by :func:`main`): the ``*_u`` cases use it."""


def daemon_config(grid: Path, ch: str, mcap: str, name: str, writer: str = "process") -> Any:
    """:func:`config` for case ``name``: a ``*_u`` case takes :data:`U_GRID` and sends U, a
    ``*_u_nosend`` case takes it without sending U on CAN (U computed and logged only)."""
    with_u = name.endswith(("_u", "_u_nosend"))
    if with_u and U_GRID is None:
        raise RuntimeError("the *_u cases need U_GRID (built by main)")
    cfg = config(U_GRID if with_u and U_GRID else grid, "virtual", ch, mcap, writer=writer)
    cfg.can.send_uncertainty = name.endswith("_u")
    return cfg


def build_u_grid(machine: Machine, grid: Path, out: Path, trials: int = 300) -> Path:
    """``grid`` (built from ``machine``) carrying U (virtual CMM, ``trials`` per node)."""
    from cmm_comp.compensation.uncertainty.grid_field import add_uncertainty

    g = CorrectionGrid.load(grid)
    add_uncertainty(g, machine, rng=np.random.default_rng(13), seed=13, trials=trials).save(out)
    return out


def _virtual_round(
    name: str, mcap: bool, writer: str, grid: Path, rs: list[RawReading], rate_hz: float, tmp: Path
) -> tuple[list[float], int]:
    ch = f"bench-{uuid.uuid4().hex[:8]}"
    if name == "echo":
        with (
            virtual_echo(ch, run_echo),
            can.Bus(interface="virtual", channel=ch) as bus,
            CanController(bus) as ctl,
        ):
            return measure(ctl, rs, rate_hz)
    path = str(tmp / f"{ch}.mcap") if mcap else ""
    with (
        DaemonService(daemon_config(grid, ch, path, name, writer), events_stream=None),
        can.Bus(interface="virtual", channel=ch) as bus,
        CanController(bus) as ctl,
    ):
        return measure(ctl, rs, rate_hz)


def interleaved(
    cases: list[str],
    rounds: int,
    one_round: Callable[[str], tuple[list[float], int]],
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Run every case in ``rounds`` interleaved rounds (order rotated every round, so a drift
    of the machine's load hits every case alike); percentiles over the pooled latencies
    (``name``), per round (``name_per_round``), answers lost (``name_lost``). ``progress``
    (optional) is told each round's number when it is done."""
    lat: dict[str, list[float]] = {name: [] for name in cases}
    per_round: dict[str, list[dict[str, float]]] = {name: [] for name in cases}
    lost: dict[str, int] = dict.fromkeys(cases, 0)
    for k in range(rounds):
        shift = k % len(cases)
        for name in cases[shift:] + cases[:shift]:
            values, n_lost = one_round(name)
            lat[name] += values
            per_round[name].append(pct(values))
            lost[name] += n_lost
        if progress is not None:
            progress(k + 1)
    out: dict[str, Any] = {"rounds": rounds}
    for name in cases:
        out[name] = pct(lat[name])
        out[f"{name}_per_round"] = per_round[name]
        out[f"{name}_lost"] = lost[name]
    return out


def bench_virtual(
    grid: Path,
    rs: list[RawReading],
    rate_hz: float,
    tmp: Path,
    rounds: int = 3,
    only: tuple[str, ...] | None = None,
) -> dict[str, Any]:
    """The :data:`VIRTUAL_CASES` (or those named in ``only``) in interleaved rounds
    (:func:`interleaved`)."""
    chunk = rs[: 200 + max(1, (len(rs) - 200) // rounds)]
    spec = {
        name: (mcap, writer) for name, mcap, writer in VIRTUAL_CASES if only is None or name in only
    }
    return interleaved(
        list(spec),
        rounds,
        lambda name: _virtual_round(name, *spec[name], grid, chunk, rate_hz, tmp),
    )


def run_batch_echo(bus: can.BusABC, stop: threading.Event) -> None:
    """The bare echo of :func:`run_echo`, done the way the daemon works under load: drain every
    waiting frame per wake-up, send all answers in one batch (:func:`send_batch`)."""
    raw_z = IDS.id_of(MessageKind.RAW_Z)
    out_ids = [
        IDS.id_of(k)
        for k in (MessageKind.CORRECTED_X, MessageKind.CORRECTED_Y, MessageKind.CORRECTED_Z)
    ]
    status_id = IDS.id_of(MessageKind.CORRECTION_STATUS)
    last: dict[int, bytes] = {}
    while not stop.is_set():
        msg = bus.recv(0.01)
        out: list[can.Message] = []
        while msg is not None:
            last[msg.arbitration_id] = bytes(msg.data)
            if msg.arbitration_id == raw_z:
                seq = last[raw_z][5:7]
                for k, cid in enumerate(out_ids):
                    data = last.get(IDS.block_start + k, bytes(8))
                    out.append(
                        can.Message(
                            arbitration_id=cid, is_extended_id=False, data=data[:7] + bytes([k])
                        )
                    )
                out.append(
                    can.Message(arbitration_id=status_id, is_extended_id=False, data=seq + bytes(6))
                )
            msg = bus.recv(0.0)
        if out:
            send_batch(bus, out, None)


def raw_frames(rs: list[RawReading]) -> list[can.Message]:
    """The 3 raw axis frames of each reading, encoded once (the flood sends them as they are)."""
    out = []
    for r in rs:
        for axis, pos in zip(Axis, r.indicated_mm, strict=True):
            frame = RawAxis(axis, r.seq, round(pos * NM_PER_MM), Direction.UNKNOWN, True)
            out.append(encode_message(frame, IDS))
    return out


def flood(
    bus: can.BusABC,
    frames: list[can.Message],
    window: int,
    chunk: int = 16,
    rate_hz: float = 0.0,
) -> dict[str, Any]:
    """Send the readings of ``frames`` (``chunk`` readings per send batch, at most ``window``
    unanswered), unpaced or paced at ``rate_hz`` readings/s (by sleeping, never spinning),
    count status frames in a receive thread; readings/s over the run."""
    n = len(frames) // 3
    status_id = IDS.id_of(MessageKind.CORRECTION_STATUS)
    got = [0]
    statuses: Counter[int] = Counter()
    cond = threading.Condition()
    stop = threading.Event()

    def rx() -> None:
        while not stop.is_set():
            msg = bus.recv(0.01)
            k = 0
            while msg is not None:
                if msg.arbitration_id == status_id:
                    statuses[msg.data[2]] += 1
                    k += 1
                msg = bus.recv(0.0)
            if k:
                with cond:
                    got[0] += k
                    cond.notify()

    thread = threading.Thread(target=rx, name="flood-rx")
    thread.start()
    t0 = time.perf_counter()
    i = 0
    try:
        while i < n:
            with cond:
                while i - got[0] >= window:
                    if not cond.wait(10.0):
                        raise RuntimeError(f"no answer for 10 s after {got[0]} of {n}")
            if rate_hz > 0:
                delay = t0 + i / rate_hz - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            j = min(n, i + chunk)
            send_batch(bus, frames[3 * i : 3 * j], None)
            i = j
        with cond:
            while got[0] < n and cond.wait(10.0):
                pass
        dt = time.perf_counter() - t0
    finally:
        stop.set()
        thread.join()
    return {
        "readings": n,
        "answered": got[0],
        "lost": n - got[0],
        "readings_per_s": n / dt,
        "statuses": {Status(k).label: v for k, v in sorted(statuses.items())},
    }


def _throughput_round(
    name: str, grid: Path, frames: list[can.Message], tmp: Path, window: int, rate_hz: float
) -> dict[str, Any]:
    """One flood of ``frames`` against the batch echo or the daemon (``*_no_mcap``: logging
    off); for the daemon, the MCAP log's own counts once it has stopped (the whole story:
    every topic written or dropped, and whether every answer reached the file)."""
    ch = f"bench-{uuid.uuid4().hex[:8]}"
    if name == "echo":
        with virtual_echo(ch, run_batch_echo), can.Bus(interface="virtual", channel=ch) as bus:
            return flood(bus, frames, window, rate_hz=rate_hz)
    path = "" if name.endswith("no_mcap") else str(tmp / f"{ch}.mcap")
    with (
        DaemonService(daemon_config(grid, ch, path, name), events_stream=None) as d,
        can.Bus(interface="virtual", channel=ch) as bus,
    ):
        CanController(bus).send_temperatures(Environment().samples(0.0))
        r = flood(bus, frames, window, rate_hz=rate_hz)
    log = d.logger  # stopped with the service: its counts are final
    if log is not None:
        st = log.stats()
        r["mcap_written"] = st.written
        r["mcap_dropped"] = st.dropped
        r["mcap_dropped_by_topic"] = dict(st.dropped_by_topic)
        r["mcap_written_by_topic"] = dict(st.written_by_topic)
        r["answers_not_logged"] = r["answered"] - st.written_by_topic.get("/cmm/corrected", 0)
        Path(path).unlink(missing_ok=True)
    return r


def bench_throughput(
    grid: Path,
    n: int,
    tmp: Path,
    rounds: int = 2,
    window: int = 512,
    sustain_hz: float = 10_000.0,
    sustain_n: int = 100_000,
    cases: tuple[str, ...] = ("echo", "daemon_mcap", "daemon_no_mcap", "sustained"),
) -> dict[str, Any]:
    """Two questions on ``virtual``, the cases in interleaved rounds:

    * unpaced flood of ``n`` readings: the batch echo, the daemon with MCAP on (default
      writer) and off; best round of each (the machine is shared: the best round is the least
      disturbed one) and the daemon/echo ratios;
    * ``sustained``: ``sustain_n`` readings paced at ``sustain_hz`` (10 s at 10 kHz) to the
      daemon with MCAP on: achieved readings/s, lost answers, answers missing from the log
      and the log's drops per topic (frames go first under overload, by policy)."""
    frames = raw_frames(readings(n, np.random.default_rng(2)))
    sframes = raw_frames(readings(sustain_n, np.random.default_rng(3))) if sustain_n else []
    runs: dict[str, list[dict[str, Any]]] = {c: [] for c in cases}
    for k in range(rounds):
        shift = k % len(cases)
        for name in cases[shift:] + cases[:shift]:
            if name == "sustained":
                r = _throughput_round("daemon_mcap", grid, sframes, tmp, window, sustain_hz)
            elif name == "sustained_u":
                r = _throughput_round("daemon_mcap_u", grid, sframes, tmp, window, sustain_hz)
            else:
                r = _throughput_round(name, grid, frames, tmp, window, 0.0)
            runs[name].append(r)
    out: dict[str, Any] = {"rounds": rounds, "window": window, "sustain_hz": sustain_hz}
    for name in cases:
        best = max(runs[name], key=lambda r: r["readings_per_s"])
        out[name] = {**best, "all_readings_per_s": [r["readings_per_s"] for r in runs[name]]}
        out[name]["all_lost"] = [r["lost"] for r in runs[name]]
        if name != "echo":
            out[name]["all_answers_not_logged"] = [r.get("answers_not_logged") for r in runs[name]]
            out[name]["all_mcap_dropped"] = [r.get("mcap_dropped") for r in runs[name]]
    if "echo" in cases:
        for name in ("daemon_mcap", "daemon_no_mcap", "daemon_mcap_u"):
            if name in cases:
                echo = out["echo"]["readings_per_s"]
                out[f"{name}_over_echo"] = out[name]["readings_per_s"] / echo
    if "daemon_no_mcap" in cases:
        out["daemon_mcap_over_no_mcap"] = (
            out["daemon_mcap"]["readings_per_s"] / out["daemon_no_mcap"]["readings_per_s"]
        )
    if "daemon_mcap_u" in cases:
        out["daemon_mcap_u_over_daemon_mcap"] = (
            out["daemon_mcap_u"]["readings_per_s"] / out["daemon_mcap"]["readings_per_s"]
        )
    return out


UDP_CASES = {  # name: extra daemon config (TOML)
    "daemon_no_mcap": "",
    "daemon": '[mcap]\npath = "{mcap}"\n',  # the production layout: MCAP on, default writer
    "daemon_reloads": '[mcap]\npath = "{mcap}"\n',  # the same, SIGHUP ×10 while measuring
}
RELOADS = 10
BEFORE_TREE = ""
OTHER_TREES: dict[str, str] = {}
"""``--other-tree NAME=DIR`` (with ``--only-before``): more trees' daemons, case ``NAME``."""
"""``--before-tree``: a ``cmm_comp`` package folder of an older tree (``git archive`` + links);
adds the ``daemon_before`` case, that tree's daemon with MCAP on, to the udp_multicast rounds."""


def bench_udp(
    grid: Path,
    rs: list[RawReading],
    rate_hz: float,
    tmp: Path,
    cases: tuple[str, ...] = ("echo", "daemon_no_mcap", "daemon", "daemon_reloads"),
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
    cpu_us: list[float] | None = None,
    internal_us: list[float] | None = None,
) -> tuple[list[float], int]:
    """One udp_multicast round of case ``name``: latencies (µs) and lost answers; with
    ``cpu_us``, appends the CPU time the case's process (its threads, not its children: the
    MCAP writer child is not counted) spent per measured reading, µs."""
    variants = {**UDP_CASES, **(extra or {})}
    port = 46000 + (uuid.uuid4().int % 2000)
    env = None
    trust = "allow_unsigned = true\nallow_any_machine = true\n"
    if name == "daemon_before":
        env = {**os.environ, "PYTHONPATH": BEFORE_TREE}
        variants[name] = UDP_CASES["daemon"]
        trust = ""  # the older tree knows no grid trust settings
    elif name in OTHER_TREES:  # a tree that knows the trust settings
        env = {**os.environ, "PYTHONPATH": OTHER_TREES[name]}
        variants[name] = UDP_CASES["daemon"]
    if name == "echo":
        cmd = [sys.executable, __file__, "--echo-server", str(port)]
    else:
        cfgf = tmp / f"udp-{port}.toml"
        cfgf.write_text(
            f'[grid]\npath = "{grid}"\nstylus_mm = {STYLUS}\n'
            + trust
            + f'[can]\ninterface = "udp_multicast"\nchannel = "{GROUP}"\nheartbeat_s = 0.05\n'
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
    proc = subprocess.Popen(
        cmd,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd="/" if env else ROOT,
        env=env,
    )
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
                if SETTLE_MAX_S > 0:
                    SETTLE_S.setdefault(name, []).append(wait_quiet(proc.pid, SETTLE_MAX_S))
            if name.endswith("_reloads"):
                return _measure_with_reloads(proc, ctl, rs, rate_hz)
            cpu0, tree0 = process_cpu_s(proc.pid), tree_cpu_s(proc.pid)
            out = measure(ctl, rs, rate_hz, internal_us)
            if cpu_us is not None:
                cpu_us.append((process_cpu_s(proc.pid) - cpu0) / len(rs) * 1e6)
                TREE_CPU_US.setdefault(name, []).append(
                    (tree_cpu_s(proc.pid) - tree0) / len(rs) * 1e6
                )
            return out
    finally:
        if name == "echo":
            assert proc.stdin is not None
            proc.stdin.close()
        else:
            proc.terminate()
        try:
            proc.wait(120)  # a loaded machine: the MCAP writer child finishes the file first
        except subprocess.TimeoutExpired:
            print(f"warning: {name} did not stop within 120 s of SIGTERM: killed", file=sys.stderr)
            proc.kill()
            proc.wait(10)
        if proc.stdout is not None:
            proc.stdout.close()


SETTLE_MAX_S = 20.0
"""Before measuring, a udp_multicast daemon case waits (at most this long, s; 0: not at all)
until its process and its children have finished starting (:func:`wait_quiet`)."""
SETTLE_S: dict[str, list[float]] = {}
"""How long each case's daemon took to settle, per round, s (reported in the JSON)."""
TREE_CPU_US: dict[str, list[float]] = {}
"""CPU per reading of each case's daemon with its children (MCAP writer…), per round, µs."""
QUIET_WINDOW_S = 0.3
QUIET_CPU_FRACTION = 0.05


def tree_cpu_s(pid: int) -> float:
    """CPU time of process ``pid`` and all its descendants (alive ones), s."""
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        try:
            total += process_cpu_s(p)
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo += [int(c) for c in f.read().split()]
        except (FileNotFoundError, ProcessLookupError):
            continue
    return total


def wait_quiet(pid: int, max_s: float) -> float:
    """Wait until daemon ``pid`` and its children (MCAP writer, grid worker importing its
    modules at start) use less than :data:`QUIET_CPU_FRACTION` of a core over
    :data:`QUIET_WINDOW_S`: its start-up is over, what follows is the steady state. Gives up
    after ``max_s`` (s, with a warning). Returns the time waited, s."""
    t0 = time.monotonic()
    cpu, quiet = tree_cpu_s(pid), 0
    while time.monotonic() - t0 < max_s:
        time.sleep(QUIET_WINDOW_S)
        now = tree_cpu_s(pid)
        quiet = quiet + 1 if now - cpu < QUIET_CPU_FRACTION * QUIET_WINDOW_S else 0
        if quiet >= 2:  # two windows in a row
            return time.monotonic() - t0
        cpu = now
    print(f"warning: daemon {pid} still busy {max_s:.0f} s after start", file=sys.stderr)
    return time.monotonic() - t0


def process_cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` (all its threads), s (``/proc/PID/stat``)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _measure_with_reloads(
    proc: subprocess.Popen[str], ctl: CanController, rs: list[RawReading], rate_hz: float
) -> tuple[list[float], int]:
    """:func:`measure` while :data:`RELOADS` SIGHUPs are sent, evenly over the paced part."""
    duration_s = (len(rs) - 200) / rate_hz
    done = threading.Event()
    sent = [0]

    def hup() -> None:
        time.sleep(200 / rate_hz + 0.05)  # after the warm-up
        for _ in range(RELOADS):
            if done.wait(duration_s / (RELOADS + 1)):
                return
            proc.send_signal(signal.SIGHUP)
            sent[0] += 1

    t = threading.Thread(target=hup)
    t.start()
    try:
        return measure(ctl, rs, rate_hz)
    finally:
        done.set()
        t.join()
        if sent[0] < RELOADS:
            print(f"warning: only {sent[0]} of {RELOADS} reloads during the run", file=sys.stderr)


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


def uncertainty_only(grid: Path, rs: list[RawReading], args: Any, tmp: Path) -> int:
    """``--only-uncertainty``: the latency rounds and the floods of ``daemon_mcap`` and
    ``daemon_mcap_u``, interleaved; table and ``results/daemon_uncertainty.json``."""
    cases = ("daemon_mcap", "daemon_mcap_u", "daemon_mcap_u_nosend")
    print("virtual latency …", file=sys.stderr)
    virt = bench_virtual(grid, rs, args.rate, tmp, args.rounds, only=cases)
    print(f"throughput, flood of {args.flood} …", file=sys.stderr)
    sus = bench_throughput(grid, args.flood, tmp, rounds=3, sustain_n=0, cases=cases)
    out = {
        "machine": platform.node(),
        "python": platform.python_version(),
        "rate_hz": args.rate,
        "virtual": virt,
        "throughput_virtual": sus,
        "ratios": {
            "p50": virt["daemon_mcap_u"]["p50"] / virt["daemon_mcap"]["p50"],
            "p99": virt["daemon_mcap_u"]["p99"] / virt["daemon_mcap"]["p99"],
            "readings_per_s": sus["daemon_mcap_u_over_daemon_mcap"],
            "nosend_p50": virt["daemon_mcap_u_nosend"]["p50"] / virt["daemon_mcap"]["p50"],
            "nosend_p99": virt["daemon_mcap_u_nosend"]["p99"] / virt["daemon_mcap"]["p99"],
            "nosend_readings_per_s": sus["daemon_mcap_u_nosend"]["readings_per_s"]
            / sus["daemon_mcap"]["readings_per_s"],
        },
    }
    path = RESULTS.with_name("daemon_uncertainty.json")
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(f"{'virtual, MCAP on (default writer)':<44} {'p50 µs':>8} {'p99 µs':>8} {'n':>6}")
    for name, label in (
        ("daemon_mcap", "grid without U"),
        ("daemon_mcap_u", "grid with U, U sent"),
        ("daemon_mcap_u_nosend", "grid with U, not sent on CAN (logged)"),
    ):
        r = virt[name]
        print(f"{label:<44} {r['p50']:>8.0f} {r['p99']:>8.0f} {r['n']:>6}")
    rt = out["ratios"]
    print(
        f"with U / without: p50 {rt['p50']:.2f}×, p99 {rt['p99']:.2f}× (target ≤ 1.10); "
        f"not sent: p50 {rt['nosend_p50']:.2f}×, p99 {rt['nosend_p99']:.2f}×"
    )
    for name in cases:
        r = sus[name]
        allr = ", ".join(f"{v:.0f}" for v in r["all_readings_per_s"])
        print(
            f"flood {name:<16} best {r['readings_per_s']:.0f} readings/s (all {allr}), "
            f"lost {r['lost']}, unlogged {r.get('answers_not_logged')}"
        )
    print(
        f"throughput with U / without: {rt['readings_per_s']:.2f}× (not sent: "
        f"{rt['nosend_readings_per_s']:.2f}×); wrote {path}"
    )
    return 0


def before_only(grid: Path, rs: list[RawReading], args: Any, tmp: Path) -> int:
    """``--only-before``: the udp_multicast daemon (MCAP on) against the ``--before-tree``
    daemon and the bare echo, ``--rounds`` interleaved rounds (order rotated); the p50 and p99
    ratio now / before of every round (the spread says what is noise), and of the pooled
    latencies. Table and ``results/daemon_before.json``."""
    cases = ["echo", "daemon", "daemon_before", *OTHER_TREES]
    load_start = os.getloadavg()
    chunk = rs[: 200 + args.n]
    per_round: list[dict[str, dict[str, float]]] = []
    pooled: dict[str, list[float]] = {c: [] for c in cases}
    lost: dict[str, int] = dict.fromkeys(cases, 0)
    cpu: dict[str, list[float]] = {c: [] for c in cases}
    internal: dict[str, list[float]] = {c: [] for c in cases if c != "echo"}
    for k in range(args.rounds):
        shift = k % len(cases)
        row: dict[str, dict[str, float]] = {}
        for name in cases[shift:] + cases[:shift]:
            own: list[float] | None = None if name == "echo" else []
            values, n_lost = _udp_round(name, grid, chunk, args.rate, tmp, None, cpu[name], own)
            pooled[name] += values
            lost[name] += n_lost
            row[name] = {**pct(values), "cpu_us_per_reading": cpu[name][-1]}
            if own is not None:
                internal[name] += own
                row[name]["internal_p50"] = float(np.percentile(own, 50))
                row[name]["internal_p90"] = float(np.percentile(own, 90))
        per_round.append(row)
        print(
            f"round {k + 1}/{args.rounds}: p50 now {row['daemon']['p50']:.0f} before "
            f"{row['daemon_before']['p50']:.0f} echo {row['echo']['p50']:.0f} µs; CPU per "
            f"reading now {row['daemon']['cpu_us_per_reading']:.0f} before "
            f"{row['daemon_before']['cpu_us_per_reading']:.0f} µs",
            file=sys.stderr,
        )
    r50 = [r["daemon"]["p50"] / r["daemon_before"]["p50"] for r in per_round]
    r99 = [r["daemon"]["p99"] / r["daemon_before"]["p99"] for r in per_round]
    total = {c: pct(pooled[c]) for c in cases}
    out = {
        "machine": platform.node(),
        "python": platform.python_version(),
        "before_tree": args.before_tree,
        "rate_hz": args.rate,
        "n_per_round": args.n,
        "rounds": per_round,
        "pooled": total,
        "lost": lost,
        "p50_ratio_per_round": r50,
        "p99_ratio_per_round": r99,
        "p50_ratio_median": float(np.median(r50)),
        "p99_ratio_median": float(np.median(r99)),
        "p50_ratio_pooled": total["daemon"]["p50"] / total["daemon_before"]["p50"],
        "p99_ratio_pooled": total["daemon"]["p99"] / total["daemon_before"]["p99"],
        "cpu_us_per_reading_median": {c: float(np.median(cpu[c])) for c in cases},
        "other_trees": dict(OTHER_TREES),
        "internal_us": {
            c: {
                "p50": float(np.percentile(v, 50)),
                "p90": float(np.percentile(v, 90)),
                "p99": float(np.percentile(v, 99)),
            }
            for c, v in internal.items()
        },
        "internal_p50_ratio_per_round": [
            r["daemon"]["internal_p50"] / r["daemon_before"]["internal_p50"] for r in per_round
        ],
        **{
            f"p50_ratio_per_round_{name}_over_before": [
                r[name]["p50"] / r["daemon_before"]["p50"] for r in per_round
            ]
            for name in OTHER_TREES
        },
        **{
            f"p50_ratio_per_round_now_over_{name}": [
                r["daemon"]["p50"] / r[name]["p50"] for r in per_round
            ]
            for name in OTHER_TREES
        },
        "cpu_us_per_reading_with_children_median": {
            c: float(np.median(v)) for c, v in TREE_CPU_US.items()
        },
        "settle_max_s": SETTLE_MAX_S,
        "settle_s_median": {c: float(np.median(v)) for c, v in SETTLE_S.items()},
        "uptime_loadavg_at_start": load_start,
        "uptime_loadavg_at_end": os.getloadavg(),
    }
    path = RESULTS.with_name("daemon_before.json")
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(f"{'udp_multicast, pooled over rounds':<40} {'p50 µs':>8} {'p99 µs':>8} {'n':>6} lost")
    for c in cases:
        r = total[c]
        print(f"{c:<40} {r['p50']:>8.0f} {r['p99']:>8.0f} {r['n']:>6} {lost[c]}")
    print(
        f"now / before p50: median {out['p50_ratio_median']:.3f}× over {len(r50)} rounds "
        f"(min {min(r50):.3f}, max {max(r50):.3f}), pooled {out['p50_ratio_pooled']:.3f}×"
    )
    print(
        f"now / before p99: median {out['p99_ratio_median']:.3f}× "
        f"(min {min(r99):.3f}, max {max(r99):.3f}), pooled {out['p99_ratio_pooled']:.3f}×"
    )
    for name in OTHER_TREES:
        rr = out[f"p50_ratio_per_round_now_over_{name}"]
        print(
            f"now / {name} p50: median {np.median(rr):.3f}× (min {min(rr):.3f}, max "
            f"{max(rr):.3f}); {name} / before: median "
            f"{np.median(out[f'p50_ratio_per_round_{name}_over_before']):.3f}×"
        )
    print(
        "daemon-reported latency (frame completing the reading → status frame encoded), "
        "pooled p50 / p90 µs: "
        + ", ".join(f"{n} {v['p50']:.0f} / {v['p90']:.0f}" for n, v in out["internal_us"].items())
    )
    ri = out["internal_p50_ratio_per_round"]
    print(
        f"daemon-reported p50 now / before: median {np.median(ri):.3f}× (min {min(ri):.3f}, "
        f"max {max(ri):.3f})"
    )
    c = out["cpu_us_per_reading_median"]
    print(
        "CPU per reading of the process (median of rounds, µs): "
        + ", ".join(f"{name} {v:.0f}" for name, v in c.items())
    )
    c = out["cpu_us_per_reading_with_children_median"]
    print(
        "… with its children (MCAP writer, grid worker), µs: "
        + ", ".join(f"{name} {v:.0f}" for name, v in c.items())
    )
    st = out["settle_s_median"]
    print(
        f"settled before measuring (≤ {SETTLE_MAX_S:.0f} s; median s): "
        + ", ".join(f"{name} {v:.1f}" for name, v in st.items())
        + f"; load average at start {load_start[0]:.2f}, at end {os.getloadavg()[0]:.2f}"
    )
    print(f"wrote {path}")
    return 0


def main() -> int:
    global BEFORE_TREE, SETTLE_MAX_S
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=6000, help="paced readings per latency case")
    ap.add_argument("--rate", type=float, default=1000.0, help="pace of latency cases, Hz")
    ap.add_argument("--rounds", type=int, default=6, help="interleaved rounds of the virtual cases")
    ap.add_argument("--flood", type=int, default=50_000, help="readings per throughput round")
    ap.add_argument("--sustain-hz", type=float, default=10_000.0, help="paced throughput case")
    ap.add_argument("--sustain-n", type=int, default=100_000, help="readings of that case")
    ap.add_argument("--modbus-n", type=int, default=2000)
    ap.add_argument("--echo-server", type=int, help=argparse.SUPPRESS)
    ap.add_argument(
        "--settle-max-s",
        type=float,
        default=SETTLE_MAX_S,
        help="udp_multicast: wait (at most this long, s) until the daemon and its children "
        "are quiet before measuring (its start-up over); 0 measures right after the first "
        "heartbeat",
    )
    ap.add_argument(
        "--before-tree",
        default="",
        help="folder holding an older tree's cmm_comp package: adds its daemon to the "
        "udp_multicast rounds (before/after in one run)",
    )
    ap.add_argument(
        "--only-virtual",
        action="store_true",
        help="run only the virtual-bus latency cases (quick check; prints, writes no JSON)",
    )
    ap.add_argument(
        "--only-uncertainty",
        action="store_true",
        help="run only daemon_mcap against daemon_mcap_u (grid with U, U sent): latency "
        "rounds and floods on virtual; writes benchmarks/results/daemon_uncertainty.json",
    )
    ap.add_argument(
        "--other-tree",
        action="append",
        default=[],
        metavar="NAME=DIR",
        help="with --only-before: also run the daemon of this tree (one that knows the grid "
        "trust settings) as case NAME in the same rounds",
    )
    ap.add_argument(
        "--only-before",
        action="store_true",
        help="with --before-tree: only the udp_multicast daemon against that tree's daemon "
        "(and the bare echo), --rounds interleaved rounds of --n readings, per-round ratios; "
        "writes benchmarks/results/daemon_before.json",
    )
    args = ap.parse_args()
    SETTLE_MAX_S = args.settle_max_s
    if args.echo_server:
        echo_main(args.echo_server)
        return 0
    sys.setswitchinterval(0.0005)  # same as the daemon process (cli/daemon.py)
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        grid = tmp / "npl.grid"
        CorrectionGrid.build(machine, steps=machine.volume.steps).save(grid)
        global U_GRID
        U_GRID = build_u_grid(machine, grid, tmp / "npl-u.grid")
        rs = readings(args.n + 200, np.random.default_rng(1))
        if args.only_uncertainty:
            return uncertainty_only(grid, rs, args, tmp)
        if args.only_before:
            if not args.before_tree:
                ap.error("--only-before needs --before-tree")
            BEFORE_TREE = args.before_tree
            for spec in args.other_tree:
                name, _, folder = spec.partition("=")
                OTHER_TREES[name] = folder
            return before_only(grid, rs, args, tmp)
        print("virtual …", file=sys.stderr)
        virt = bench_virtual(grid, rs, args.rate, tmp, args.rounds)
        if args.only_virtual:
            for name in (
                "echo",
                "daemon_no_mcap",
                "daemon_mcap",
                "daemon_mcap_thread",
                "daemon_mcap_u",
            ):
                r = virt[name]
                print(f"{name:<22} p50 {r['p50']:7.0f}  p99 {r['p99']:7.0f}  n {r['n']}")
            return 0
        print("udp_multicast …", file=sys.stderr)
        BEFORE_TREE = args.before_tree
        udp_cases = ("echo", "daemon_no_mcap", "daemon", "daemon_reloads")
        if BEFORE_TREE:
            udp_cases += ("daemon_before",)
        udp = bench_udp(grid, rs, args.rate, tmp, udp_cases, rounds=max(1, args.rounds // 2))
        print(f"throughput, flood of {args.flood} …", file=sys.stderr)
        sus = bench_throughput(
            grid,
            args.flood,
            tmp,
            sustain_hz=args.sustain_hz,
            sustain_n=args.sustain_n,
            cases=("echo", "daemon_mcap", "daemon_no_mcap", "daemon_mcap_u", "sustained"),
        )
        print("modbus …", file=sys.stderr)
        mb = bench_modbus(grid, args.modbus_n)
    result = {
        "machine": platform.node(),
        "python": platform.python_version(),
        "rate_hz": args.rate,
        "virtual": virt,
        "udp_multicast": udp,
        "throughput_virtual": sus,
        "modbus": mb,
        "targets": {
            "uncertainty_p50_ratio": virt["daemon_mcap_u"]["p50"] / virt["daemon_mcap"]["p50"],
            "uncertainty_p99_ratio": virt["daemon_mcap_u"]["p99"] / virt["daemon_mcap"]["p99"],
            "uncertainty_throughput_ratio": sus["daemon_mcap_u_over_daemon_mcap"],
            "virtual_p50_over_echo_us": virt["daemon_mcap"]["p50"] - virt["echo"]["p50"],
            "virtual_p99_over_echo_us": virt["daemon_mcap"]["p99"] - virt["echo"]["p99"],
            "udp_p50_over_echo_us": udp["daemon"]["p50"] - udp["echo"]["p50"],
            "udp_p99_over_echo_us": udp["daemon"]["p99"] - udp["echo"]["p99"],
            "reload_p99_ratio": udp["daemon_reloads"]["p99"] / udp["daemon"]["p99"],
            "throughput_daemon_mcap_over_echo": sus["daemon_mcap_over_echo"],
            "throughput_daemon_mcap_over_no_mcap": sus["daemon_mcap_over_no_mcap"],
            "throughput_readings_per_s": sus["daemon_mcap"]["readings_per_s"],
            "sustained_readings_per_s": sus["sustained"]["readings_per_s"],
            "sustained_lost": sus["sustained"]["all_lost"],
            "sustained_answers_not_logged": sus["sustained"]["all_answers_not_logged"],
            **(
                {
                    "udp_p50_over_before": udp["daemon"]["p50"] / udp["daemon_before"]["p50"],
                    "udp_p99_over_before": udp["daemon"]["p99"] / udp["daemon_before"]["p99"],
                }
                if "daemon_before" in udp
                else {}
            ),
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
        ("udp_multicast: … during 10 SIGHUP reloads", udp["daemon_reloads"]),
        *(
            [("udp_multicast: daemon of --before-tree, MCAP on", udp["daemon_before"])]
            if "daemon_before" in udp
            else []
        ),
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
    print(f"p99 during 10 reloads / without: {t['reload_p99_ratio']:.2f}× (target ≤ 2)")
    if "daemon_before" in udp:
        print(
            f"udp_multicast daemon (MCAP on) / --before-tree daemon, same rounds: p50 "
            f"{t['udp_p50_over_before']:.2f}×, p99 {t['udp_p99_over_before']:.2f}× (target ≤ 1)"
        )
    print(
        f"\n{'throughput, virtual':<46} {'readings/s':>11} {'× echo':>7} {'lost':>5} "
        f"{'unlogged':>8} {'MCAP dropped (frames)':>22}"
    )
    for name, label in (
        ("echo", "bare echo (drain + batch send), unpaced"),
        ("daemon_mcap", "daemon, MCAP on (default writer), unpaced"),
        ("daemon_no_mcap", "daemon, MCAP off, unpaced"),
        ("sustained", f"daemon, MCAP on, paced at {sus['sustain_hz']:.0f}/s"),
    ):
        r = sus[name]
        ratio = r["readings_per_s"] / sus["echo"]["readings_per_s"]
        unlogged = r.get("answers_not_logged", "")
        dropped = r.get("mcap_dropped", "")
        print(
            f"{label:<46} {r['readings_per_s']:>11.0f} {ratio:>7.2f} {r['lost']:>5} "
            f"{unlogged!s:>8} {dropped!s:>22}"
        )
    print(
        f"(best of {sus['rounds']} rounds; all rounds: "
        + "; ".join(
            f"{n} {', '.join(f'{v:.0f}' for v in sus[n]['all_readings_per_s'])}"
            for n in ("echo", "daemon_mcap", "daemon_no_mcap", "sustained")
        )
        + ")"
    )
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
