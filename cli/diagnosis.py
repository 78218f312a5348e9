"""``cmm-comp diagnose`` and ``cmm-comp extend`` (docs/formats.md §4).

Register with :func:`add_parsers` (each subparser sets ``handler``). Bad input files give one
message naming the file, line and column on stderr, write nothing and return exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import load_machine, write_json_atomic


def _load(args: argparse.Namespace) -> tuple[Any, Any]:
    from cmm_comp.compensation.formats.measurements import read_measurements

    machine = load_machine(args.machine)
    data = read_measurements(args.measurements)
    return machine, data


def _run(args: argparse.Namespace, action: Any) -> int:
    from cmm_comp.compensation import CmmCompError
    from cmm_comp.compensation.diagnosis import diagnose

    try:
        machine, data = _load(args)
    except (CmmCompError, OSError) as exc:
        print(f"cmm-comp {args.command}: {exc}", file=sys.stderr)
        return 2

    def progress(line: str) -> None:
        print(f"cmm-comp {args.command}: {line}", file=sys.stderr, flush=True)

    try:
        diagnosis = diagnose(machine, data, progress=progress)
    except ValueError as exc:
        print(f"cmm-comp {args.command}: {args.measurements}: {exc}", file=sys.stderr)
        return 2
    return action(diagnosis)


def cmd_diagnose(args: argparse.Namespace) -> int:
    """``diagnose MACHINE MEASUREMENTS --json OUT [--report DIR]``: exit 0 found or not."""

    def action(diagnosis: Any) -> int:
        write_json_atomic(Path(args.json), diagnosis.to_json())  # standard JSON, else refused
        from cmm_comp.compensation.diagnosis.report import display_label, write_report

        if args.report:
            write_report(diagnosis, args.report, title=f"Diagnosis of {args.machine}")
        machine = diagnosis.residuals.machine
        print(
            f"verdict: {diagnosis.verdict}; "
            + ", ".join(
                display_label(e.get("label", e["cause"]), machine) for e in diagnosis.entries
            )
            + f"; held-out RMS {diagnosis.summary['heldout_rms_um']['before']:.3f} → "
            f"{diagnosis.summary['heldout_rms_um']['after']:.3f} µm"
        )
        return 0

    return _run(args, action)


def cmd_extend(args: argparse.Namespace) -> int:
    """``extend MACHINE MEASUREMENTS -o EXTENDED.toml``: the machine with the effects found."""

    def action(diagnosis: Any) -> int:
        extended = diagnosis.extended_machine()
        out = Path(args.output)
        extended.to_toml(out)  # atomic: nothing is written on failure
        added = [e for e in diagnosis.effects if e.compensable]
        print(f"{out}: {len(added)} effect(s) added")
        for e in diagnosis.effects:
            if not e.compensable:
                print(
                    f"  not added: {e.cause} ({e.describe().get('axis', '')}): it describes this "
                    "session but cannot be predicted at run time; log the temperature that "
                    "drives it and diagnose again"
                )
        return 0

    return _run(args, action)


def add_parsers(subparsers: Any) -> None:
    """Add ``diagnose`` and ``extend`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "diagnose", help="compare the model with measurements and name the causes of the misfit"
    )
    p.add_argument("machine", help="machine.toml")
    p.add_argument("measurements", help="measurements.csv (docs/formats.md §2)")
    p.add_argument("--json", required=True, help="output JSON (docs/formats.md §4)")
    p.add_argument("--report", help="directory for PNG plots and index.html")
    p.set_defaults(handler=cmd_diagnose)
    e = subparsers.add_parser("extend", help="write the machine extended by the effects found")
    e.add_argument("machine", help="machine.toml")
    e.add_argument("measurements", help="measurements.csv (docs/formats.md §2)")
    e.add_argument("-o", "--output", required=True, help="extended machine.toml")
    e.set_defaults(handler=cmd_extend)
