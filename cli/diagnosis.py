"""``cmm-comp diagnose`` and ``cmm-comp extend`` (docs/formats.md §4).

Register with :func:`add_parsers` (each subparser sets ``handler``). Bad input files give one
message naming the file, line and column on stderr, write nothing and return exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cmm_comp.compensation.errors import CmmCompError

from .common import load_machine, write_json_atomic


def run_diagnosis(
    machine_path: str | Path,
    measurements_path: str | Path,
    *,
    warn: Callable[[str], None] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Any:
    """Load ``machine_path`` and ``measurements_path`` and diagnose: what ``cmm-comp diagnose``
    runs, and each task of ``cmm-comp fleet diagnose``. ``warn`` receives the machine's load
    warnings (default: printed to stderr). Raises :class:`CmmCompError`/``OSError`` for a file
    that cannot be read and ``ValueError`` (prefixed by the measurements file) for data the
    diagnosis refuses."""
    from cmm_comp.compensation import Machine
    from cmm_comp.compensation.diagnosis import diagnose
    from cmm_comp.compensation.formats.measurements import read_measurements

    if warn is None:
        machine = load_machine(machine_path)
    else:
        machine = Machine.from_toml(machine_path)
        for warning in machine.warnings:
            warn(warning)
    data = read_measurements(measurements_path)
    try:
        return diagnose(machine, data, progress=progress)
    except ValueError as exc:
        raise _RefusedData(f"{measurements_path}: {exc}") from None


class _RefusedData(CmmCompError, ValueError):
    """The diagnosis refused the data (message names the measurements file)."""


def _run(args: argparse.Namespace, action: Any) -> int:

    def progress(line: str) -> None:
        print(f"cmm-comp {args.command}: {line}", file=sys.stderr, flush=True)

    try:
        diagnosis = run_diagnosis(args.machine, args.measurements, progress=progress)
    except (CmmCompError, OSError, _RefusedData) as exc:
        print(f"cmm-comp {args.command}: {exc}", file=sys.stderr)
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
