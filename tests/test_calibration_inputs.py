"""Bad calibration input: one clear error naming the file, the line (or key) and the field, exit
code 2, nothing written — a previous machine file is left as it was (docs/formats.md §10).

Each case corrupts one file of the worked example (examples/calibration) in a copy and runs the
command line as a user types it, through the CLI's own ``main()`` in this process (what the
installed script calls: exit code, stdout and stderr as a subprocess would give them).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
from doc_commands import cli

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "calibration"
FILES = ("calibration.toml", "laser.csv", "plate.toml", "plate.csv", "trac.csv")


@pytest.fixture()
def plan_dir(tmp_path: Path) -> Path:
    for name in FILES:
        shutil.copy(EXAMPLE / name, tmp_path / name)
    (tmp_path / "machine.toml").write_text("# the previous machine: must survive\n")
    return tmp_path


def _run(folder: Path) -> subprocess.CompletedProcess[str]:
    return cli(
        "calibrate",
        "calibration.toml",
        "-o",
        "machine.toml",
        "--report",
        "report",
        "--quiet",
        cwd=folder,
    )


def _fails(folder: Path, *needles: str) -> str:
    proc = _run(folder)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("cmm-comp: error: "), proc.stderr
    for needle in needles:
        assert needle in lines[0], f"{needle!r} not in {lines[0]!r}"
    assert (folder / "machine.toml").read_text() == "# the previous machine: must survive\n"
    assert not (folder / "report").exists()
    assert "Traceback" not in proc.stderr
    return lines[0]


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _line_number(path: Path, predicate) -> int:  # type: ignore[no-untyped-def]
    for i, line in enumerate(_lines(path), start=1):
        if predicate(line):
            return i
    raise AssertionError("no such line")


def test_station_with_too_few_points(plan_dir: Path) -> None:
    path = plan_dir / "trac.csv"
    lines = _lines(path)
    kept = [
        line
        for line in lines
        if not line.startswith("S3,") or line.split(",")[1] in ("1", "2", "3")
    ]
    path.write_text("\n".join(kept) + "\n")
    first = _line_number(path, lambda s: s.startswith("S3,"))
    _fails(plan_dir, "trac.csv", f"line {first}", "column 'station'", "'S3' has 3 point(s)", "≥ 4")


def test_plate_with_duplicate_ball_id(plan_dir: Path) -> None:
    path = plan_dir / "plate.toml"
    text = path.read_text().replace("id = 7\n", "id = 3\n", 1)
    path.write_text(text)
    _fails(plan_dir, "plate.toml", "ball[6].id", "duplicate ball id '3'")


def test_run_whose_positions_are_not_monotonic(plan_dir: Path) -> None:
    path = plan_dir / "laser.csv"
    lines = _lines(path)
    # the third row of the first forward pass goes back below the second
    i = _line_number(path, lambda s: s.startswith("x,linear_um,100.000"))
    lines[i - 1] = lines[i - 1].replace("x,linear_um,100.000", "x,linear_um,10.000", 1)
    path.write_text("\n".join(lines) + "\n")
    _fails(plan_dir, "laser.csv", f"line {i}", "column 'position_mm'", "not monotonic")


@pytest.mark.parametrize(
    ("name", "line", "cell", "column", "text"),
    [("plate.csv", 10, 3, "y", "nan"), ("laser.csv", 40, 3, "value", "NaN")],
)
def test_nan_reading(
    plan_dir: Path, name: str, line: int, cell: int, column: str, text: str
) -> None:
    path = plan_dir / name
    lines = _lines(path)
    cells = lines[line - 1].split(",")
    cells[cell] = text
    lines[line - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    _fails(plan_dir, name, f"line {line}", f"column '{column}'", f"not a finite number: '{text}'")


def test_plan_naming_a_missing_file(plan_dir: Path) -> None:
    (plan_dir / "plate.csv").unlink()
    _fails(plan_dir, "calibration.toml", "plate[0].file", "no such file", "plate.csv")


def test_plan_with_an_unknown_key(plan_dir: Path) -> None:
    path = plan_dir / "calibration.toml"
    path.write_text(path.read_text().replace("[fit]\n", "[fit]\nnodez = 5\n"))
    _fails(plan_dir, "calibration.toml", "fit", "unknown key(s) ['nodez']")


def test_station_guesses_must_match_the_stations(plan_dir: Path) -> None:
    path = plan_dir / "calibration.toml"
    text = path.read_text()
    start = text.index("station_guess_mm = [[") + len("station_guess_mm = [")
    end = text.index("]", start) + 1  # drop the first guess
    path.write_text(text[:start] + text[end + 2 :])
    _fails(plan_dir, "trac.csv", "4 stations", "gives 3 positions")


def test_straightness_along_its_own_axis(plan_dir: Path) -> None:
    path = plan_dir / "laser.csv"
    lines = _lines(path)
    i = _line_number(path, lambda s: s.startswith("x,straightness_y_um"))
    lines[i - 1] = lines[i - 1].replace("straightness_y_um", "straightness_x_um", 1)
    path.write_text("\n".join(lines) + "\n")
    _fails(plan_dir, "laser.csv", f"line {i}", "column 'quantity'", "perpendicular")
