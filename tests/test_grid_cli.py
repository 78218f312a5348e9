"""``grid build`` and ``correct`` command handlers (registered by the lead's CLI)."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import pytest

from cmm_comp.cli.grid import add_parsers
from cmm_comp.compensation.machine import Machine

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "machines" / "npl-bridge.toml"


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    add_parsers(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.handler(args))


def test_build_then_correct(tmp_path: Path) -> None:
    grid_path = tmp_path / "npl.grid"
    assert (
        _run(["grid", "build", str(EXAMPLE), "-o", str(grid_path), "--steps", "12", "12", "6"]) == 0
    )
    points = tmp_path / "points.csv"
    points.write_text(
        "x,y,z,px,py,pz,T_x,T_y,T_z,T_wp,group\n"
        "100,200,50,0,0,-120,21,21,21,20,a\n"
        "450,575,200,10,0,-100,20,20,20,20,b\n"
        "1e4,0,0,0,0,-120,20,20,20,20,c\n"
        "300,300,100,0,0,-120,,20,20,20,d\n"
    )
    out = tmp_path / "out.csv"
    assert _run(["correct", str(grid_path), "--in", str(points), "--out", str(out)]) == 0
    with out.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["status"] for r in rows] == ["ok", "ok", "outside_volume", "no_temperature"]
    assert rows[0]["group"] == "a" and rows[2]["cx"] == ""
    machine = Machine.from_toml(EXAMPLE)
    p = np.array([[100.0, 200.0, 50.0]])
    exact = machine.volumetric_error(
        p, (0, 0, -120), {"T_x": 21.0, "T_y": 21.0, "T_z": 21.0, "T_wp": 20.0}
    )
    got = np.array([[float(rows[0][c]) for c in ("cx", "cy", "cz")]])
    np.testing.assert_allclose(got, p + exact / 1000.0, atol=1e-4)  # coarse 12×12×6 grid
    assert np.abs(got - p).max() > 1e-3  # and the correction is really applied


def test_bad_points_file_names_line_and_column(tmp_path: Path) -> None:
    grid_path = tmp_path / "g.grid"
    _run(["grid", "build", str(EXAMPLE), "-o", str(grid_path), "--steps", "5", "5", "4"])
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,z\n1,2,3\n1,zz,3\n")
    out = tmp_path / "out.csv"
    with pytest.raises(ValueError, match=r"bad\.csv:3: column 'y': not a number: 'zz'"):
        _run(["correct", str(grid_path), "--in", str(bad), "--out", str(out)])
    assert not out.exists()
    (tmp_path / "nox.csv").write_text("a,y,z\n1,2,3\n")
    with pytest.raises(ValueError, match="missing column 'x'"):
        _run(["correct", str(grid_path), "--in", str(tmp_path / "nox.csv"), "--out", str(out)])
