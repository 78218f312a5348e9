"""``cmm-comp diagnose`` and ``cmm-comp extend`` (docs/formats.md §4).

Register with :func:`add_parsers` (each subparser sets ``handler``). Bad input files give one
message naming the file, line and column on stderr, write nothing and return exit code 2.
"""

from __future__ import annotations

import argparse
import json
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
        from cmm_comp.compensation.diagnosis.words import verdict_line

        write_json_atomic(Path(args.json), diagnosis.to_json())  # standard JSON, else refused
        from cmm_comp.compensation.diagnosis.report import write_report

        if args.report:
            write_report(diagnosis, args.report, title=f"Diagnosis of {args.machine}")
        print(verdict_line(diagnosis))
        return 0

    return _run(args, action)


def _annotated_toml(machine: Any, notes: dict[int, str]) -> str:
    """The machine's TOML with a comment line before the ``[[effects]]`` tables in ``notes``
    (index among the machine's effects → text)."""
    import tomli_w

    text = tomli_w.dumps(json.loads(json.dumps(machine.description)))
    out: list[str] = []
    k = -1
    for line in text.splitlines(keepends=True):
        if line.strip() == "[[effects]]":
            k += 1
            if k in notes:
                out.append(f"# {notes[k]}\n")
        out.append(line)
    return "".join(out)


def cmd_extend(args: argparse.Namespace) -> int:
    """``extend MACHINE MEASUREMENTS -o EXTENDED.toml [--include-either]``: the machine with the
    machine's effects found (``source: machine``); ``either`` ones only on request, with a
    comment; the reference instrument's never."""

    def action(diagnosis: Any) -> int:
        from cmm_comp.compensation.formats.atomic import write_text_atomic

        added = diagnosis.machine_effects(args.include_either)
        extended = diagnosis.residuals.machine.with_effects(added)
        either = {id(e) for e in diagnosis.either_machine}
        either |= {
            id(e)
            for e, s in zip(diagnosis.effects, diagnosis.sources, strict=True)
            if s == "either"
        }
        first = len(extended.effects) - len(added)
        notes = {
            first + i: (
                f"{e.cause} ({e.describe().get('axis') or e.describe().get('component', '')}): "
                "either the machine's or the reference instrument's — this session cannot tell "
                "which; added by --include-either"
            )
            for i, e in enumerate(added)
            if id(e) in either
        }
        out = Path(args.output)
        write_text_atomic(out, _annotated_toml(extended, notes))  # nothing written on failure
        print(f"{out}: {len(added)} effect(s) added")
        for e, source in zip(diagnosis.effects, diagnosis.sources, strict=True):
            what = f"{e.cause} ({e.describe().get('axis') or e.describe().get('component', '')})"
            if e in added:
                continue
            if source == "reference":
                print(f"  not added: {what}: the reference instrument's, not the machine's")
            elif source == "either" and not args.include_either:
                print(
                    f"  not added: {what}: the session cannot tell whether the machine or the "
                    "reference carries it (--include-either adds it)"
                )
            elif not e.compensable:
                print(
                    f"  not added: {what}: it describes this session but cannot be predicted "
                    "at run time; log the temperature that drives it and diagnose again"
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
    e.add_argument(
        "--include-either",
        action="store_true",
        help="also add the effects the session cannot assign to the machine or the reference "
        "(each with a comment in the TOML)",
    )
    e.set_defaults(handler=cmd_extend)
