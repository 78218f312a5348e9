"""Effects found by model discovery flow through the grid as runtime-signal sensitivities.

Oracle: the exact model (``Machine.volumetric_error``) of the same extended machine.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation import CorrectionGrid, Machine
from cmm_comp.compensation.thermal import SignalFilter

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"

EFFECTS = [
    {"cause": "probe_lobing", "lobes": 3, "a_cos_um": 1.5, "b_sin_um": -0.8},
    {"cause": "probe_lobing", "lobes": 2, "a_cos_um": 0.6, "b_sin_um": 0.4, "radial_power": 1},
    {"cause": "reversal", "axis": "x", "half_step_um": [2.0, 0.5], "span_mm": [0.0, 900.0]},
]


@pytest.fixture(scope="module")
def extended() -> tuple[Machine, CorrectionGrid]:
    base = Machine.from_toml(NPL)
    data = dict(base.description)
    data["effects"] = EFFECTS
    machine = Machine.from_dict(data)
    return machine, CorrectionGrid.build(machine, steps=(19, 23, 16))


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_grid_with_lobing_and_reversal_matches_the_model(
    extended: tuple[Machine, CorrectionGrid],
) -> None:
    machine, grid = extended
    assert {"dir_x", "lobe3_c_x", "lobe3_s_z", "lobe2r1_c_y"} <= {s.name for s in grid.signals}
    rng = np.random.default_rng(4)
    n = 300
    pts = rng.uniform(machine.volume.lower_mm, machine.volume.upper_mm, (n, 3))
    nvec = _directions(rng, n)
    temps = {"T_x": 21.0, "T_y": 19.0, "T_z": 20.5, "T_wp": 22.0}
    inputs = {
        "nx": nvec[:, 0],
        "ny": nvec[:, 1],
        "nz": nvec[:, 2],
        "dir_x": rng.choice([-1.0, 1.0], n),
    }
    stylus = (0.0, 0.0, -120.0)
    expected = pts + machine.volumetric_error(pts, stylus, temps, inputs=inputs) / 1000
    got, status = grid.correct(pts, stylus, temps, inputs)
    assert (status == "ok").all()
    np.testing.assert_allclose(got, expected, atol=5e-5)  # 0.05 µm
    # the single-reading fast path derives the lobing signals too
    for i in range(5):
        one = {k: float(v[i]) for k, v in inputs.items()}
        c, st = grid.correct_point(pts[i], stylus, {k: float(v) for k, v in temps.items()}, one)
        assert st == "ok"
        np.testing.assert_allclose(c, expected[i], atol=5e-5)


def test_missing_probe_direction_is_flagged(extended: tuple[Machine, CorrectionGrid]) -> None:
    _, grid = extended
    temps = {"T_x": 20.0, "T_y": 20.0, "T_z": 20.0, "T_wp": 20.0}
    _, status = grid.correct(np.array([[100.0, 100.0, 100.0]]), (0, 0, 0), temps, {"dir_x": 1.0})
    assert status[0] == "missing_input"
    _c, st = grid.correct_point((100.0, 100.0, 100.0), (0, 0, 0), temps, {"dir_x": 1.0})
    assert st == "missing_input"


def test_thermal_lag_filter_travels_in_the_grid_file(tmp_path: Path) -> None:
    base = Machine.from_toml(NPL)
    data = dict(base.description)
    data["effects"] = [{"cause": "thermal_lag", "time_constant_s": 1800.0, "fraction": 0.6}]
    machine = Machine.from_dict(data)
    grid = CorrectionGrid.build(machine, steps=(5, 5, 4))
    assert [f.to_header() for f in grid.signal_filters] == [
        {
            "kind": "first_order_lag",
            "signals": ["T_x", "T_y", "T_z"],
            "time_constant_s": 1800.0,
            "fraction": 0.6,
        }
    ]
    assert grid.signal_filters == [
        SignalFilter("first_order_lag", ("T_x", "T_y", "T_z"), 1800.0, 0.6)
    ]
    grid.save(tmp_path / "lag.grid")
    loaded = CorrectionGrid.load(tmp_path / "lag.grid")
    assert loaded.signal_filters == grid.signal_filters
    np.testing.assert_allclose(loaded.metadata["probe_offset_mm"], base.probe.offset_mm)
    assert CorrectionGrid.build(base, steps=(5, 5, 4)).signal_filters == []
