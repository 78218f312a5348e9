"""Bad-input cases of the issue, each a valid mixed case with one defect, and the check.

The issue: "a station with < 4 points, a plate with duplicate ball ids, a run whose positions are
not monotonic, NaN, a plan naming a missing file" get one clear error naming file, line and field;
nothing half-written. The check (``check_rejection``) asks of ``cmm-comp calibrate``:

* exit code 2, no traceback, exactly one line starting ``cmm-comp: error:``;
* that line names the defective file (base name), a line number among the defect's lines
  (``line N`` or ``lines N-M``, physical lines of the file counted from 1 as an editor shows
  them, comment and header lines included) — or for a TOML file the key path or the line — and
  the field (column or key);
* nothing written: ``-o OUT`` (made beforehand with known bytes) is unchanged and ``--report DIR``
  (absent beforehand) still does not exist.
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from .case import build_case
from .scoring import Calibrate, error_lines, mentioned_lines

SENTINEL = b"# an earlier result that a failed calibrate must not touch\n"


@dataclass
class BadCase:
    """A plan with one defect and what its error line must name."""

    name: str
    plan: Path
    file: str  # base name of the file the message must name
    lines: frozenset[int]  # acceptable line numbers (empty: not checked)
    field_pattern: str  # regex the message must match (the field, column or key)
    also: tuple[str, ...] = ()  # further words the message must contain
    key_prefix: str = ""  # a TOML array whose entry may be named instead of a line …
    key_indices: frozenset[int] = frozenset()  # … by one of these indices (0- or 1-based)

    def names_the_place(self, message: str) -> bool:
        """The message names one of the defect's lines, or (TOML) one of its array entries."""
        if mentioned_lines(message) & self.lines:
            return True
        if self.key_prefix:
            pattern = rf"\b{re.escape(self.key_prefix)}\s*(?:\[|\.|#|\s)\s*(\d+)"
            return any(int(m) in self.key_indices for m in re.findall(pattern, message))
        return False


def _data_lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines(keepends=True)


def _rows(lines: list[str]) -> list[tuple[int, list[str]]]:
    """(physical line number from 1, fields) of the data rows (after comments and header)."""
    out = []
    header_seen = False
    for i, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        if not header_seen:
            header_seen = True
            continue
        out.append((i, line.rstrip("\n").split(",")))
    return out


def _station_with_three_points(d: Path) -> BadCase:
    path = d / "trac.csv"
    lines = _data_lines(path)
    rows = _rows(lines)
    last = max(int(f[0]) for _, f in rows)
    keep, drop = [], []
    for n, f in rows:
        if int(f[0]) == last:
            (keep if len(keep) < 3 else drop).append(n)
    text = [line for i, line in enumerate(lines, start=1) if i not in set(drop)]
    path.write_text("".join(text), encoding="utf-8")
    first_kept = len(text) - 2  # the station's rows are the file's last three lines
    allowed = frozenset(range(first_kept, first_kept + 3))
    return BadCase("station_with_3_points", d / "calibration.toml", "trac.csv", allowed, r"station")


def _duplicate_ball_id(d: Path) -> BadCase:
    path = d / "plate.toml"
    lines = _data_lines(path)
    id_lines = [i for i, line in enumerate(lines) if re.match(r"\s*id\s*=", line)]
    first, second = id_lines[2], id_lines[5]  # the 3rd and 6th ball
    value = lines[first].split("=")[1].strip()
    lines[second] = f"id = {value}\n"
    path.write_text("".join(lines), encoding="utf-8")
    k1, k2 = 2, 5  # the entries' indices in the [[ball]] array (one id line each)
    return BadCase(
        "duplicate_ball_id",
        d / "calibration.toml",
        "plate.toml",
        frozenset({first + 1, second + 1}),
        r"\bid\b",
        key_prefix="ball",
        key_indices=frozenset({k1, k2, k1 + 1, k2 + 1}),
    )


