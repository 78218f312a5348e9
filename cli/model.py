"""``cmm-comp`` subcommands of the model layer: map, diagonals, line, report, iso230.

Each ``cmd_*`` takes parsed arguments and returns an exit code; problems with the user's files
raise :class:`CmmCompError` (or ``ValueError``), which the top-level CLI prints as one line.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .common import Subparsers, load_machine, progress_printer, temps_from_args, write_json_atomic


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("machine", type=Path, help="machine description (machine.toml)")
    p.add_argument(
        "--probe",
        nargs=3,
        type=float,
        metavar=("XP", "YP", "ZP"),
        help="stylus offset, mm (default: the machine's)",
    )
    p.add_argument("--temp-x", type=float, metavar="C", help="X scale temperature, °C")
    p.add_argument("--temp-y", type=float, metavar="C", help="Y scale temperature, °C")
    p.add_argument("--temp-z", type=float, metavar="C", help="Z scale temperature, °C")
    p.add_argument("--temp-wp", type=float, metavar="C", help="workpiece temperature, °C")


def cmd_map(args: argparse.Namespace) -> int:
    import numpy as np

    from cmm_comp.compensation.reports.maps import volumetric_map

    machine = load_machine(args.machine)
    vmap = volumetric_map(
        machine, args.steps, args.probe, temps_from_args(args), progress_printer("map")
    )
    vmap.write_csv(args.out)
    if args.plot:
        from cmm_comp.compensation.reports.plots import plot_vector_map

        plot_vector_map(vmap, args.plot, args.magnification, title=machine.name)
    peak = float(np.max(np.linalg.norm(vmap.error_um, axis=1)))
    print(
        f"{machine.name}: {len(vmap.points_mm)} nodes {vmap.steps}, peak error {peak:.2f} µm → {args.out}"
    )
    return 0


def cmd_diagonals(args: argparse.Namespace) -> int:
    from cmm_comp.compensation.reports.maps import diagonal_endpoints, diagonals_um

    machine = load_machine(args.machine)
    diag = diagonals_um(machine, args.probe, temps_from_args(args))
    ends = diagonal_endpoints(machine)
    out = {
        "diagonals_um": diag,
        "endpoints_mm": [[a.tolist(), b.tolist()] for a, b in ends],
        "convention": "length error = true − indicated length, µm",
    }
    if args.json:
        write_json_atomic(args.json, out)
    if args.plot:
        from cmm_comp.compensation.reports.plots import plot_diagonals

        plot_diagonals(machine, diag, args.plot)
    for n, (v, (a, b)) in enumerate(zip(diag, ends, strict=True), start=1):
        print(f"diagonal {n}: {a.tolist()} → {b.tolist()}: {v:+.2f} µm")
    return 0


def cmd_line(args: argparse.Namespace) -> int:
    from cmm_comp.compensation.reports.maps import line_report

    machine = load_machine(args.machine)
    report = line_report(
        machine, args.axis, args.through, args.samples, args.probe, temps_from_args(args)
    )
    if args.out:
        report.write_csv(args.out)
    if args.plot:
        from cmm_comp.compensation.reports.plots import plot_line

        plot_line(report, args.plot, title=machine.name)
    s = report.summary()
    print(
        f"line ∥ {args.axis.upper()} through {args.through}: bandwidth {s['bandwidth_um']:.2f} µm, "
        f"max {s['max_um']:.2f} µm; components (pv) "
        + ", ".join(f"{k} {v:.2f}" for k, v in s["component_bandwidth_um"].items())
    )
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    """Everything people look at, in one directory: map CSV, diagonals JSON, line CSV, PNG plots."""
    import numpy as np

    from cmm_comp.compensation.reports.maps import diagonals_um, line_report, volumetric_map
    from cmm_comp.compensation.reports.plots import (
        plot_diagonals,
        plot_line,
        plot_parametric_errors,
        plot_vector_map,
    )

    machine = load_machine(args.machine)
    out: Path = args.out
    temps = temps_from_args(args)
    vmap = volumetric_map(machine, args.steps, args.probe, temps, progress_printer("map"))
    out.mkdir(parents=True, exist_ok=True)  # after the checks: a refused run leaves no directory
    vmap.write_csv(out / "map.csv")
    plot_vector_map(vmap, out / "map.png", args.magnification, title=machine.name)
    plot_parametric_errors(machine, out / "parametric_errors.png")
    diag = diagonals_um(machine, args.probe, temps)
    plot_diagonals(machine, diag, out / "diagonals.png")
    centre = (machine.volume.lower_mm + machine.volume.upper_mm) / 2
    centre[0] = machine.volume.lower_mm[0]
    line = line_report(machine, "x", centre, stylus_mm=args.probe, temps_C=temps)
    line.write_csv(out / "line_x.csv")
    plot_line(line, out / "line_x.png", title=machine.name)
    summary = {
        "machine": machine.name,
        "model": machine.model,
        "steps": list(vmap.steps),
        "peak_error_um": float(np.max(np.linalg.norm(vmap.error_um, axis=1))),
        "diagonals_um": diag,
        "line_x": line.summary(),
    }
    if vmap.random_um is not None:
        summary["peak_random_um"] = [float(v) for v in vmap.random_um.max(axis=0)]
    write_json_atomic(out / "summary.json", summary)
    print(json.dumps(summary, indent=2))
    print(
        f"wrote {out}/: map.csv map.png parametric_errors.png diagonals.png line_x.csv line_x.png summary.json"
    )
    return 0


def cmd_iso230(args: argparse.Namespace) -> int:
    """Evaluate an ISO 230-2 run (key=value .dat file) and print/plot the standard's values."""
    from cmm_comp.compensation.formats.realdata import read_iso230_dat
    from cmm_comp.compensation.reports.iso230 import format_iso230_report, plot_iso230

    run = read_iso230_dat(args.dat)
    result = run.evaluate()
    print(format_iso230_report(result, title=str(args.dat.name)))
    if args.json:
        write_json_atomic(args.json, result.to_dict())
    if args.plot:
        plot_iso230(result, args.plot, title=str(args.dat.name))
    return 0


