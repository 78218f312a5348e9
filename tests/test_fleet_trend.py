"""compensation.trend: the change tests against scipy and brute force, the stated false-alarm
rate by Monte Carlo, and effects taken generically (causes and keys the code never saw)."""

from __future__ import annotations

import itertools
from datetime import date, timedelta

import numpy as np
import pytest
from scipy import stats

from cmm_comp.compensation.trend import (
    SessionEffects,
    effect_identity,
    line_fit,
    machine_trend,
    numeric_parameters,
    presence_change,
    smallest_presence_p,
    step_change,
    trend_change,
)


def test_line_fit_and_trend_p_equal_scipy_linregress() -> None:
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 80, 11))
    v = 0.05 * t + rng.normal(0, 0.3, t.size)
    ref = stats.linregress(t, v)
    p, fit = trend_change(t, v)
    assert fit is not None
    assert fit.slope == pytest.approx(ref.slope, rel=1e-12)
    assert fit.u_slope == pytest.approx(ref.stderr, rel=1e-10)
    assert fit.at(0.0)[0] == pytest.approx(ref.intercept, rel=1e-10)
    assert p == pytest.approx(ref.pvalue, rel=1e-8)
    assert line_fit(t[:2], v[:2]) is None


def _g_by_scipy(x: tuple[int, ...]) -> float:
    """Largest G-test statistic over splits, from scipy's contingency table G-test."""
    n, best = len(x), 0.0
    for k in range(1, n):
        a, b = sum(x[:k]), sum(x[k:])
        table = np.array([[a, k - a], [b, n - k - b]], dtype=float)
        if (table.sum(axis=0) == 0).any() or (table.sum(axis=1) == 0).any():
            continue
        g = stats.chi2_contingency(table, correction=False, lambda_="log-likelihood")[0]
        best = max(best, float(g))
    return best


@pytest.mark.parametrize(
    "series",
    [(0, 0, 0, 0, 0, 1, 1, 1, 1, 1), (1, 0, 1, 1, 0, 0, 1, 0, 0), (0, 1, 0, 0, 1, 1, 1, 1)],
)
def test_presence_p_equals_brute_force_over_arrangements(series: tuple[int, ...]) -> None:
    observed = _g_by_scipy(series)
    arrangements = set(itertools.permutations(series))
    hits = sum(_g_by_scipy(a) >= observed - 1e-9 for a in arrangements)
    result = presence_change(np.array(series))
    assert result.exact
    assert result.p_value == pytest.approx(hits / len(arrangements), abs=1e-12)


def test_presence_perfect_split_and_its_floor() -> None:
    r = presence_change(np.array([0] * 6 + [1] * 6))
    assert r.p_value == pytest.approx(2 / 924)  # the two most extreme of C(12, 6)
    assert (r.split, r.before, r.after) == (6, 0, 6)
    assert smallest_presence_p(12) == pytest.approx(2 / 924)
    assert presence_change(np.ones(7)).p_value == 1.0
    big = presence_change(np.array([0] * 20 + [1] * 20))  # Monte Carlo branch
    assert not big.exact and big.p_value < 1e-3


def test_step_p_is_bonferroni_of_scipy_ttest() -> None:
    rng = np.random.default_rng(5)
    v = np.r_[rng.normal(1.0, 0.1, 6), rng.normal(1.6, 0.1, 7)]
    step = step_change(v)
    assert step is not None and step.split == 6
    ref = stats.ttest_ind(v[6:], v[:6], equal_var=True)
    assert step.p_value == pytest.approx(min(1.0, ref.pvalue * (len(v) - 3)), rel=1e-8)
    assert step.before == pytest.approx(v[:6].mean()) and step.after == pytest.approx(v[6:].mean())


def _sessions(
    named: np.ndarray, params: dict[str, np.ndarray], entry: dict
) -> list[SessionEffects]:
    start = date(2026, 1, 5)
    out = []
    for i, on in enumerate(named):
        effects = []
        if on:
            effects.append({**entry, "parameters": {k: float(v[i]) for k, v in params.items()}})
        out.append(SessionEffects(start + timedelta(days=7 * i), f"m/{i}", effects))
    return out


@pytest.mark.slow  # soak-like: a statistical claim over many seeds (tests/README.md rule 8)
def test_false_alarm_rate_by_monte_carlo() -> None:
    """Stable machines (the effect named at random with a fixed chance, parameters scattering
    about fixed values): the share of machines with any change reported stays within the stated
    alpha per effect (binomial 3σ margin over 600 machines)."""
    rng = np.random.default_rng(11)
    alpha, machines, flagged = 0.01, 600, 0
    entry = {"cause": "a_cause_never_seen", "axis": "x", "label": "a_cause_never_seen(axis=x)"}
    for _ in range(machines):
        n = int(rng.integers(8, 30))
        named = rng.random(n) < rng.uniform(0.3, 1.0)
        base = rng.normal(0.0, 1.0, n)
        params = {"amp_um": 2.0 + 0.2 * base, "twice_um": -2 * (2.0 + 0.2 * base),
                  "other": rng.normal(5.0, 0.5, n)}  # fmt: skip
        result = machine_trend("m", _sessions(named, params, entry))
        flagged += bool(result["changes"])
    margin = 3 * np.sqrt(alpha * (1 - alpha) / machines)
    assert flagged / machines <= alpha + margin, flagged


def test_injected_step_and_creep_are_found() -> None:
    rng = np.random.default_rng(2)
    n = 14
    named = np.ones(n, dtype=bool)
    creep = {"value": 0.1 * np.arange(n) * 7 / 7 + rng.normal(0, 0.05, n)}
    step = {"value": np.where(np.arange(n) < 9, 1.0, 1.8) + rng.normal(0, 0.05, n)}
    entry = {"cause": "c", "label": "c()"}
    (c1,) = machine_trend("m", _sessions(named, creep, entry))["changes"]
    assert c1["kind"] == "creep" and c1["rate_per_day"] == pytest.approx(0.1 / 7, rel=0.1)
    (c2,) = machine_trend("m", _sessions(named, step, entry))["changes"]
    assert c2["kind"] == "step" and c2["between"] == ["2026-03-02", "2026-03-09"]


def test_effects_are_taken_generically() -> None:
    entry = {
        "cause": "new_cause",
        "axis": "y",
        "lobes": 3,
        "period_mm": 60.1,  # a fitted number: not part of the identity
        "source": "diagnosis",
        "locked_to": "grid-2026",
        "evidence": {"bic": -3.0, "tests": [1, 2]},
        "parameters": {
            "a_um": 1.0,
            "shape": [0.5, 0.25],
            "nested": {"k": 2},
            "note": "x",
            "flag": True,
            "bad": float("nan"),
        },
    }
    name, cause, keys = effect_identity(entry)
    assert (name, cause, keys) == (
        "new_cause(axis=y,lobes=3)",
        "new_cause",
        {"axis": "y", "lobes": 3},
    )
    assert effect_identity({**entry, "label": "L"})[0] == "L"
    assert numeric_parameters(entry["parameters"]) == {
        "a_um": 1.0, "shape[0]": 0.5, "shape[1]": 0.25, "nested.k": 2.0
    }  # fmt: skip
