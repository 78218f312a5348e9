"""CorrectionGrid against independent oracles: the analytic field, numpy Squad, scipy splines."""

from __future__ import annotations

import numpy as np
import pytest
import quaternion as npq
from scipy.interpolate import make_interp_spline

from cmm_comp.compensation.grid import CorrectionGrid, GridSignal, make_grid_continuous
from cmm_comp.compensation.grid import quaternion as qt
from cmm_comp.compensation.grid.field import AnalyticErrorField
from cmm_comp.compensation.grid.squad import squad

STYLUS = np.array([30.0, -40.0, -150.0])
REF = {"T_x": 20.0, "T_top": 20.0}  # reference temperatures: the geometric grid


@pytest.fixture(scope="module")
def field() -> AnalyticErrorField:
    return AnalyticErrorField(rotation_urad=30.0, translation_um=5.0)


@pytest.fixture(scope="module")
def grid(field: AnalyticErrorField) -> CorrectionGrid:
    return CorrectionGrid.build(field, steps=(12, 10, 6))


def _random_points(grid: CorrectionGrid, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(grid.lower_mm, grid.upper_mm, size=(n, 3))


def _window(n: int, i: int) -> tuple[int, int]:
    """Indices of the ≤4 local keyframes used for segment i (boundary: fewer)."""
    return max(i - 1, 0), min(i + 2, n - 1)


def _oracle_rotation(grid: CorrectionGrid, p: np.ndarray) -> np.ndarray:
    """Tensor Squad written with the numpy Squad: x on full lines, then local y, z windows."""
    q = grid.q_work_stylus
    u = [
        (p[k] - grid.lower_mm[k]) / (grid.upper_mm[k] - grid.lower_mm[k]) * (grid.steps[k] - 1)
        for k in range(3)
    ]
    cell = [min(int(np.floor(u[k])), grid.steps[k] - 2) for k in range(3)]
    j0, j1 = _window(grid.steps[1], cell[1])
    k0, k1 = _window(grid.steps[2], cell[2])
    along_x = np.empty((j1 - j0 + 1, k1 - k0 + 1, 4))
    for a, jj in enumerate(range(j0, j1 + 1)):
        for b, kk in enumerate(range(k0, k1 + 1)):
            along_x[a, b] = squad(q[:, jj, kk], [u[0]], "quadratic")[0]
    along_y = np.array(
        [squad(along_x[:, b], [u[1] - j0], "quadratic")[0] for b in range(k1 - k0 + 1)]
    )
    return squad(along_y, [u[2] - k0], "quadratic")[0]


def _oracle_translation(grid: CorrectionGrid, p: np.ndarray) -> np.ndarray:
    vals = grid.translation_um
    for axis in range(3):
        vals = make_interp_spline(grid.axes[axis], vals, k=3, axis=0)(p[axis])
    return vals


def test_hits_the_exact_model_at_the_nodes(field: AnalyticErrorField, grid: CorrectionGrid) -> None:
    nodes = np.stack(np.meshgrid(*grid.axes, indexing="ij"), axis=-1).reshape(-1, 3)
    err_um, status = grid.error_um(nodes, STYLUS, REF)
    assert np.all(status == "ok")
    np.testing.assert_allclose(err_um, field.volumetric_error(nodes, STYLUS), atol=1e-9)


def test_rotation_is_tensor_squad_and_translation_tricubic(grid: CorrectionGrid) -> None:
    pts = _random_points(grid, 25, seed=1)
    pts[0] = grid.lower_mm  # corner: boundary rule on every axis
    pts[1] = grid.upper_mm
    q, t, status = grid.pose(pts, REF)
    assert np.all(status == "ok")
    for n, p in enumerate(pts):
        np.testing.assert_allclose(q[n], _oracle_rotation(grid, p), atol=1e-15)
        np.testing.assert_allclose(t[n], _oracle_translation(grid, p), atol=1e-11)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)


