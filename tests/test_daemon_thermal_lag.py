"""A thermal lag found by model discovery reaches the daemon: the grid carries the filter and the
daemon feeds the grid lagged temperatures. Oracle: the batch lag filter of the model
(``compensation.thermal.lag_filter``, itself checked against an ODE solution) on the same samples."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmm_comp.compensation.thermal import FirstOrderLag, SignalFilter, lag_filter
from cmm_comp.daemon.config import TemperaturesSection
from cmm_comp.daemon.temperatures import TemperatureTable


def test_value_at_holds_the_input_between_samples() -> None:
    lag = FirstOrderLag(100.0)
    assert math.isnan(lag.value_at(0.0))
    lag.update(0.0, 20.0)
    lag.update(10.0, 20.0)
    lag.update(10.0 + 1e-9, 25.0)  # a step
    # held at 25 °C from t = 10 s: y = 25 + (20 − 25)·exp(−h/τ)
    assert lag.value_at(110.0) == pytest.approx(25 - 5 * math.exp(-1), abs=1e-6)


def test_daemon_temperatures_follow_the_grid_filter() -> None:
    cfg = TemperaturesSection()
    table = TemperatureTable(cfg, {0: "T_x", 1: "T_y"})
    tau, weight = 600.0, 0.7
    filters = [
        SignalFilter.from_header(
            {
                "kind": "first_order_lag",
                "signals": ["T_x", "T_y", "T_z"],
                "time_constant_s": tau,
                "fraction": weight,
            }
        )
    ]
    t = np.arange(0.0, 3600.0, 5.0)
    temp = 20.0 + 2.0 * np.sin(t / 900.0) + 0.0005 * t  # a slow drift, within the rate limit
    got = []
    for k, (ts, tc) in enumerate(zip(t, temp, strict=True)):
        table.update(0, float(tc), k, True, float(ts))
        table.update(1, 21.0, k, True, float(ts))
        verdict = table.inputs(("T_x", "T_y"), float(ts))
        assert verdict.status is None
        got.append(table.effective(verdict.temps_C, filters, float(ts)))
    lagged = lag_filter(t, temp, tau)
    expected = temp + weight * (lagged - temp)
    np.testing.assert_allclose([g["T_x"] for g in got], expected, atol=1e-9)
    assert all(g["T_y"] == pytest.approx(21.0) for g in got)  # constant input: lag = input
    assert table.effective({"T_wp": 23.0}, filters, 10.0) == {"T_wp": 23.0}  # not filtered
