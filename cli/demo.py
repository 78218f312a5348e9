"""``cmm-comp demo``: simulated controller → daemon over a python-can ``virtual`` bus, in one process.

Builds the grid from ``examples/machines/npl-bridge.toml`` unless one is given, starts a
:class:`DaemonService` on a fresh virtual channel (MCAP log on), runs the ISO 10360-2 length
test, a ball plate and random points through :class:`sim_controller.CanController`, and
returns the summary of docs/formats.md §3 (``readings``, ``corrected``, ``e0_before_um``,
``e0_after_um``, ``latency_us.p50/p99``) plus detail figures. Lives in the CLI because it wires both sides:
the daemon never imports the simulator, and the simulator never imports the daemon.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .common import fail

if TYPE_CHECKING:
    from cmm_comp.daemon import DaemonConfig

SUMMARY_KEYS = ("readings", "corrected", "e0_before_um", "e0_after_um", "latency_us")


def default_machine_path() -> Path:
    """``examples/machines/npl-bridge.toml`` of this checkout (FileNotFoundError if absent)."""
    path = Path(__file__).resolve().parents[1] / "examples" / "machines" / "npl-bridge.toml"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: demo machine not found; pass --machine MACHINE.toml")
    return path


def demo_config(
    grid_path: str,
    channel: str,
    mcap_path: str,
    stylus_mm: list[float],
    machine_path: str = "",
    public_key: str = "",
) -> DaemonConfig:
    """Daemon configuration of the demo: virtual CAN, no Modbus, no metrics port.

    The grid the demo builds is signed with ``public_key`` and bound to ``machine_path``. A grid
    the user brings (no key) may be unsigned and built from another description than the
    simulated true machine (a model of it): both are allowed, explicitly.
    """
    from cmm_comp.daemon import DaemonConfig

    cfg = DaemonConfig(source="<demo>")
    cfg.grid.path = grid_path
    cfg.grid.stylus_mm = list(stylus_mm)
    cfg.grid.machine = machine_path
    cfg.grid.public_key = public_key
    cfg.grid.allow_unsigned = not public_key
    cfg.grid.allow_any_machine = not machine_path
    cfg.can.interface = "virtual"
    cfg.can.channel = channel
    cfg.mcap.path = mcap_path
    cfg.metrics.enabled = False
    return cfg.check()


def run_demo(
    machine_path: str | Path | None = None,
    grid_path: str | Path | None = None,
    mcap_path: str | Path | None = None,
    n_random: int = 500,
    seed: int = 0,
    noise_um: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the demo; return the summary (docs/formats.md keys first, then details)."""
    import can
    import numpy as np

    from cmm_comp.compensation import CorrectionGrid, Machine
    from cmm_comp.compensation.grid import generate_signing_key, sign_grid
    from cmm_comp.daemon import DaemonService
    from cmm_comp.sim_controller.controller import CanController
    from cmm_comp.sim_controller.runner import build_program, evaluate, make_readings, run_can
    from cmm_comp.sim_controller.sim_machine import Environment, SimulatedMachine

    say = progress or (lambda _msg: None)
    t_start = time.perf_counter()
    machine_path = Path(machine_path or default_machine_path())
    machine = Machine.from_toml(machine_path)
    public_key = bound_machine = ""
    stylus = [float(v) for v in machine.probe.offset_mm]
    with tempfile.TemporaryDirectory(prefix="cmm-demo-") as tmp:
        if grid_path is None:
            steps = machine.volume.steps or (19, 23, 16)
            say(f"building grid for {machine.name} ({steps[0]}×{steps[1]}×{steps[2]} nodes)…")
            grid = CorrectionGrid.build(machine, steps=steps)
            # next to the session log, so ``cmm-comp replay`` finds it; else temporary
            keep = Path(mcap_path).with_suffix(".grid") if mcap_path is not None else None
            grid_path = keep or Path(tmp) / f"{machine.name}.grid"
            grid.save(grid_path)
            # signed with a key made for this run, as a production grid would be
            private_key, public = generate_signing_key(Path(tmp) / "keys")
            sign_grid(grid_path, private_key)
            public_key, bound_machine = str(public), str(machine_path)
        mcap = Path(mcap_path) if mcap_path is not None else Path(tmp) / "demo.mcap"
        if mcap.exists():
            mcap.unlink()
        channel = f"cmm-demo-{uuid.uuid4().hex[:8]}"
        cfg = demo_config(str(grid_path), channel, str(mcap), stylus, bound_machine, public_key)
        rng = np.random.default_rng(seed)
        program = build_program(machine.volume.lower_mm, machine.volume.upper_mm, rng, n_random)
        env = Environment()
        sim = SimulatedMachine(machine, stylus, noise_um, rng)
        say(f"simulating {len(program.points)} probe points on the true machine…")
        indicated, readings = make_readings(sim, env, program.points)
        with DaemonService(cfg, events_stream=None) as daemon:
            bus = can.Bus(interface="virtual", channel=channel)
            try:
                with CanController(bus) as ctl:
                    say(f"daemon ready ({daemon.state.state.label}); probing over virtual CAN…")
                    answers = run_can(
                        ctl,
                        readings,
                        env,
                        progress=lambda i, n: say(f"  {i}/{n} readings answered"),
                    )
                    errors = list(ctl.errors)
            finally:
                bus.shutdown()
        result = evaluate(program, indicated, answers)
        result["controller_errors"] = [repr(e) for e in errors]
        result["mcap"] = str(mcap) if mcap_path is not None else ""
        result["grid"] = str(grid_path)
        result["elapsed_s"] = time.perf_counter() - t_start
    return result


