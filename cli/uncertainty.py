"""``cmm-comp uncertainty MACHINE --points P.csv | --volume NX NY NZ | --length X1 Y1 Z1 X2 Y2 Z2 |
--e0-test | --sphere X Y Z R | --plane X Y Z UX UY UZ VX VY VZ`` (docs/formats.md §3,
docs/uncertainty.md): the virtual CMM's U of corrected points and of measurement tasks.

Imports nothing heavy at module level (``cmm-comp --help`` stays numpy-free). Progress goes to
stderr (on a terminal); results to CSV/JSON/PNG, written atomically; a bad input is one line.
"""

from __future__ import annotations

import argparse
import csv
import io
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .common import Subparsers, load_machine, temps_from_args, write_json_atomic, write_text_atomic

if TYPE_CHECKING:
    from cmm_comp.compensation import Machine
    from cmm_comp.compensation.uncertainty import MonteCarloSettings, PointUncertainty

__all__ = ["add_parsers", "assumption_lines", "cmd_uncertainty", "print_assumptions"]

_POINT_COLUMNS = (
    "Ux_um", "Uy_um", "Uz_um",
    "U95x_um", "U95y_um", "U95z_um",
    "lowx_um", "lowy_um", "lowz_um", "highx_um", "highy_um", "highz_um",
    "gum_ux_um", "gum_uy_um", "gum_uz_um",
)  # fmt: skip


def _progress(label: str) -> Any:
    """A ``progress(trials, worst)`` callback writing one refreshed line on a terminal."""

    def report(trials: int, worst: float) -> None:
        if sys.stderr.isatty():
            stab = "…" if math.isnan(worst) else f"{worst:.2f}"
            print(
                f"\r{label}: {trials} trials, stability 2s/δ = {stab} (≤ 1 to stop)   ",
                end="",
                file=sys.stderr,
                flush=True,
            )

    return report


_TABLE_KEYS = ("u", "u_per_m", "u_relative", "correlation_mm")


def assumption_lines(
    defaulted: Sequence[str], zero: Sequence[str], label: Callable[[str], str] = str
) -> list[str]:
    """What an uncertainty statement assumed, for the terminal: every input ``defaulted``
    (``uncertainty.errors.dx_x.u`` …) grouped by kind, and every component taken as exactly
    ``zero``; error components named by ``label`` (the machine file's own names)."""
    tables: dict[str, list[str]] = {}
    groups: dict[str, list[str]] = {}
    for name in defaulted:
        parts = name.split(".")
        if len(parts) == 4 and parts[1] == "errors":
            tables.setdefault(parts[2], []).append(parts[3])
        elif len(parts) == 3:
            groups.setdefault(parts[1], []).append(parts[2])
        else:
            groups.setdefault("", []).append(parts[-1])
    lines = []
    if defaulted:
        lines.append(
            f"{len(defaulted)} uncertainty input(s) not in [uncertainty], defaulted "
            "(values: docs/uncertainty.md §2):"
        )
        by_keys: dict[tuple[str, ...], list[str]] = {}
        for comp, keys in tables.items():
            ordered = tuple(k for k in _TABLE_KEYS if k in keys) + tuple(
                k for k in keys if k not in _TABLE_KEYS
            )
            by_keys.setdefault(ordered, []).append(label(comp))
        for key_set, comps in by_keys.items():
            lines.append(f"  {', '.join(key_set)} of {len(comps)} table(s): {', '.join(comps)}")
        for group, names in groups.items():
            lines.append(f"  {group}: {', '.join(names)}" if group else f"  {', '.join(names)}")
    if zero:
        lines.append(
            f"taken as exactly zero (no table, no [uncertainty.errors.<name>]): "
            f"{', '.join(label(c) for c in zero)}; give [uncertainty.errors.<name>] u = … for "
            "an error that was never measured"
        )
    return lines


def print_assumptions(
    defaulted: Sequence[str],
    zero: Sequence[str],
    label: Callable[[str], str] = str,
    *,
    where: str,
) -> None:
    """:func:`assumption_lines` on stderr as ``cmm-comp: note:`` lines (all also in ``where``)."""
    lines = assumption_lines(defaulted, zero, label)
    if lines:
        lines[-1] += f" (all in {where})"
    for line in lines:
        print(f"cmm-comp: note: {line}", file=sys.stderr)


def _end_progress() -> None:
    if sys.stderr.isatty():
        print(file=sys.stderr)