def cmd_import_seed(args: argparse.Namespace) -> int:
    """Load a data set kept in the paper's file layout (NAME S/R + .CTL, .DPX …) → machine.toml."""
    from cmm_comp.compensation.formats.seedfiles import find_seed_machines, load_seed_fileset

    if args.name is None:
        names = find_seed_machines(args.directory)
        if len(names) != 1:
            raise ValueError(
                f"{args.directory}: name the machine to import; found {names or 'no .CTL file'}"
            )
        args.name = names[0]
    machine = load_seed_fileset(args.directory, args.name)
    machine.to_toml(args.out)
    print(f"{machine.name} ({machine.model}): {len(machine.tables)} tables → {args.out}")
    return 0


def cmd_export_seed(args: argparse.Namespace) -> int:
    """Write a machine description as the paper's file set (for legacy tools)."""
    from cmm_comp.compensation.formats.seedfiles import write_seed_fileset

    machine = load_machine(args.machine)
    written = write_seed_fileset(machine, args.directory, args.name)
    print(f"wrote {len(written)} files to {args.directory}")
    return 0


def add_parsers(sub: Subparsers) -> None:
    """Register this layer's subcommands on the top-level parser."""
    p = sub.add_parser("map", help="volumetric error at every node of the working volume (CSV)")
    _add_common(p)
    p.add_argument("--out", type=Path, required=True, help="CSV x,y,z,ex,ey,ez[,rx,ry,rz]")
    p.add_argument("--steps", nargs=3, type=int, metavar=("NX", "NY", "NZ"))
    p.add_argument("--plot", type=Path, help="also write the 3-D vector map as PNG")
    p.add_argument("--magnification", type=float, help="plot magnification (default: automatic)")
    p.set_defaults(handler=cmd_map)

    p = sub.add_parser("diagonals", help="length errors along the 4 space diagonals")
    _add_common(p)
    p.add_argument("--json", type=Path, help='write {"diagonals_um": [d1, d2, d3, d4]}')
    p.add_argument("--plot", type=Path, help="bar chart PNG")
    p.set_defaults(handler=cmd_diagonals)

    p = sub.add_parser("line", help="ΔX, ΔY, ΔZ and resultant along a line parallel to an axis")
    _add_common(p)
    p.add_argument("--axis", choices=("x", "y", "z"), required=True)
    p.add_argument("--through", nargs=3, type=float, required=True, metavar=("X", "Y", "Z"))
    p.add_argument("--samples", type=int, default=101)
    p.add_argument("--out", type=Path, help="CSV of the line")
    p.add_argument("--plot", type=Path, help="PNG of the line")
    p.set_defaults(handler=cmd_line)

    p = sub.add_parser(
        "report", help="map, diagonals, line and plots of a machine in one directory"
    )
    _add_common(p)
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--steps", nargs=3, type=int, metavar=("NX", "NY", "NZ"))
    p.add_argument("--magnification", type=float)
    p.set_defaults(handler=cmd_report)

    p = sub.add_parser(
        "import-seed", help="convert a seed-paper file set (NAME.CTL, NAMES.DPX …) to TOML"
    )
    p.add_argument("directory", type=Path)
    p.add_argument("name", nargs="?", help="machine specification name (default: the only one)")
    p.add_argument("-o", "--out", type=Path, required=True, help="machine.toml to write")
    p.set_defaults(handler=cmd_import_seed)

    p = sub.add_parser("export-seed", help="write a machine as a seed-paper file set")
    p.add_argument("machine", type=Path)
    p.add_argument("directory", type=Path)
    p.add_argument("name", help="machine specification name (≤ 7 letters/digits)")
    p.set_defaults(handler=cmd_export_seed)

    p = sub.add_parser("iso230", help="evaluate an ISO 230-2 run (.dat key=value file)")
    p.add_argument("dat", type=Path)
    p.add_argument("--json", type=Path)
    p.add_argument("--plot", type=Path)
    p.set_defaults(handler=cmd_iso230)
