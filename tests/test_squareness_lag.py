"""A squareness that follows the air through a lag (issue 11: causes as physical families).

Oracles: a brute-force explicit integration of τ·dT_s/dt = T − T_s, the direct (unlagged) effect
fed that integrated temperature, and the daemon's own runtime filter fed the samples one by one.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_diagnosis import NPL

from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.thermal import SignalFilter, ThermalLagEffect, signal_filters
from cmm_comp.compensation.thermal.distortion import SquarenessDriftEffect
from cmm_comp.compensation.thermal.lag import FirstOrderLag


def npl_machine() -> Machine:
    return Machine.from_toml(NPL)


TAU_S = 1500.0


def _session(n: int = 150) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    t = np.sort(rng.uniform(0.0, 4 * 3600.0, n))
    t[0] = 0.0
    air = 20.0 + 1.5 * np.sin(t / 2500.0) + 0.3 * t / 3600.0
    m = npl_machine()
    lo, hi = m.volume.lower_mm, m.volume.upper_mm
    pts = lo + rng.random((n, 3)) * (hi - lo)
    return t, air, pts


def _integrate(t: np.ndarray, temp: np.ndarray, tau: float) -> np.ndarray:
    """Explicit Euler on a fine grid, started in equilibrium (T_s(0) = T(0))."""
    fine = np.linspace(t[0], t[-1], 400_000)
    drive = np.interp(fine, t, temp)
    y = np.empty_like(fine)
    y[0] = drive[0]
    h = fine[1] - fine[0]
    for i in range(1, len(fine)):
        y[i] = y[i - 1] + h * (drive[i - 1] - y[i - 1]) / tau
    return np.interp(t, fine, y)


def test_lagged_squareness_is_the_direct_one_fed_the_integrated_structure_temperature() -> None:
    t, air, pts = _session()
    base = npl_machine()
    lagged = base.with_effects([SquarenessDriftEffect("beta1", 2.5, time_constant_s=TAU_S)])
    direct = base.with_effects([SquarenessDriftEffect("beta1", 2.5)])
    got = lagged.volumetric_error(pts, None, {"T_air": air}, inputs={"t": t})
    structure = _integrate(t, air, TAU_S)
    want = direct.volumetric_error(pts, None, {"T_air": structure}, inputs={"t": t})
    assert np.max(np.abs(got - want)) < 2e-3 * np.max(np.abs(want - base.volumetric_error(pts)))
    # and it is not the unlagged drift (the lag matters at this τ)
    unlagged = direct.volumetric_error(pts, None, {"T_air": air}, inputs={"t": t})
    assert np.max(np.abs(unlagged - got)) > 0.1


def test_grid_carries_the_lag_and_the_runtime_filter_reproduces_it() -> None:
    eff = SquarenessDriftEffect("alpha", -3.0, time_constant_s=TAU_S)
    assert signal_filters([eff]) == [SignalFilter("first_order_lag", ("T_air",), TAU_S, 1.0)]
    m = npl_machine().with_effects([eff])
    grid = CorrectionGrid.build(m, steps=(4, 4, 4))
    assert [f.signals for f in grid.signal_filters] == [("T_air",)]
    # the daemon's filter, fed sample by sample, gives the integrated structure temperature
    t, air, _ = _session(60)
    lag = FirstOrderLag(TAU_S)
    fed = []
    for ti, ai in zip(t, air, strict=True):
        lag.update(float(ti), float(ai))
        fed.append(lag.value_at(float(ti)))
    np.testing.assert_allclose(fed, _integrate(t, air, TAU_S), atol=2e-3)


def test_round_trip_through_the_machine_file(tmp_path) -> None:
    eff = SquarenessDriftEffect("beta2", 1.25, time_constant_s=900.0)
    m = npl_machine().with_effects([eff])
    path = tmp_path / "m.toml"
    m.to_toml(path)
    back = [e for e in Machine.from_toml(path).effects if isinstance(e, SquarenessDriftEffect)]
    assert len(back) == 1 and back[0].time_constant_s == 900.0 and back[0].urad_per_C == 1.25


def test_two_lags_on_one_signal_are_refused_with_a_reason() -> None:
    a = SquarenessDriftEffect("alpha", 1.0, time_constant_s=600.0)
    b = SquarenessDriftEffect("beta1", 1.0, time_constant_s=1200.0)
    with pytest.raises(ValueError, match="T_air"):
        signal_filters([a, b])
    # different signals are fine: the scale lag filters T_x/T_y/T_z, this one T_air
    assert len(signal_filters([a, ThermalLagEffect(600.0)])) == 2


def test_negative_time_constant_is_refused() -> None:
    with pytest.raises(ValueError, match="time_constant_s"):
        SquarenessDriftEffect("alpha", 1.0, time_constant_s=-5.0)