def summary_json(result: dict[str, Any]) -> dict[str, Any]:
    """Exactly the docs/formats.md §3 keys."""
    return {
        "readings": int(result["readings"]),
        "corrected": int(result["corrected"]),
        "e0_before_um": round(float(result["e0_before_um"]), 4),
        "e0_after_um": round(float(result["e0_after_um"]), 4),
        "latency_us": {
            "p50": round(float(result["latency_us"]["p50"]), 1),
            "p99": round(float(result["latency_us"]["p99"]), 1),
        },
    }


def format_table(result: dict[str, Any]) -> str:
    """Human-readable summary table."""
    rows = [
        ("readings", f"{result['readings']}"),
        ("corrected (status ok)", f"{result['corrected']}"),
        ("E0 before compensation", f"{result['e0_before_um']:.2f} µm"),
        ("E0 after compensation", f"{result['e0_after_um']:.2f} µm"),
    ]
    if "ball_plate_max_um" in result:
        bp = result["ball_plate_max_um"]
        rows.append(
            ("ball plate, max distance error", f"{bp['before']:.2f} → {bp['after']:.2f} µm")
        )
    if "random_rms_um" in result:
        rr = result["random_rms_um"]
        rows.append(("random points, RMS 3-D error", f"{rr['before']:.2f} → {rr['after']:.2f} µm"))
    lat = result["latency_us"]
    rows.append(("latency p50 / p99", f"{lat['p50']:.0f} / {lat['p99']:.0f} µs"))
    rows.append(("statuses", ", ".join(f"{k}={v}" for k, v in sorted(result["statuses"].items()))))
    if result.get("mcap"):
        rows.append(("session log (MCAP)", result["mcap"]))
    rows.append(("elapsed", f"{result['elapsed_s']:.1f} s"))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def add_parsers(subparsers: Any) -> None:
    """Register ``demo`` on an argparse subparsers object."""
    p = subparsers.add_parser(
        "demo",
        help="simulated controller → daemon over a virtual CAN bus; E0 before/after",
        description="Run the ISO 10360-2 length test, a ball plate and random points on a "
        "simulated machine through the daemon (python-can virtual bus, one process).",
    )
    p.add_argument("--mcap", metavar="PATH", help="write the session log here (overwritten)")
    p.add_argument("--json", metavar="SUMMARY", help="write the summary JSON here")
    p.add_argument("--machine", help="machine.toml (default examples/machines/npl-bridge.toml)")
    p.add_argument("--grid", help="use this grid instead of building one from the machine")
    p.add_argument("--random", type=int, default=500, help="random points (default 500)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(handler=cmd_demo)


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the demo, print the summary table, write the JSON summary."""
    from cmm_comp.compensation import CmmCompError

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"[demo] {msg}", file=sys.stderr, flush=True)

    try:
        result = run_demo(
            machine_path=args.machine,
            grid_path=args.grid,
            mcap_path=args.mcap,
            n_random=args.random,
            seed=args.seed,
            progress=progress,
        )
    except (CmmCompError, FileNotFoundError, ValueError) as exc:
        return fail(str(exc))
    print(format_table(result))
    if args.json:
        Path(args.json).write_text(json.dumps(summary_json(result), indent=2) + "\n")
    if result["controller_errors"]:
        print(f"controller errors: {result['controller_errors']}", file=sys.stderr)
        return 1
    return 0
