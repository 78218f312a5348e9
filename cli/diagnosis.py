"""``cmm-comp diagnose`` and ``cmm-comp extend`` (docs/formats.md §4).

Register with :func:`add_parsers` (each subparser sets ``handler``). Bad input files give one
message naming the file, line and column on stderr, write nothing and return exit code 2.
"""

from __future__ import annotations

import argparse
import json
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
