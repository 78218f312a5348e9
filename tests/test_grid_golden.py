"""Grids written by the code before issue 26 load, save and correct as they did then.

Oracle: the files and the answers recorded by that code (tests/data/grid_golden.md), not
today's code: a change of the file format or of the arithmetic of any correction path fails.

Bit for bit where this process runs the kernels from numba's on-disk cache (the answers were
recorded so). A kernel compiled in this process may differ from its cached copy in the last
bits (fast-math code generation; measured on the recording code itself: up to 1.4e-14 mm,
2.2e-16 in a quaternion component); then the answers must agree within 1 pm (1e-12 mm), 1e-9 µm
and 1e-14 per quaternion component, far below anything a change of the formulas would move.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from grid_golden import cases

from cmm_comp.compensation.grid import CorrectionGrid, kernels, uncertainty

DATA = Path(__file__).resolve().parent / "data"
SHA256 = {
    "npl": "96ab515b2605073070e30b66f9efe288328f4dfcb85fa2e0d6c67e8c52d4dc99",
    "wide": "3716095e8316e25d2af4c45b298aff1a63853a2cba6df9e6bc90dbf7d2de4f7e",
}
KERNELS = (
    kernels.eval_serial,
    kernels.eval_parallel,
    uncertainty._u_rows,
    uncertainty._u_rows_serial,
    uncertainty._point_kernel,
)
#: Agreement allowed when a kernel was compiled in this process, by the unit of the answer.
ATOL = {"q": 1e-14, "um": 1e-9, "mm": 1e-12}


def _unit(key: str) -> str:
    if key == "pose_q":
        return "q"
    return "um" if key in ("pose_t", "error_um", "u_um", "point_u") else "mm"


def _from_cache() -> bool:
    """Whether every kernel this process ran came from numba's on-disk cache."""
    return all(k.stats.cache_path is not None and not k.stats.cache_misses for k in KERNELS)


@pytest.fixture(scope="module")
def expected() -> dict[str, np.ndarray]:
    with np.load(DATA / "grid_golden_expected.npz", allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


@pytest.mark.parametrize("name", sorted(SHA256))
def test_an_old_grid_loads_saves_and_corrects_as_before(
    name: str, expected: dict[str, np.ndarray], tmp_path: Path
) -> None:
    grid = CorrectionGrid.load(DATA / f"grid_golden_{name}.grid")
    assert grid.sha256 == SHA256[name]
    assert grid.has_uncertainty == (name == "npl")
    assert grid.save(tmp_path / "again.grid") == SHA256[name]  # same header, same arrays
    got = cases(grid, [s.name for s in grid.signals])
    want = {k.split("/", 1)[1]: v for k, v in expected.items() if k.startswith(f"{name}/")}
    assert sorted(got) == sorted(want)
    exact = _from_cache()
    for key, value in want.items():
        if value.dtype.kind == "U":
            assert got[key].tolist() == value.tolist(), key
            continue
        assert got[key].dtype == value.dtype and got[key].shape == value.shape, key
        assert np.array_equal(np.isnan(got[key]), np.isnan(value)), key
        if exact:
            assert np.array_equal(got[key], value, equal_nan=True), key
        else:
            np.testing.assert_allclose(got[key], value, rtol=0, atol=ATOL[_unit(key)], err_msg=key)
