"""Maps, space diagonals and line reports against hand values and independent computations."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from doc_commands import cli as _cli

from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.reports.maps import (
    diagonal_endpoints,
    diagonals_um,
    line_report,
    volumetric_map,
)

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"

SCALE_ONLY = """
name = "scale"
model = "MB1"
[volume]
x = [0.0, 1000.0]
y = [0.0, 1000.0]
z = [0.0, 1000.0]
[errors.dx_x]
polynomial = [0.0, 0.01]   # 10 µm/m positional error of X
"""


def test_diagonals_of_a_pure_scale_error_match_hand_values(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text(SCALE_ONLY)
    m = Machine.from_toml(path)
    # each diagonal's X run is ±1000 mm with a 10 µm/m scale error: true − indicated length = 10/√3 µm
    hand = 10 / np.sqrt(3)
    np.testing.assert_allclose(diagonals_um(m, (0, 0, 0)), [hand] * 4, rtol=1e-5)


def test_diagonal_order_is_the_papers() -> None:
    m = Machine.from_toml(NPL)
    ends = diagonal_endpoints(m)
    X, Y, Z = m.volume.upper_mm
    assert [a.tolist() for a, _ in ends] == [[0, 0, 0], [X, 0, 0], [0, Y, 0], [0, 0, Z]]
    assert [b.tolist() for _, b in ends] == [[X, Y, Z], [0, Y, Z], [X, 0, Z], [X, Y, 0]]


def test_diagonals_agree_with_first_order_projection() -> None:
    """Oracle: (e_end − e_start)·unit direction, the first-order length error."""
    m = Machine.from_toml(NPL)
    p = m.probe.offset_mm
    for (a, b), got in zip(diagonal_endpoints(m), diagonals_um(m), strict=True):
        e = m.volumetric_error(np.stack([a, b]), p)
        u = (b - a) / np.linalg.norm(b - a)
        assert got == pytest.approx(float((e[1] - e[0]) @ u), abs=1e-4)


def test_map_nodes_and_values(tmp_path: Path) -> None:
    m = Machine.from_toml(NPL)
    vm = volumetric_map(m, (4, 5, 3), (0, 0, -50), {"T_x": 22.0})
    assert vm.points_mm.shape == (60, 3)
    np.testing.assert_allclose(np.unique(vm.points_mm[:, 1]), np.linspace(0, 1150, 5))
    np.testing.assert_allclose(
        vm.error_um, m.volumetric_error(vm.points_mm, (0, 0, -50), {"T_x": 22.0})
    )
    out = tmp_path / "map.csv"
    vm.write_csv(out)
    rows = list(csv.reader(out.read_text().splitlines()))
    assert rows[0] == ["x", "y", "z", "ex", "ey", "ez", "rx", "ry", "rz"]
    assert len(rows) == 61
    np.testing.assert_allclose(np.array(rows[1:], dtype=float)[:, 3:6], vm.error_um, atol=1e-5)


def test_line_report_bandwidth_and_max() -> None:
    m = Machine.from_toml(NPL)
    rep = line_report(m, "x", (0, 550, 200), samples=181)
    r = np.linalg.norm(
        m.volumetric_error(
            np.column_stack([rep.position_mm, np.full(181, 550.0), np.full(181, 200.0)]),
            m.probe.offset_mm,
        ),
        axis=1,
    )
    assert rep.max_um == pytest.approx(r.max())
    assert rep.bandwidth_um == pytest.approx(r.max() - r.min())
    with pytest.raises(ValueError, match="axis must be"):
        line_report(m, "w", (0, 0, 0))


def test_cli_map_and_diagonals(tmp_path: Path) -> None:
    r = _cli("map", str(NPL), "--out", str(tmp_path / "m.csv"), "--steps", "3", "3", "3", cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert len((tmp_path / "m.csv").read_text().splitlines()) == 28
    r = _cli("diagonals", str(NPL), "--json", str(tmp_path / "d.json"), cwd=ROOT)
    assert r.returncode == 0, r.stderr
    data = json.loads((tmp_path / "d.json").read_text())
    np.testing.assert_allclose(
        data["diagonals_um"], diagonals_um(Machine.from_toml(NPL)), rtol=1e-12
    )


def test_cli_bad_machine_is_one_line_and_writes_nothing(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'b'\nmodel = 'MB7'\n[volume]\nx=[0,1]\ny=[0,1]\nz=[0,1]\n")
    out = tmp_path / "m.csv"
    r = _cli("map", str(bad), "--out", str(out), cwd=ROOT)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert "unknown model 'MB7'" in r.stderr and str(bad) in r.stderr
    assert not out.exists()