def _non_monotonic_run(d: Path) -> BadCase:
    path = d / "laser.csv"
    lines = _data_lines(path)
    rows = _rows(lines)
    run1 = [(n, f) for n, f in rows if f[5] == rows[0][1][5]]
    (n3, f3), (n4, f4) = run1[3], run1[4]  # two rows of the first forward pass
    f3[2], f4[2] = f4[2], f3[2]
    lines[n3 - 1] = ",".join(f3) + "\n"
    lines[n4 - 1] = ",".join(f4) + "\n"
    path.write_text("".join(lines), encoding="utf-8")
    return BadCase(
        "non_monotonic_run",
        d / "calibration.toml",
        "laser.csv",
        frozenset({n3, n4}),
        r"position_mm",
    )


def _nan_in(d: Path, file: str, column: str, row_index: int, spelled: str) -> BadCase:
    path = d / file
    lines = _data_lines(path)
    header = (
        next(line for line in lines if line.strip() and not line.lstrip().startswith("#"))
        .strip()
        .split(",")
    )
    n, f = _rows(lines)[row_index]
    f[header.index(column)] = spelled
    lines[n - 1] = ",".join(f) + "\n"
    path.write_text("".join(lines), encoding="utf-8")
    return BadCase(
        f"nan_{file.split('.')[0]}_{column}",
        d / "calibration.toml",
        file,
        frozenset({n}),
        rf"\b{re.escape(column)}\b",
    )


def _missing_file(d: Path) -> BadCase:
    plan = d / "calibration.toml"
    text = plan.read_text(encoding="utf-8").replace('file = "plate.csv"', 'file = "plate_gone.csv"')
    plan.write_text(text, encoding="utf-8")
    return BadCase(
        "missing_file", plan, "calibration.toml", frozenset(), r"\bfile\b", also=("plate_gone.csv",)
    )


def make_bad_cases(root: Path, seed: int = 4242, model: str = "FB1") -> list[BadCase]:
    """Every bad-input case, each in its own folder under ``root``."""
    builders = [
        _station_with_three_points,
        _duplicate_ball_id,
        _non_monotonic_run,
        lambda d: _nan_in(d, "laser.csv", "value", 7, "nan"),
        lambda d: _nan_in(d, "trac.csv", "length_mm", 11, "NaN"),
        _missing_file,
    ]
    template = root / "template"
    build_case(template, seed, "mixed", model)
    shutil.rmtree(template / "truth")
    cases = []
    for i, make in enumerate(builders):
        d = root / f"bad_{i}"
        shutil.copytree(template, d)
        cases.append(make(d))
    return cases


def check_rejection(bad: BadCase, work: Path, calibrate: Calibrate) -> list[str]:
    """Run ``calibrate`` on the bad plan; the problems with how it refused (empty: all good)."""
    work.mkdir(parents=True, exist_ok=True)
    out, report = work / "out.toml", work / "report"
    out.write_bytes(SENTINEL)
    rc, _, stderr = calibrate(bad.plan, out, report)
    problems = []
    if rc != 2:
        problems.append(f"exit code {rc}, expected 2")
    if "Traceback" in stderr:
        problems.append("a traceback on stderr")
    errors = error_lines(stderr)
    if len(errors) != 1:
        problems.append(f"{len(errors)} 'cmm-comp: error:' lines, expected 1: {stderr.strip()!r}")
    message = errors[0] if errors else ""
    if bad.file not in message:
        problems.append(f"the message does not name {bad.file}: {message!r}")
    if bad.lines and not bad.names_the_place(message):
        where = f"line of {sorted(bad.lines)}"
        if bad.key_prefix:
            where += f" nor {bad.key_prefix}[i] with i in {sorted(bad.key_indices)}"
        problems.append(f"the message names no {where}: {message!r}")
    if not re.search(bad.field_pattern, message):
        problems.append(f"the message does not name the field /{bad.field_pattern}/: {message!r}")
    problems += [
        f"the message does not say {w!r}: {message!r}" for w in bad.also if w not in message
    ]
    if not out.exists() or out.read_bytes() != SENTINEL:
        problems.append("OUT was changed or removed")
    if report.exists():
        problems.append("the report folder was created")
    return problems