def _settings(args: argparse.Namespace, default_ndig: int) -> MonteCarloSettings:
    from cmm_comp.compensation.uncertainty import MonteCarloSettings

    ndig = args.ndig if args.ndig is not None else default_ndig
    try:
        return MonteCarloSettings(
            probability=args.probability,
            trials=args.trials,
            ndig=ndig,
            tolerance=args.tolerance_um,
            batch=args.batch,
            max_trials=args.max_trials,
        )
    except ValueError as exc:
        raise ValueError(f"uncertainty: {exc}") from None


def _mode_flags(args: argparse.Namespace) -> list[str]:
    given = [
        name
        for name, value in (
            ("--points", args.points),
            ("--volume", args.volume),
            ("--length", args.length),
            ("--e0-test", args.e0_test or None),
            ("--sphere", args.sphere),
            ("--plane", args.plane),
        )
        if value is not None
    ]
    if len(given) != 1:
        raise ValueError(
            "uncertainty: give exactly one of --points, --volume, --length, --e0-test, "
            f"--sphere, --plane (got {', '.join(given) or 'none'})"
        )
    return given


def _finite(values: list[float], what: str) -> list[float]:
    bad = [v for v in values if not math.isfinite(v)]
    if bad:
        raise ValueError(f"uncertainty: {what} must be finite numbers, got {values}")
    return values


def cmd_uncertainty(args: argparse.Namespace) -> int:
    """Run the virtual CMM for one task and write what was asked for."""
    import numpy as np

    (mode,) = _mode_flags(args)
    machine = load_machine(args.machine)
    model = machine.uncertainty_model()
    if not args.quiet:
        print_assumptions(model.defaulted, model.zero, machine.error_label, where="the JSON output")
    seed = args.seed
    rng = np.random.default_rng(seed)
    temps = temps_from_args(args)
    stylus = _finite(list(args.probe), "--probe") if args.probe is not None else None
    if mode in ("--points", "--volume"):
        return _points_mode(args, machine, rng, temps, stylus, mode)
    from .uncertainty_tasks import task_mode

    return task_mode(args, machine, rng, temps, stylus, mode)