def test_x_stage_agrees_with_numpy_quaternion_squad(grid: CorrectionGrid) -> None:
    # on a node line in y and z the tensor product reduces to Squad along x; numpy-quaternion
    # uses the "reflect" boundary rule, so compare on the interior segments (1 … n − 3)
    x = np.linspace(grid.axes[0][1], grid.axes[0][-2] - 1e-6, 57)
    j, k = 3, 2
    pts = np.c_[x, np.full_like(x, grid.axes[1][j]), np.full_like(x, grid.axes[2][k])]
    q, _, _ = grid.pose(pts, REF)
    t_in = np.asarray(grid.axes[0])
    ref = npq.as_float_array(npq.squad(npq.as_quat_array(grid.q_work_stylus[:, j, k]), t_in, x))
    np.testing.assert_allclose(q, ref, atol=1e-15)


@pytest.mark.parametrize("rotation_urad", [30.0, 3000.0])
def test_interpolation_error_is_small_and_falls_with_density(rotation_urad: float) -> None:
    field = AnalyticErrorField(rotation_urad=rotation_urad, translation_um=5.0)
    pts = np.random.default_rng(2).uniform(field.volume.lower_mm, field.volume.upper_mm, (3000, 3))
    exact = field.volumetric_error(pts, STYLUS)
    errs = []
    for steps in [(8, 8, 5), (16, 16, 10), (32, 32, 20)]:
        g = CorrectionGrid.build(field, steps=steps)
        err, _ = g.error_um(pts, STYLUS, REF)
        errs.append(np.abs(err - exact).max())
    # Squad with Catmull-Rom-like control points converges ~h³, the cubic spline ~h⁴
    assert errs[0] > 6 * errs[1] > 36 * errs[2]
    assert errs[2] < 1e-3 * np.abs(exact).max()


def test_signal_sensitivity_is_linear_and_reproduces_the_field(field: AnalyticErrorField) -> None:
    grid = CorrectionGrid.build(field, steps=(16, 16, 8))
    nonlin = grid.metadata["nonlinearity"]
    assert nonlin["T_x"]["translation_um"] < 1e-9  # scale expansion: exactly linear
    assert nonlin["T_top"]["rotation_urad"] < 1e-6  # bending: linear to first order
    assert [s.name for s in grid.signals] == ["T_x", "T_top"]
    pts = _random_points(grid, 2000, seed=3)
    rng = np.random.default_rng(4)
    temps = {"T_x": rng.uniform(15, 25, 2000), "T_top": rng.uniform(15, 25, 2000)}
    exact = field.volumetric_error(pts, STYLUS, temps)
    err, status = grid.error_um(pts, STYLUS, temps)
    assert np.all(status == "ok")
    thermal = exact - field.volumetric_error(pts, STYLUS)
    assert np.abs(thermal).max() > 30.0  # the signals matter here
    assert np.abs(err - exact).max() < 0.01 * np.abs(exact).max()


def test_status_outside_invalid_and_missing_temperature(grid: CorrectionGrid) -> None:
    inside = 0.5 * (grid.lower_mm + grid.upper_mm)
    pts = np.array([inside, grid.upper_mm + np.array([1.0, 0, 0]), [np.nan, 1.0, 1.0], inside])
    temps = {"T_x": np.array([21.0, 21.0, 21.0, np.nan]), "T_top": 20.0}
    out, status = grid.correct(pts, STYLUS, temps)
    assert status.tolist() == ["ok", "outside_volume", "invalid_input", "no_temperature"]
    assert np.all(np.isnan(out[1:3]))
    # without T_x: geometric correction only, flagged, never silently "ok"
    geo, _ = grid.correct(inside[None], STYLUS, {"T_x": 20.0, "T_top": 20.0})
    np.testing.assert_allclose(out[3], geo[0], atol=1e-12)
    _, status2 = grid.correct(pts[:1], STYLUS, None)
    assert status2.tolist() == ["no_temperature"]
    clamped, st = grid.correct(pts[1:2], STYLUS, {"T_x": 20.0, "T_top": 20.0}, outside="clamp")
    assert st.tolist() == ["clamped_outside_volume"]
    edge, _ = grid.correct(grid.upper_mm[None], STYLUS, {"T_x": 20.0, "T_top": 20.0})
    np.testing.assert_allclose(clamped[0] - pts[1], edge[0] - grid.upper_mm, atol=1e-12)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        grid.correct(np.zeros((2, 2)))


