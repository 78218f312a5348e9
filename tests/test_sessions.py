"""Simulated sessions and the true machine: design properties and the hidden truth's size."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.machine import Machine
from cmm_comp.sim_controller.sessions import plan_session, true_error_um
from cmm_comp.sim_controller.true_machine import HIDDEN_CAUSES, effect_rms_um, simulate

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"


def test_session_design() -> None:
    m = Machine.from_toml(NPL)
    d = plan_session(m, np.random.default_rng(5)).data
    assert 600 <= d.n <= 800
    assert np.all(m.volume.contains(d.indicated_mm))
    assert np.all(np.diff(d.t_s) >= 0) and d.t_s[-1] > 3 * 3600
    for k in ("dir_x", "dir_y", "dir_z"):
        assert set(np.unique(d.directions[k])) == {-1.0, 1.0}
    for k in ("T_x", "T_y", "T_z", "T_air", "T_wp"):
        assert d.temps_C[k].min() < 20.0 < d.temps_C[k].max()  # crosses the reference
    grad = d.temps_C["T_top"] - d.temps_C["T_bottom"]
    assert np.ptp(grad) > 0.2
    # thermal signals are not collinear (so their causes can be told apart)
    assert abs(np.corrcoef(grad, d.temps_C["T_air"])[0, 1]) < 0.95
    assert len(np.unique(d.group)) >= 15
    assert len({tuple(p) for p in d.stylus_mm}) >= 2
    np.testing.assert_allclose(np.linalg.norm(d.normals, axis=1), 1.0)


@pytest.mark.parametrize("cause", HIDDEN_CAUSES)
def test_hidden_effect_has_requested_size_and_noise_is_noise(cause) -> None:
    m = Machine.from_toml(NPL)
    truth, data = simulate(m, [cause], [2.0], seed=7, noise_um=0.5)
    assert effect_rms_um(m, truth.hidden[0], data) == pytest.approx(
        2.0 * truth.noise_rms_3d_um, rel=1e-3
    )
    noise = data.observed_error_um() - true_error_um(truth.machine, data)
    assert np.std(noise) == pytest.approx(0.5, rel=0.1)
    assert abs(np.mean(noise)) < 0.05
