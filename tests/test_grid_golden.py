"""Grids written by the code before issue 26 load, save and correct bit for bit as they did then.

Oracle: the files and the answers recorded by that code (tests/data/grid_golden.md), not
today's code: any change of the file format or of the arithmetic of any correction path fails.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from grid_golden import cases

from cmm_comp.compensation.grid import CorrectionGrid

DATA = Path(__file__).resolve().parent / "data"
SHA256 = {
    "npl": "96ab515b2605073070e30b66f9efe288328f4dfcb85fa2e0d6c67e8c52d4dc99",
    "wide": "3716095e8316e25d2af4c45b298aff1a63853a2cba6df9e6bc90dbf7d2de4f7e",
}


@pytest.fixture(scope="module")
def expected() -> dict[str, np.ndarray]:
    with np.load(DATA / "grid_golden_expected.npz", allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


@pytest.mark.parametrize("name", sorted(SHA256))
def test_an_old_grid_loads_saves_and_corrects_bit_for_bit(
    name: str, expected: dict[str, np.ndarray], tmp_path: Path
) -> None:
    grid = CorrectionGrid.load(DATA / f"grid_golden_{name}.grid")
    assert grid.sha256 == SHA256[name]
    assert grid.has_uncertainty == (name == "npl")
    assert grid.save(tmp_path / "again.grid") == SHA256[name]  # same header, same arrays
    got = cases(grid, [s.name for s in grid.signals])
    want = {k.split("/", 1)[1]: v for k, v in expected.items() if k.startswith(f"{name}/")}
    assert sorted(got) == sorted(want)
    for key, value in want.items():
        if value.dtype.kind == "U":
            assert got[key].tolist() == value.tolist(), key
        else:
            assert got[key].dtype == value.dtype and got[key].shape == value.shape, key
            assert np.array_equal(got[key], value, equal_nan=True), key
