"""CPU of the daemon's CAN reply path per reading, without any bus or thread wake-ups.

Run: ``.venv/bin/python benchmarks/bench_hotpath.py [--uncertainty-only] [--rounds 5]``. Prints
a table and writes ``benchmarks/results/hotpath.json``; the uncertainty comparison (below) goes
to ``benchmarks/results/hotpath_uncertainty.json``. A stub bus (sends are dropped, nothing is ever received) is
handed to a real :class:`daemon.service.DaemonService`; the frames a simulated controller would
send are fed straight to the endpoint's handler in one thread, so the figures are pure CPU of
decoding, assembling, correcting, answering, counting and (after ``bookkeeping``) building the
MCAP records, µs per reading (3 raw frames), frame by frame (the low-rate case) and in bursts
of 32 readings per wake-up (a drained queue: one vectorised correction, one send batch). The baseline in the same run is the bare
``can.Message`` construction + ``struct`` unpack of the same frames, and the parts are timed on
their own: ``decode_message`` per frame, ``CorrectionEngine.correct`` per reading.

Uncertainty (issue 13): the same reply path with a grid carrying U (``grid build
--uncertainty``) and ``[can] send_uncertainty`` on (U computed per reading, a fifth frame sent)
against the same grid without U (four frames), in interleaved rounds (the order rotated every
round), frame by frame and in bursts of 32, MCAP off and on; ratios of the medians over rounds.
"""

from __future__ import annotations

import argparse
import json
import platform
import struct
import sys
import tempfile
import time
import timeit
from pathlib import Path
from typing import Any

import can
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from bench_daemon import config, readings  # noqa: E402

from cmm_comp.compensation.grid import CorrectionGrid  # noqa: E402
from cmm_comp.compensation.machine import Machine  # noqa: E402
from cmm_comp.daemon.engine import Reading  # noqa: E402
from cmm_comp.daemon.service import DaemonService  # noqa: E402
from cmm_comp.protocol import CanIds, decode_message  # noqa: E402
from cmm_comp.sim_controller.controller import CanController  # noqa: E402
from cmm_comp.sim_controller.sim_machine import Environment  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "hotpath.json"
U_RESULTS = ROOT / "benchmarks" / "results" / "hotpath_uncertainty.json"
N = 6000


class StubBus(can.BusABC):
    """Drops what is sent, never receives (the endpoint's own thread just idles)."""

    def __init__(self, *_: Any, **__: Any) -> None:
        super().__init__(channel="stub")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        time.sleep(timeout or 0.01)
        return None, False

    def shutdown(self) -> None:
        super().shutdown()


class CaptureBus(StubBus):
    """Keeps what a controller sends."""

    def __init__(self) -> None:
        super().__init__()
        self.sent: list[can.Message] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)


def controller_frames(n: int) -> tuple[list[can.Message], list[can.Message]]:
    """Temperature frames and the 3·n raw axis frames of n readings, as the controller sends."""
    bus = CaptureBus()
    ctl = CanController(bus)
    ctl.send_temperatures(Environment().samples(0.0))
    temps = list(bus.sent)
    bus.sent.clear()
    for r in readings(n, np.random.default_rng(1)):
        ctl.send_reading(r)
    bus.shutdown()
    return temps, list(bus.sent)


def per_reading_us(
    grid: Path,
    tmp: Path,
    mcap: str,
    batch: int = 1,
    send_uncertainty: bool = False,
) -> float:
    """µs per reading; ``batch`` readings' frames are handled per wake-up (1: the low-rate
    case, frame by frame; 32: a drained burst, corrected and answered together)."""
    temps, frames = controller_frames(N)
    cfg = config(grid, "stub", mcap)
    cfg.can.send_uncertainty = send_uncertainty
    with DaemonService(cfg, events_stream=None, bus_factory=lambda c, i: StubBus()) as d:
        ep = d.can
        assert ep is not None
        for msg in temps:
            ep._handle(msg, time.perf_counter())
        warm = 600
        for msg in frames[:warm]:
            ep._handle(msg, time.perf_counter())
            ep._answer_ready()
        ep._bookkeeping()
        t0 = time.perf_counter()
        rest = frames[warm:]
        step = 3 * batch
        for i in range(0, len(rest), step):
            for msg in rest[i : i + step]:
                ep._handle(msg, time.perf_counter())
                if batch == 1:
                    ep._answer_ready()  # one frame per wake-up
            ep._answer_ready()
            ep._bookkeeping()  # what the endpoint does once the bus is quiet
        dt = time.perf_counter() - t0
    return dt / ((len(frames) - warm) / 3) * 1e6


def u_grid(machine: Machine, plain: Path, out: Path, trials: int = 300) -> Path:
    """``plain`` (built from ``machine``) carrying U from the virtual CMM, saved at ``out``."""
    from cmm_comp.compensation.uncertainty.grid_field import add_uncertainty

    grid = CorrectionGrid.load(plain)
    add_uncertainty(grid, machine, rng=np.random.default_rng(13), seed=13, trials=trials).save(out)
    return out


U_CASES = (  # name, grid carries U + U sent, MCAP, burst
    ("plain_1", False, False, 1),
    ("u_1", True, False, 1),
    ("plain_32", False, False, 32),
    ("u_32", True, False, 32),
    ("plain_1_mcap", False, True, 1),
    ("u_1_mcap", True, True, 1),
)


