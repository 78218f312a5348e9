"""``cmm-comp export``: the machine's model as a controller's own compensation tables.

``cmm-comp export MACHINE --format sinumerik-cec|twincat-cnc|linuxcnc [--tool X Y Z] -o DIR``
writes the controller files, ``export.json`` (what is left after the control's own
interpolation, and why), ``export.png`` and ``export.html`` into DIR (docs/export.md); with
``--check-table`` only the one-table sign check of the format (and its instructions,
``check-table.txt``). Bad input is one error line, exit 2, nothing written; an existing non-empty
DIR is not touched without ``--force``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import Subparsers, load_machine

FORMATS = ("sinumerik-cec", "twincat-cnc", "linuxcnc")


def cmd_export(args: argparse.Namespace) -> int:
    from cmm_comp.compensation.export import ExportOptions, describe, export_tables
    from cmm_comp.compensation.export.report import write_export

    out: Path = args.output
    if out.exists() and not out.is_dir():
        raise ValueError(f"-o {out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not args.force:
        raise ValueError(
            f"-o {out}: the directory is not empty (pass --force to overwrite its files)"
        )
    machine = load_machine(args.machine)
    opts = ExportOptions()
    for name in ("points", "max_points", "max_tables"):
        value = getattr(args, name)
        if value is not None:
            setattr(opts, name, value)
    opts.products = bool(args.products)
    opts.invert_sign = bool(args.invert_sign)
    if args.cec_max_sum_mm is not None:
        opts.cec_max_sum_mm = args.cec_max_sum_mm
    if args.eval_steps is not None:
        opts.eval_steps = tuple(args.eval_steps)
    if args.linuxcnc_type is not None:
        opts.linuxcnc_file_type = args.linuxcnc_type
    if args.axis_names is not None:
        opts.cec_axis_names = tuple(args.axis_names)
        opts.twincat_axis_names = tuple(args.axis_names)
    if args.axis_numbers is not None:
        opts.twincat_axis_numbers = tuple(args.axis_numbers)
        opts.linuxcnc_joints = tuple(args.axis_numbers)
    if args.check_table:
        return _write_check(args, machine, opts, out)

    def progress(line: str) -> None:
        print(f"cmm-comp export: {line}", file=sys.stderr, flush=True)

    result = export_tables(machine, args.format, args.tool, opts, progress=progress)
    write_export(result, machine, out)
    for line in describe(result):
        print(line)
    print(
        f"wrote {out}/: {', '.join(result.report['files'])}, export.json, export.png, export.html"
    )
    return 0


def _write_check(args: argparse.Namespace, machine: Any, opts: Any, out: Path) -> int:
    """``--check-table``: the check files, check-table.json, and the instructions printed."""
    import json

    from cmm_comp.compensation.export import check_tables, validate_axes
    from cmm_comp.compensation.formats.atomic import write_text_atomic

    validate_axes(args.format, opts)
    cec = args.format == "sinumerik-cec"
    result = check_tables(
        machine,
        args.format,
        input_axis="xyz".index(args.check_axes[0]),
        output_axis="xyz".index(args.check_axes[1]),
        axis_names=opts.cec_axis_names if cec else opts.twincat_axis_names,
        axis_numbers=opts.twincat_axis_numbers,
        products=opts.products,
    )
    out.mkdir(parents=True, exist_ok=True)
    for name, text in result.files.items():
        write_text_atomic(out / name, text)
    write_text_atomic(out / "check-table.json", json.dumps(result.report, indent=2) + "\n")
    print(result.text, end="")
    print(f"wrote {out}/: {', '.join(sorted(result.files))}, check-table.json")
    return 0


def add_parsers(sub: Subparsers) -> None:
    """Register ``export`` on the top-level parser. Long on purpose: one flat list of the
    subcommand's flags, in the order ``--help`` prints them."""
    p = sub.add_parser(
        "export",
        help="write the model as a controller's compensation tables (SINUMERIK CEC, TwinCAT, LinuxCNC)",
        description="Fit the compensation tables a controller can hold to the machine's model over "
        "the working volume, write them, and report what is left after the control's own "
        "interpolation (docs/export.md).",
    )
    p.add_argument(
        "machine", type=Path, help="machine description (machine.toml, or one from extend)"
    )
    p.add_argument("--format", required=True, choices=FORMATS)
    p.add_argument(
        "--tool",
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        help="tool/stylus offset the tables are for, mm (default: the machine's probe offset)",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite files in a non-empty directory")
    p.add_argument("--points", type=int, help="points per table (default: one per ~10 mm, ≥ 11)")
    p.add_argument(
        "--max-points",
        type=int,
        help="points a table may hold on your control (defaults: CEC 200 = MD18342 on an 828D, "
        "TwinCAT 1001, LinuxCNC 256)",
    )
    p.add_argument("--max-tables", type=int, help="sinumerik-cec: CEC tables available (default 8)")
    p.add_argument(
        "--products",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="sinumerik-cec: carry two-axis terms with $AN_CEC_MULT_BY_TABLE products, in "
        "Siemens' example semantics (not verified: run the product check first; default: none)",
    )
    p.add_argument(
        "--invert-sign",
        action="store_true",
        help="write the unverified sign negated (CEC values, TwinCAT cross corrections): only "
        "after --check-table showed the opposite of the documented reading",
    )
    p.add_argument(
        "--check-table",
        action="store_true",
        help="write only the sign check (one table with a known 0.010 mm step) and what a dial "
        "indicator must show; with --products also the product check (sinumerik-cec)",
    )
    p.add_argument(
        "--check-axes",
        nargs=2,
        choices=("x", "y", "z"),
        default=("y", "x"),
        metavar=("IN", "OUT"),
        help="--check-table: input and output axis of the check table (default y x)",
    )
    p.add_argument(
        "--cec-max-sum-mm",
        type=float,
        help="sinumerik-cec: MD32720 $MA_CEC_MAX_SUM of your control, mm (default 1)",
    )
    p.add_argument(
        "--axis-names",
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="controller axis names (CEC default AX1 AX2 AX3; TwinCAT X Y Z)",
    )
    p.add_argument(
        "--axis-numbers",
        nargs=3,
        type=int,
        metavar=("X", "Y", "Z"),
        help="TwinCAT logical axis numbers (default 1 2 3) / LinuxCNC joints (default 0 1 2)",
    )
    p.add_argument("--linuxcnc-type", type=int, choices=(0, 1), help="COMP_FILE_TYPE (default 0)")
    p.add_argument(
        "--eval-steps",
        nargs=3,
        type=int,
        metavar=("NX", "NY", "NZ"),
        help="grid the residual is measured on (default 41 41 21)",
    )
    p.set_defaults(handler=cmd_export)
