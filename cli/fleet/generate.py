"""``cmm-comp fleet generate``: a simulated fleet to try ``fleet diagnose`` and ``fleet replay`` on.

Measurement sessions come from :mod:`cmm_comp.sim_controller.fleet` (machines × dates, the
default slow changes of :func:`~cmm_comp.sim_controller.fleet.default_fleet`). With ``--logs``
each machine also gets a grid built from its description (``ROOT/<machine>/grid/<machine>.grid``)
and, per date and shift, a daemon session log ``ROOT/<machine>/<date>/shift-<k>.mcap``: the
simulated controller probing the machine *as it truly is that day* through the real daemon over
a virtual CAN bus (the wiring of ``cmm-comp demo``, :func:`cmm_comp.cli.demo.run_demo`).
Lives in the CLI because it wires the simulator and the daemon together.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from datetime import date
from pathlib import Path
from typing import Any

from ..common import fail

__all__ = ["add_generate_parser", "cmd_generate", "write_logs"]


def add_generate_parser(sub: Any) -> None:
    """Register ``fleet generate`` on the ``fleet`` subparsers."""
    g = sub.add_parser(
        "generate",
        help="write a simulated fleet (sessions, optionally daemon logs) with slow changes",
        description="Write ROOT/<machine>/<date>/machine.toml + measurements.csv for N "
        "machines × D dates; cmm-02's squareness alpha creeps, the last machine's X reversal "
        "appears on the middle date, cmm-03 (of ≥ 4) has a constant cyclic Y error. What was "
        "injected: ROOT/fleet-truth.json.",
    )
    g.add_argument("root", metavar="ROOT")
    g.add_argument("--machine", help="description every machine starts from (default: demo's)")
    g.add_argument("--machines", type=int, default=4, help="number of machines (≥ 3)")
    g.add_argument("--dates", type=int, default=12, help="sessions per machine (≥ 4)")
    g.add_argument("--start", default="2026-01-05", help="first date (YYYY-MM-DD)")
    g.add_argument("--every-days", type=int, default=7, help="days between sessions")
    g.add_argument("--points", type=int, default=400, help="points per session")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--logs", action="store_true", help="also write daemon session logs")
    g.add_argument("--shifts", type=int, default=1, help="logs per machine and date (--logs)")
    g.add_argument("--readings", type=int, default=50, help="random points per log (--logs)")
    g.add_argument(
        "--grid-steps",
        type=int,
        nargs=3,
        default=(7, 8, 5),
        metavar=("NX", "NY", "NZ"),
        help="nodes of each machine's grid (--logs; default 7 8 5)",
    )
    g.add_argument("--force", action="store_true", help="write into a ROOT that is not empty")
    g.set_defaults(handler=cmd_generate)


def write_logs(
    root: Path,
    spec: Any,
    shifts: int,
    readings: int,
    grid_steps: tuple[int, int, int],
    say: Any,
) -> list[Path]:
    """Per machine a grid of its description, per date and shift a daemon session log of the
    true machine of that date (module docstring); returns the log paths."""
    from cmm_comp.compensation import CorrectionGrid

    from ..demo import run_demo

    logs: list[Path] = []
    with tempfile.TemporaryDirectory(prefix="cmm-fleet-") as tmp:
        for machine in spec.machines:
            grid_path = root / machine / "grid" / f"{machine}.grid"
            grid_path.parent.mkdir(parents=True, exist_ok=True)
            CorrectionGrid.build(spec.description(machine), steps=grid_steps).save(grid_path)
            for day in spec.dates:
                truth = Path(tmp) / f"{machine}-{day.isoformat()}.toml"
                spec.truth_on(machine, day).to_toml(truth)
                for shift in range(1, shifts + 1):
                    log = root / machine / day.isoformat() / f"shift-{shift}.mcap"
                    log.parent.mkdir(parents=True, exist_ok=True)
                    seed = int(spec.rng(machine, day, stream=shift).integers(2**31))
                    result = run_demo(truth, grid_path, log, n_random=readings, seed=seed)
                    if result["controller_errors"]:
                        raise RuntimeError(f"{log}: {result['controller_errors'][0]}")
                    logs.append(log)
                    say(f"{log.relative_to(root)}: {result['readings']} readings")
    return logs


def cmd_generate(args: argparse.Namespace) -> int:
    """Write the fleet; print what was injected."""
    from cmm_comp.compensation import CmmCompError, Machine
    from cmm_comp.sim_controller.fleet import default_fleet, write_fleet

    from ..demo import default_machine_path

    root = Path(args.root)
    if root.exists() and any(root.iterdir()) and not args.force:
        return fail(f"fleet generate: {root} is not empty (--force writes into it)")
    try:
        start = date.fromisoformat(args.start)
    except ValueError:
        return fail(f"fleet generate: --start {args.start!r}: expected YYYY-MM-DD")
    try:
        model = Machine.from_toml(args.machine or default_machine_path())
        spec = default_fleet(
            model,
            args.machines,
            args.dates,
            start=start,
            every_days=args.every_days,
            n_points=args.points,
            seed=args.seed,
        )
    except (CmmCompError, ValueError, FileNotFoundError) as exc:
        return fail(f"fleet generate: {exc}")

    def progress(i: int, n: int) -> None:
        if sys.stderr.isatty():
            print(f"\rfleet generate: {i}/{n} sessions", end="", file=sys.stderr, flush=True)

    write_fleet(root, spec, progress)
    if sys.stderr.isatty():
        print(file=sys.stderr)
    n_logs = 0
    if args.logs:

        def say(line: str) -> None:
            print(f"fleet generate: {line}", file=sys.stderr, flush=True)

        n_logs = len(write_logs(root, spec, args.shifts, args.readings, args.grid_steps, say))
    print(
        f"{root}: {len(spec.machines)} machines × {len(spec.dates)} dates "
        f"({spec.dates[0]} … {spec.dates[-1]}), {n_logs} session logs; injected:"
    )
    for change in spec.changes:
        c = change.as_dict()
        rate = f", per day {json.dumps(c['per_day'])}" if c["per_day"] else ""
        print(
            f"  {c['machine']}: {c['cause']} {json.dumps(c['keys'])} {c['kind']} from {c['start']}{rate}"
        )
    return 0
