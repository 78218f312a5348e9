"""Six-DOF capture (seed Fig. 7): simulate the six readings from known poses and recover them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.compensation.grid import quaternion as qt
from cmm_comp.compensation.grid.field import AnalyticErrorField
from cmm_comp.compensation.reports.sixdof import (
    SixDofLayout,
    grid_from_readings,
    pose_first_order,
    pose_from_readings,
    readings_from_pose,
)

LAYOUT = SixDofLayout(
    d1_mm=80.0,
    d2_mm=60.0,
    d3_mm=70.0,
    p1_mm=np.array([-20.0, -10.0, 45.0]),
    p4_mm=np.array([50.0, -30.0, 5.0]),
    p6_mm=np.array([10.0, 40.0, -5.0]),
    origin_mm=np.array([0.0, 0.0, -120.0]),
)


@pytest.mark.parametrize("angle_rad", [30e-6, 3e-3, 0.05])
def test_exact_round_trip(angle_rad: float) -> None:
    rng = np.random.default_rng(1)
    rot = Rotation.from_rotvec(rng.normal(scale=angle_rad, size=(200, 3))).as_matrix()
    t_um = rng.normal(scale=20.0, size=(200, 3))
    m = readings_from_pose(LAYOUT, rot, t_um)
    rot_back, t_back = pose_from_readings(LAYOUT, m)
    np.testing.assert_allclose(rot_back, rot, atol=1e-14)
    np.testing.assert_allclose(t_back, t_um, atol=1e-9)
    np.testing.assert_allclose(
        np.swapaxes(rot_back, 1, 2) @ rot_back, np.broadcast_to(np.eye(3), rot.shape), atol=1e-15
    )


def test_readings_by_hand_for_pure_motions() -> None:
    layout = SixDofLayout(d1_mm=100.0, d2_mm=50.0, d3_mm=40.0)
    # pure translation: each sensor reads the displacement along its own axis
    m = readings_from_pose(layout, np.eye(3), [1.0, 2.0, 3.0])[0]
    np.testing.assert_allclose(m, [3, 3, 3, 1, 1, 2], atol=1e-12)
    # rotation about y by +θ tilts face Z: its height at x = d1 changes by −d1·tanθ
    theta = 1e-4
    rot = Rotation.from_rotvec([0, theta, 0]).as_matrix()
    m = readings_from_pose(layout, rot, [0, 0, 0])[0]
    p1 = layout.points_mm()[0]
    assert m[1] - m[0] == pytest.approx(-1000 * 100.0 * np.tan(theta), rel=1e-9)
    assert m[0] == pytest.approx(
        1000 * (p1[2] * (1 / np.cos(theta) - 1) - p1[0] * np.tan(theta)), abs=1e-9
    )


@pytest.mark.parametrize("angle_rad", [30e-6, 3e-3])
def test_first_order_differs_by_second_order_only(angle_rad: float) -> None:
    rng = np.random.default_rng(2)
    rv = rng.normal(scale=angle_rad, size=(100, 3))
    rot = Rotation.from_rotvec(rv).as_matrix()
    t_um = rng.normal(scale=20.0, size=(100, 3))
    m = readings_from_pose(LAYOUT, rot, t_um)
    w_urad, t1 = pose_first_order(LAYOUT, m)
    second = (4 * angle_rad) ** 2
    assert np.abs(w_urad * 1e-6 - rv).max() < 5 * second + 1e-15
    # lever arms ~200 mm (θ² terms) and translation × angle cross terms (|t| ≲ 60 µm)
    assert np.abs(t1 - t_um).max() < 1000 * 200 * second + 60 * 4 * angle_rad
    if angle_rad > 1e-3:  # and the exact solution is really better at mrad
        _, t_exact = pose_from_readings(LAYOUT, m)
        assert np.abs(t1 - t_um).max() > 1e3 * np.abs(t_exact - t_um).max()


def test_grid_from_captures_equals_grid_from_model() -> None:
    field = AnalyticErrorField(rotation_urad=2000.0)
    steps = (6, 5, 4)
    axes = [
        np.linspace(field.volume.lower_mm[k], field.volume.upper_mm[k], steps[k]) for k in range(3)
    ]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    pose = field.pose_error(nodes)
    layout = SixDofLayout(origin_mm=np.zeros(3))  # the probe reference point
    m = readings_from_pose(layout, pose.rotation, pose.translation_um).reshape(*steps, 6)
    measured = grid_from_readings(axes, m, layout, machine_name="captured")
    model = CorrectionGrid.build(field, steps=steps)
    np.testing.assert_allclose(measured.q_work_stylus, model.q_work_stylus, atol=1e-14)
    np.testing.assert_allclose(measured.translation_um, model.translation_um, atol=1e-9)
    pts = np.random.default_rng(3).uniform(field.volume.lower_mm, field.volume.upper_mm, (100, 3))
    a, _ = measured.correct(pts, (0, 0, -150))
    b, _ = model.correct(pts, (0, 0, -150), {"T_x": 20.0, "T_top": 20.0})
    np.testing.assert_allclose(a, b, atol=1e-12)
    assert qt.quaternion_from_matrix(pose.rotation).shape == (len(nodes), 4)


def test_bad_layout_and_readings() -> None:
    with pytest.raises(ValueError, match="d2_mm must be > 0"):
        SixDofLayout(d2_mm=0.0)
    with pytest.raises(ValueError, match="finite"):
        pose_from_readings(LAYOUT, [0, 0, np.nan, 0, 0, 0])