def bench_uncertainty(machine: Machine, grid: Path, tmp: Path, rounds: int) -> dict[str, Any]:
    """The reply path with a grid carrying U and U sent against the same grid without U:
    :data:`U_CASES` in ``rounds`` interleaved rounds; medians and their ratios."""
    ugrid = u_grid(machine, grid, tmp / "npl-u.grid")
    runs: dict[str, list[float]] = {name: [] for name, *_ in U_CASES}
    for k in range(rounds):
        order = list(U_CASES[k % len(U_CASES) :] + U_CASES[: k % len(U_CASES)])
        for name, with_u, mcap, batch in order:
            path = str(tmp / f"{name}-{k}.mcap") if mcap else ""
            g = ugrid if with_u else grid
            runs[name].append(per_reading_us(g, tmp, path, batch, with_u))
    med = {name: float(np.median(v)) for name, v in runs.items()}
    out: dict[str, Any] = {"rounds": rounds, "readings_per_run": N, "runs_us": runs}
    out["median_us"] = med
    for tag in ("1", "32", "1_mcap"):
        out[f"ratio_{tag}"] = med[f"u_{tag}"] / med[f"plain_{tag}"]
        out[f"ratio_{tag}_per_round"] = [
            u / p for u, p in zip(runs[f"u_{tag}"], runs[f"plain_{tag}"], strict=True)
        ]
    return out


def print_uncertainty(u: dict[str, Any]) -> None:
    med = u["median_us"]
    print(
        f"\nreply path per reading, grid with U + U sent vs the same grid without U "
        f"(median of {u['rounds']} interleaved rounds)"
    )
    print(f"{'case':<40} {'no U µs':>8} {'U µs':>8} {'ratio':>6}  per round")
    for tag, label in (
        ("1", "frame by frame, MCAP off"),
        ("32", "bursts of 32 per wake-up, MCAP off"),
        ("1_mcap", "frame by frame, MCAP on (process)"),
    ):
        per = ", ".join(f"{r:.2f}" for r in u[f"ratio_{tag}_per_round"])
        print(
            f"{label:<40} {med[f'plain_{tag}']:>8.1f} {med[f'u_{tag}']:>8.1f} "
            f"{u[f'ratio_{tag}']:>6.2f}  {per}"
        )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds of the U cases")
    ap.add_argument("--uncertainty-only", action="store_true", help="run only the U comparison")
    args = ap.parse_args()
    sys.setswitchinterval(0.0005)
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    if args.uncertainty_only:
        with tempfile.TemporaryDirectory() as tmpd:
            tmp = Path(tmpd)
            grid = tmp / "npl.grid"
            CorrectionGrid.build(machine, steps=machine.volume.steps).save(grid)
            u = bench_uncertainty(machine, grid, tmp, args.rounds)
        write_uncertainty(u)
        print_uncertainty(u)
        return 0
    _, frames = controller_frames(2000)
    ids = CanIds()
    unpack = struct.Struct("<5sHB").unpack
    msg = frames[1000]
    n = 50_000
    base_us = timeit.timeit(lambda: unpack(bytes(msg.data)), number=n) / n * 1e6
    decode_us = timeit.timeit(lambda: decode_message(msg, ids), number=n) / n * 1e6
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        grid = tmp / "npl.grid"
        CorrectionGrid.build(machine, steps=machine.volume.steps).save(grid)
        off = per_reading_us(grid, tmp, "")
        on = per_reading_us(grid, tmp, str(tmp / "p.mcap"))
        off_32 = per_reading_us(grid, tmp, "", batch=32)
        on_32 = per_reading_us(grid, tmp, str(tmp / "p32.mcap"), batch=32)
        u = bench_uncertainty(machine, grid, tmp, args.rounds)
        cfg = config(grid, "stub", "")
        with DaemonService(cfg, events_stream=None, bus_factory=lambda c, i: StubBus()) as d:
            temps, _ = controller_frames(1)
            assert d.can is not None and d.engine is not None
            for m in temps:
                d.can._handle(m, time.perf_counter())
            r = Reading(1, (300_000_000, 400_000_000, 200_000_000))
            eng = d.engine
            assert eng.correct(r).status.label == "ok"
            correct_us = timeit.timeit(lambda: eng.correct(r), number=20_000) / 20_000 * 1e6
    result = {
        "machine": platform.node(),
        "python": platform.python_version(),
        "struct_unpack_baseline_us": base_us,
        "decode_message_us": decode_us,
        "engine_correct_us": correct_us,
        "reading_mcap_off_us": off,
        "reading_mcap_process_us": on,
        "reading_mcap_off_burst32_us": off_32,
        "reading_mcap_process_burst32_us": on_32,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    rows = [
        ("bare struct unpack of one frame (baseline)", base_us),
        ("decode_message, one raw axis frame", decode_us),
        ("CorrectionEngine.correct, one reading", correct_us),
        ("reply path + bookkeeping per reading, MCAP off", off),
        ("… MCAP on, process writer (default)", on),
        ("… bursts of 32 readings per wake-up, MCAP off", off_32),
        ("… bursts of 32 readings per wake-up, MCAP on", on_32),
    ]
    print(f"{'case':<52} {'µs':>8}")
    for name, v in rows:
        print(f"{name:<52} {v:>8.1f}")
    print(f"decode / baseline: {decode_us / base_us:.1f}×; wrote {RESULTS}")
    write_uncertainty(u)
    print_uncertainty(u)
    return 0


def write_uncertainty(u: dict[str, Any]) -> None:
    out = {"machine": platform.node(), "python": platform.python_version(), **u}
    U_RESULTS.parent.mkdir(parents=True, exist_ok=True)
    U_RESULTS.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {U_RESULTS}")


if __name__ == "__main__":
    sys.exit(main())
