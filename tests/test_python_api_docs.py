"""The Python API blocks of README.md ("Python API") and docs/formats.md §5 run as printed.

Oracle: the machine model itself — what the documented grid calls return is checked against the
exact model error the same block computes (``volumetric_error``), and the two-value and
three-value correction calls against each other and against the single-reading call.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _block(path: Path, heading: str) -> str:
    """The first ```python block after ``heading`` in ``path``."""
    text = path.read_text(encoding="utf-8")
    start = text.index(heading)
    match = re.search(r"```python\n(.*?)```", text[start:], re.S)
    assert match is not None, f"{path.name}: no python block after {heading!r}"
    return match.group(1)


@pytest.fixture
def in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    shutil.copytree(ROOT / "examples" / "machines", tmp_path / "examples" / "machines")
    shutil.copy(ROOT / "examples" / "machines" / "npl-bridge.toml", tmp_path / "machine.toml")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _points() -> np.ndarray:
    rng = np.random.default_rng(5)
    return rng.uniform((50.0, 50.0, 50.0), (850.0, 1100.0, 350.0), (40, 3))


def test_readme_python_api_block(in_tmp: Path) -> None:
    scope: dict[str, Any] = {"points_mm": _points()}
    exec(_block(ROOT / "README.md", "## Python API"), scope)
    grid, pts = scope["grid"], scope["points_mm"]
    # only T_x is given: the grid says so, and corrects with the other temperatures' terms left
    # out, i.e. as the model at their reference
    assert np.all(scope["status"] == "no_temperature")
    # the grid's correction against the model's exact error (interpolated: within 0.05 µm)
    err_mm = (scope["corrected_mm"] - pts) * 1000.0
    assert np.abs(err_mm - scope["err_um"]).max() < 0.05
    assert np.array_equal(scope["corrected_mm"], grid.correct(pts, (0, 0, -120), {"T_x": 21.3})[0])
    assert np.all(np.isnan(scope["U_um"]))  # this grid carries no U: never a number
    assert (in_tmp / "npl.grid").is_file() and (in_tmp / "bridge.toml").is_file()


def test_formats_python_api_block(in_tmp: Path) -> None:
    pts = _points()
    temps = {"T_x": 21.0, "T_wp": 19.5}
    scope: dict[str, Any] = {"points_mm": pts, "temps": temps, "point_mm": pts[3]}
    exec(_block(ROOT / "docs" / "formats.md", "## 5. Python API"), scope)
    grid, machine = scope["grid"], scope["machine"]
    exact_um = machine.volumetric_error(pts, stylus_mm=(0, 0, 0), temps_C=temps)
    assert np.abs((scope["corrected_mm"] - pts) * 1000.0 - exact_um).max() < 0.05
    two = grid.correct(pts, (0, 0, 0), temps)
    assert len(two) == 2 and np.array_equal(two[0], scope["corrected_mm"])
    assert (scope["cx"], scope["cy"], scope["cz"]) == tuple(two[0][3])  # one reading, last
    assert scope["status"] == two[1][3] == "no_temperature"  # T_y, T_z not given
    assert np.all(np.isnan(scope["U_um"])) and np.all(np.isnan((scope["ux"], scope["uy"])))