def _points_input(
    args: argparse.Namespace,
    machine: Machine,
    temps: dict[str, float] | None,
    stylus: list[float] | None,
    mode: str,
) -> tuple[list[str], list[list[str]], Any, Any, dict[str, Any] | None, Any, list[Any] | None]:
    """The points of ``--points`` (CSV) or ``--volume`` (a grid over the machine's volume, mm):
    ``(header, rows, points_mm, stylus_mm, signals, inputs, axes)``; ``axes`` only for a volume."""
    import numpy as np

    from .grid import read_points_csv

    if mode == "--points":
        header, rows, cols = read_points_csv(Path(args.points))
        if not rows:
            raise ValueError(f"{args.points}: no points")
        pts = np.c_[cols["x"], cols["y"], cols["z"]]
        sty: Any = stylus
        if all(c in cols for c in ("px", "py", "pz")):
            sty = np.c_[cols["px"], cols["py"], cols["pz"]]
        signals: dict[str, Any] = dict(temps or {})
        signals.update({k: v for k, v in cols.items() if k.startswith("T_")})
        inputs = {k: v for k, v in cols.items() if k.startswith("dir_")} or None
        return header, rows, pts, sty, signals, inputs, None
    steps = args.volume
    if any(s < 2 or s > 200 for s in steps):
        raise ValueError(f"uncertainty: --volume needs 2…200 nodes per axis, got {steps}")
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    axes = [np.linspace(lo[k], hi[k], steps[k]) for k in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    rows = [[f"{v:.6f}" for v in p] for p in pts]
    return ["x", "y", "z"], rows, pts, stylus, temps, None, axes


def _points_summary(
    args: argparse.Namespace,
    machine: Machine,
    temps: dict[str, float] | None,
    pts: Any,
    signals: dict[str, Any] | None,
    result: PointUncertainty,
    axes: list[Any] | None,
) -> dict[str, Any]:
    """The ``--json`` summary of a points/volume run, with the first-order budget at the point
    of largest U (µm)."""
    import numpy as np

    ok = result.status == "ok"
    mc = result.mc
    summary: dict[str, Any] = {
        "task": "points" if axes is None else "volume",
        "machine": machine.name,
        "points": len(pts),
        "ok": int(ok.sum()),
        "stylus_mm": result.stylus_mm[0].tolist() if len(pts) else None,
        "temperatures_C": temps or {},
        "seed": args.seed,
        "U_k2_um": _stats(result.U_um[ok]),
        "U95_zero_centred_um": _stats(result.U95_um[ok]),
        "gum_vs_monte_carlo_u_ratio": _ratio(result.gum_u_um, result.u_um, ok),
        "monte_carlo": None if mc is None else mc.info(),
        "uncertainty_model": result.model,
    }
    if axes is not None:
        summary["steps"] = [len(a) for a in axes]
    if ok.any():
        from cmm_comp.compensation.uncertainty import uncertainty_budget

        worst = int(np.flatnonzero(ok)[np.argmax(np.max(result.U_um[ok], axis=1))])
        sub_t = {
            k: np.atleast_1d(v)[worst if np.ndim(v) else 0] for k, v in (signals or {}).items()
        }
        budget = uncertainty_budget(machine, pts[worst], result.stylus_mm[worst], sub_t or None)
        summary["budget_first_order_at_largest_U"] = {
            "point_mm": pts[worst].tolist(),
            "u_um_by_input": {k: v[0].tolist() for k, v in budget.items()},
        }
    return summary


def _points_mode(
    args: argparse.Namespace,
    machine: Machine,
    rng: Any,
    temps: dict[str, float] | None,
    stylus: list[float] | None,
    mode: str,
) -> int:
    import numpy as np

    from cmm_comp.compensation.uncertainty import point_uncertainty

    header, rows, pts, sty, signals, inputs, axes = _points_input(
        args, machine, temps, stylus, mode
    )
    result = point_uncertainty(
        machine,
        pts,
        sty,
        signals or None,
        inputs,
        rng=rng,
        settings=_settings(args, default_ndig=1),
        progress=_progress("uncertainty"),
    )
    _end_progress()
    ok = result.status == "ok"
    mc = result.mc
    if args.out is not None:
        _write_points_csv(Path(args.out), header, rows, result)
    if args.json is not None:
        write_json_atomic(
            args.json, _points_summary(args, machine, temps, pts, signals, result, axes)
        )
    if args.plot is not None:
        from cmm_comp.compensation.uncertainty.plots import plot_points_u, plot_volume_u

        if axes is not None:
            u_grid = result.U_um.reshape(len(axes[0]), len(axes[1]), len(axes[2]), 3)
            plot_volume_u(
                axes, u_grid, args.plot, title=f"{machine.name}: U (k = 2) over the volume"
            )
        else:
            plot_points_u(pts, result.U_um, args.plot, title=f"{machine.name}: U (k = 2)")
    u = result.U_um[ok]
    trials = "" if mc is None else f", {mc.trials} trials{_stability(mc, args)}"
    if u.size:
        print(
            f"{int(ok.sum())}/{len(pts)} points ok{trials}: U (k = 2) x {np.max(u[:, 0]):.3g}, "
            f"y {np.max(u[:, 1]):.3g}, z {np.max(u[:, 2]):.3g} µm at most"
        )
    else:
        print(f"0/{len(pts)} points ok: nothing to evaluate (see the status column)")
    _warn_if_unstable(mc, args)
    return 0


def _stability(mc: Any, args: argparse.Namespace) -> str:
    if args.trials is not None:
        return " (a fixed number: no stopping rule)"
    return ", stable (JCGM 101 §7.9)" if mc.stable else ", NOT stable"


def _warn_if_unstable(mc: Any, args: argparse.Namespace) -> None:
    """One line on stderr when the adaptive Monte Carlo stopped at --max-trials unstable."""
    if mc is not None and not mc.stable and args.trials is None:
        worst = (
            f"worst 2s/δ = {mc.worst:.2f}"
            if math.isfinite(mc.worst)
            else "a single run: its stability cannot be measured"  # was printed as 'nan'
        )
        print(
            "cmm-comp: warning: the Monte Carlo did not stabilise within --max-trials "
            f"({mc.trials}); {worst}",
            file=sys.stderr,
        )


def _write_points_csv(
    path: Path, header: list[str], rows: list[list[str]], result: PointUncertainty
) -> None:
    buf = io.StringIO(newline="")
    writer = csv.writer(buf)
    writer.writerow([*header, *_POINT_COLUMNS, "status"])
    arrays = (result.U_um, result.U95_um, result.low_um, result.high_um, result.gum_u_um)
    for i, row in enumerate(rows):
        cells = []
        for arr in arrays:
            assert arr is not None
            cells += ["" if not math.isfinite(v) else f"{v:.4f}" for v in arr[i]]
        writer.writerow([*row, *cells, str(result.status[i])])
    write_text_atomic(path, buf.getvalue())


def _stats(values: Any) -> dict[str, float] | None:
    import numpy as np

    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return None
    return {
        "max": float(v.max()),
        "mean": float(v.mean()),
        "min": float(v.min()),
        "max_x": float(v[:, 0].max()),
        "max_y": float(v[:, 1].max()),
        "max_z": float(v[:, 2].max()),
    }


def _ratio(gum: Any, mc: Any, ok: Any) -> dict[str, float] | None:
    import numpy as np

    if gum is None or not ok.any():
        return None
    g, m = np.asarray(gum)[ok], np.asarray(mc)[ok]
    keep = m > 0
    if not keep.any():
        return None
    r = g[keep] / m[keep]
    return {"min": float(r.min()), "max": float(r.max())}


def add_parsers(sub: Subparsers) -> None:
    """Add ``uncertainty`` to the ``cmm-comp`` subcommands. Long on purpose: one flat list of the
    subcommand's flags, in the order ``--help`` prints them."""
    p = sub.add_parser(
        "uncertainty",
        help="virtual CMM: U of corrected points and of measurement tasks (Monte Carlo)",
        description="The virtual CMM (ISO/TS 15530-4, JCGM 101 Monte Carlo): draws machines "
        "consistent with the machine's [uncertainty] model and reports U of what the "
        "correction leaves (docs/uncertainty.md).",
    )
    p.add_argument("machine", type=Path, help="machine description (machine.toml)")
    task = p.add_argument_group("the task (exactly one)")
    task.add_argument(
        "--points", type=Path, metavar="POINTS.csv", help="points (x,y,z[,px,py,pz][,T_x…])"
    )
    task.add_argument(
        "--volume",
        nargs=3,
        type=int,
        metavar=("NX", "NY", "NZ"),
        help="U at the nodes of a grid over the volume",
    )
    task.add_argument(
        "--length",
        nargs=6,
        type=float,
        metavar=("X1", "Y1", "Z1", "X2", "Y2", "Z2"),
        help="a length between two points, mm",
    )
    task.add_argument(
        "--e0-test", action="store_true", help="the ISO 10360-2 E0 test (105 lengths)"
    )
    task.add_argument(
        "--sphere",
        nargs=4,
        type=float,
        metavar=("X", "Y", "Z", "R"),
        help="a sphere's centre from probing points, mm",
    )
    task.add_argument("--plane", nargs=9, type=float, metavar=("X", "Y", "Z", "UX", "UY", "UZ", "VX", "VY", "VZ"), help="the flatness of a plane: corner and two edges, mm")  # fmt: skip
    p.add_argument(
        "--sphere-points",
        type=int,
        default=25,
        help="probing points on the sphere (25: ISO 10360-5)",
    )
    p.add_argument("--plane-points", type=int, default=5, help="points per edge of the plane")
    p.add_argument(
        "--mpe",
        nargs=2,
        type=float,
        metavar=("A_UM", "K"),
        help="E0,MPE = A + L/K µm (L mm): probability of passing",
    )
    p.add_argument(
        "--probe",
        nargs=3,
        type=float,
        metavar=("XP", "YP", "ZP"),
        help="stylus offset, mm (default [probe] offset)",
    )
    for axis in ("x", "y", "z"):
        p.add_argument(
            f"--temp-{axis}",
            type=float,
            metavar="C",
            help=f"{axis.upper()} scale temperature as read, °C",
        )
    p.add_argument("--temp-wp", type=float, metavar="C", help="workpiece temperature as read, °C")
    mc = p.add_argument_group("Monte Carlo (JCGM 101)")
    mc.add_argument("--seed", type=int, default=0, help="random seed (default 0: reproducible)")
    mc.add_argument("--trials", type=int, help="a fixed number of trials (no stopping rule)")
    mc.add_argument(
        "--ndig",
        type=int,
        help="significant digits of u the result must be stable to (default 2; 1 for "
        "--points/--volume/--e0-test)",
    )
    mc.add_argument(
        "--tolerance-um", type=float, help="numerical tolerance of u in µm (instead of --ndig)"
    )
    mc.add_argument(
        "--batch", type=int, help="trials per run (default max(J, 10⁴), fewer for many points)"
    )
    mc.add_argument(
        "--max-trials", type=int, default=1_000_000, help="stop here even if not stable"
    )
    mc.add_argument(
        "--probability", type=float, default=0.95, help="coverage probability (default 0.95)"
    )
    out = p.add_argument_group("output")
    out.add_argument("--out", type=Path, help="CSV of U per point (--points, --volume)")
    out.add_argument("--json", type=Path, help="JSON summary")
    out.add_argument(
        "--plot", type=Path, help="PNG: U over the volume / at the points, or histograms"
    )
    out.add_argument("--quiet", action="store_true", help="no notes about defaulted inputs and components taken as zero")  # fmt: skip
    p.set_defaults(handler=cmd_uncertainty)
