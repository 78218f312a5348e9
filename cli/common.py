"""Helpers shared by the ``cmm-comp`` command groups: loading, progress, atomic output.

Imports nothing heavy at module level: ``cmm-comp --help`` must start fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from cmm_comp.compensation import Machine

__all__ = [
    "Subparsers",
    "fail",
    "load_machine",
    "progress_printer",
    "temps_from_args",
    "write_json_atomic",
    "write_text_atomic",
]


class Subparsers(Protocol):
    """What a command group needs of ``ArgumentParser.add_subparsers()``'s result (whose class
    argparse keeps private): a new subcommand parser."""

    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser:
        """The parser of subcommand ``name`` (``help``, ``description`` … as argparse takes)."""
        ...


def fail(message: str) -> int:
    """Print ``cmm-comp: MESSAGE`` on stderr and return exit code 2 (bad input)."""
    print(f"cmm-comp: {message}", file=sys.stderr)
    return 2


def load_machine(path: str | Path) -> Machine:
    """Load a machine description and print its load warnings to stderr (one line each)."""
    from cmm_comp.compensation import Machine

    machine = Machine.from_toml(path)
    for warning in machine.warnings:
        print(f"cmm-comp: warning: {warning}", file=sys.stderr)
    return machine


def progress_printer(label: str) -> Callable[[float], None]:
    """A progress callback printing ``label: NN %`` to stderr (only on a terminal)."""
    last = [-1]

    def report(fraction: float) -> None:
        pct = int(fraction * 100)
        if pct != last[0] and sys.stderr.isatty():
            last[0] = pct
            end = "\n" if pct >= 100 else ""
            print(f"\r{label}: {pct:3d} %", end=end, file=sys.stderr, flush=True)

    return report


def temps_from_args(args: argparse.Namespace) -> dict[str, float] | None:
    """``--temp-x/-y/-z/-wp`` flags as a ``temps_C`` mapping (°C), or None when none is given."""
    temps = {
        name: value
        for name, value in (
            ("T_x", getattr(args, "temp_x", None)),
            ("T_y", getattr(args, "temp_y", None)),
            ("T_z", getattr(args, "temp_z", None)),
            ("T_wp", getattr(args, "temp_wp", None)),
        )
        if value is not None
    }
    for name, value in temps.items():
        if not -273.15 <= value <= 1000.0:  # also NaN; inf made every figure inf or NaN
            flag = {"T_x": "--temp-x", "T_y": "--temp-y", "T_z": "--temp-z", "T_wp": "--temp-wp"}
            raise ValueError(
                f"{flag[name]} {value}: not a temperature (a finite number in -273.15…1000 °C)"
            )
    return temps or None


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically: a failed run leaves the previous file intact."""
    from cmm_comp.compensation.formats.atomic import write_text_atomic as write

    write(path, text)


def write_json_atomic(path: str | Path, data: Any) -> None:
    """``data`` as indented JSON, written atomically (see :func:`write_text_atomic`)."""
    try:  # standard JSON only: NaN/Infinity are refused, the previous file is kept
        text = json.dumps(data, indent=2, default=float, allow_nan=False)
    except ValueError:
        raise ValueError(
            f"{path}: a figure to write is not a finite number; nothing written"
        ) from None
    write_text_atomic(path, text + "\n")
