"""The line grammar of the paper's data files (see :mod:`.seedfiles` for the layout): file
names, keywords, one parsed file, and the index of a directory. Values as written in the files
(positions mm, linear errors µm, angles µrad).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import MachineFileError
from ..parametric_errors import AXES

__all__ = [
    "CRITERIA",
    "CTL_KEYS",
    "DATA_KEYS",
    "EXTENSIONS",
    "SPEC_NAME_RE",
    "SQUARENESS_EXT",
    "TABLE_EXT",
    "THERMAL_EXT",
    "SeedFile",
    "index_seed_files",
    "parse_seed_file",
]

#: Machine specification name: 1–7 letters or digits (paper section 3.1).
SPEC_NAME_RE = re.compile(r"^[A-Za-z0-9]{1,7}$")

#: Parametric-error extensions → our component names (paper section 3.1).
EXTENSIONS: dict[str, str] = {
    "DPX": "dx_x",
    "DPY": "dy_y",
    "DPZ": "dz_z",
    **{f"D{i.upper()}{a.upper()}": f"d{i}_{a}" for a in AXES for i in AXES if i != a},
    **{f"E{i.upper()}{a.upper()}": f"e{i}_{a}" for a in AXES for i in AXES},
    "ALP": "alpha",
    "BT1": "beta1",
    "BT2": "beta2",
    "THX": "thermal_x",
    "THY": "thermal_y",
    "THZ": "thermal_z",
}
TABLE_EXT = {ext: c for ext, c in EXTENSIONS.items() if c[0] in "de" and c[2] == "_"}
SQUARENESS_EXT = {"ALP": "alpha", "BT1": "beta1", "BT2": "beta2"}
THERMAL_EXT = {"THX": "x", "THY": "y", "THZ": "z"}
_FILE_RE = re.compile(r"^([A-Za-z0-9]{1,7})([SRsr])\.([A-Za-z0-9]{3})$")
CTL_KEYS = {
    "MACHINE",
    "TITLE",
    "EXAMINER",
    "ENVIRONMENT",
    "DATE",
    "NOTE",
    "TYPE",
    "INITIAL",
    "FINAL",
    "STEPS",
    "STEPSIZE",
    "REFERENCE",
    "PROBE",
    "PROBE_RANDOM",
    "TREF",
    "WORKPIECE_EXPANSION",
    "WORKPIECE_FIXTURE",
    "PHI1",
    "PHI2",
}
DATA_KEYS = {
    "MACHINE",
    "TYPE",
    "OFFSET",
    "CRITERION",
    "POLYNOMIAL",
    "BAND",
    "VALUE",
    "UNIT",
    "NOTE",
}
CRITERIA = ("least_squares", "end_points", "min_zone")
_TEXT_KEYS = {"MACHINE", "TITLE", "EXAMINER", "ENVIRONMENT", "DATE", "NOTE", "TYPE", "CRITERION"}


# --------------------------------------------------------------------------- parsing one file
@dataclass
class SeedFile:
    """One parsed file: header keywords (with their line numbers) and ``(line, numbers)`` rows."""

    path: Path
    header: dict[str, tuple[int, list[str]]] = field(default_factory=dict)
    rows: list[tuple[int, list[float]]] = field(default_factory=list)

    def fail(self, line: int | None, problem: str) -> MachineFileError:
        return MachineFileError(str(self.path), f"line {line}" if line else "", problem)

    def text(self, key: str) -> str | None:
        if key not in self.header:
            return None
        return " ".join(self.header[key][1])

    def numbers(self, key: str, count: int | None = None) -> list[float] | None:
        if key not in self.header:
            return None
        line, fields = self.header[key]
        out = [_number(f, self, line) for f in fields]
        if count is not None and len(out) != count:
            raise self.fail(line, f"{key} needs {count} numbers, got {len(out)}")
        if not out:
            raise self.fail(line, f"{key} needs at least one number")
        return out


def _number(text: str, f: SeedFile, line: int) -> float:
    try:
        value = float(text)
    except ValueError:
        raise f.fail(line, f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise f.fail(line, f"expected a finite number, got {text!r}")
    return value


def _split(line: str) -> list[str]:
    for mark in "#!;":
        line = line.split(mark, 1)[0]
    return [t for t in re.split(r"[,\s]+", line.strip()) if t]


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def parse_seed_file(path: Path, allowed: set[str]) -> SeedFile:
    f = SeedFile(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise f.fail(None, f"cannot read the file ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            raise f.fail(None, "not an ASCII/UTF-8 text file") from None
    for n, line in enumerate(text.splitlines(), start=1):
        tokens = _split(line)
        if not tokens:
            continue
        if _is_number(tokens[0]):
            f.rows.append((n, [_number(t, f, n) for t in tokens]))
            continue
        key = tokens[0].rstrip(":=").upper()
        values = tokens[1:]
        if values and values[0] in ("=", ":"):
            values = values[1:]
        if key not in allowed:
            raise f.fail(n, f"unknown keyword {tokens[0]!r}; allowed: {', '.join(sorted(allowed))}")
        if f.rows:
            raise f.fail(n, f"keyword {key} after the data rows; header lines come first")
        if key in f.header:
            raise f.fail(n, f"{key} is given twice (first on line {f.header[key][0]})")
        if key not in _TEXT_KEYS and key != "CRITERION" and not values:
            raise f.fail(n, f"{key} needs a value")
        f.header[key] = (n, values)
    return f


# --------------------------------------------------------------------------- discovery
def index_seed_files(directory: Path) -> dict[str, dict[tuple[str, str], Path]]:
    """spec name (upper case) → {(S|R, EXT): path} for every file that fits the naming."""
    out: dict[str, dict[tuple[str, str], Path]] = {}
    if not directory.is_dir():
        raise MachineFileError(str(directory), "", "not a directory")
    for path in sorted(directory.iterdir()):
        m = _FILE_RE.match(path.name)
        if not m or not path.is_file():
            continue
        spec, kind, ext = m.group(1).upper(), m.group(2).upper(), m.group(3).upper()
        if ext != "CTL" and ext not in EXTENSIONS:
            continue  # e.g. the paper's S.VOL / R.VOL volumetric-error files
        out.setdefault(spec, {})[(kind, ext)] = path
    return out