def test_single_point_path_equals_batch(grid: CorrectionGrid) -> None:
    pts = _random_points(grid, 20, seed=5)
    temps = {"T_x": 22.5, "T_top": 19.0}
    batch, st = grid.correct(pts, STYLUS, temps)
    for n, p in enumerate(pts):
        one, status = grid.correct_point(tuple(p), tuple(STYLUS), temps)
        assert status == st[n] == "ok"
        np.testing.assert_allclose(one, batch[n], atol=1e-12)
        arr, status_arr = grid.correct(p[None], STYLUS, {"T_x": [22.5], "T_top": 19.0})
        np.testing.assert_allclose(arr[0], batch[n], atol=1e-12)
        assert status_arr.dtype.kind == "U"
    assert grid.correct_point((1e9, 0, 0), (0, 0, 0), temps)[1] == "outside_volume"
    assert grid.correct_point((np.nan, 0, 0), (0, 0, 0), temps)[1] == "invalid_input"
    assert grid.correct_point(tuple(pts[0]), (0, 0, 0), {"T_top": 20.0})[1] == "no_temperature"


def test_command_for_target_inverts_correct(grid: CorrectionGrid) -> None:
    targets = _random_points(grid, 200, seed=6)
    targets = np.clip(targets, grid.lower_mm + 0.1, grid.upper_mm - 0.1)
    temps = {"T_x": 23.0, "T_top": 21.0}
    cmd, status = grid.command_for_target(targets, STYLUS, temps, tol_mm=1e-9)
    assert np.all(status == "ok")
    back, _ = grid.correct(cmd, STYLUS, temps)
    np.testing.assert_allclose(back, targets, atol=1e-8)
    _, st = grid.command_for_target(targets[:3], STYLUS, temps, max_iter=1, tol_mm=1e-15)
    assert st.tolist() == ["not_converged"] * 3


def test_build_refuses_absurd_steps(field: AnalyticErrorField) -> None:
    with pytest.raises(ValueError, match="steps along z = 2"):
        CorrectionGrid.build(field, steps=(10, 10, 2))
    with pytest.raises(ValueError, match="at most 2000000"):
        CorrectionGrid.build(field, steps=(1000, 1000, 1000))


def test_from_poses_and_grid_continuity() -> None:
    axes = [np.linspace(0, 300, 5), np.linspace(0, 200, 4), np.linspace(0, 100, 4)]
    rng = np.random.default_rng(7)
    rv = rng.normal(scale=20e-6, size=(5, 4, 4, 3))
    q = qt.quaternion_from_rotvec(rv)
    flips = np.where(rng.random((5, 4, 4, 1)) < 0.5, -1.0, 1.0)
    t = rng.normal(size=(5, 4, 4, 3))
    grid = CorrectionGrid.from_poses(axes, q * flips, t, machine_name="bench")
    np.testing.assert_allclose(grid.q_work_stylus, q, atol=0)  # w > 0 everywhere here
    assert np.all(grid.q_work_stylus[..., 0] > 0)
    with pytest.raises(ValueError, match="equally spaced"):
        CorrectionGrid.from_poses([np.array([0, 1, 3.0, 4]), *axes[1:]], q[:4], t[:4])
    with pytest.raises(ValueError, match="unit"):
        CorrectionGrid.from_poses(axes, q * 1.1, t)
    with pytest.raises(ValueError, match="120°"):
        make_grid_continuous(
            qt.quaternion_from_rotvec(np.r_[[[[0, 0, 0]]], [[[0, 0, 3.0]]]] * np.ones((2, 1, 1, 3)))
        )
    with pytest.raises(ValueError, match="without sensitivity"):
        CorrectionGrid.from_poses(axes, q, t, signals=[GridSignal("T_x", 20.0, True)])
