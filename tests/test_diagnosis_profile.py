"""The fast profile over a nonlinear parameter (all thetas at once, normal equations on the Gram
matrix XᵀX − CᵀC, one error component for a periodic error) against brute force: for each theta
the accepted terms and the candidate fitted jointly by plain least squares (numpy lstsq on the
stacked design, no projection)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.diagnosis import compute_residuals
from cmm_comp.compensation.diagnosis.candidates import all_candidates
from cmm_comp.compensation.diagnosis.fitting import Term, make_problem, profile_rss
from cmm_comp.compensation.machine import Machine
from cmm_comp.sim_controller.true_machine import simulate

NPL = Path(__file__).resolve().parents[1] / "examples" / "machines" / "npl-bridge.toml"


@pytest.fixture(scope="module")
def problem():
    m = Machine.from_toml(NPL)
    _, data = simulate(m, ["periodic", "thermal_lag"], [2.0, 2.0], seed=5, n_points=150)
    return make_problem(compute_residuals(m, data))


def _brute(problem, base, cand, theta, rows):
    x = problem.stacked([*base, Term(cand, theta)], rows)
    y = problem.y[rows].reshape(-1)
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    return float(np.sum((y - x @ beta) ** 2))


@pytest.mark.parametrize("cause", ["periodic", "thermal_lag", "squareness_drift"])
def test_profile_equals_brute_force(problem, cause) -> None:
    cands = [c for c in all_candidates(problem.res) if len(c.thetas) > 1]
    base_c = [c for c in all_candidates(problem.res) if c.cause == "parametric"][:2]
    base = [Term(c) for c in base_c]
    rows = np.flatnonzero(np.arange(problem.res.n) % 4 != 1)  # a training fold
    q = problem.projector(base, rows)
    y = problem.y[rows].reshape(-1)
    tested = 0
    for cand in (c for c in cands if c.cause == cause):
        for rich in (cand, cand.rich):
            if rich is None:
                continue
            thetas = rich.thetas[:: max(1, len(rich.thetas) // 6)]
            rss, rank = profile_rss(problem, rich, thetas, rows, q, y)
            for i, th in enumerate(thetas):
                expect = _brute(problem, base, rich, th, rows)
                assert rss[i] == pytest.approx(expect, rel=1e-6, abs=1e-9 * float(y @ y)), (
                    rich.label,
                    th,
                )
                assert 0 < rank[i] <= rich.n_params
                tested += 1
    assert tested >= 6


def test_periodic_on_an_unmeasured_component_explains_nothing(problem) -> None:
    """A periodic error of z where only x and y were measured: the profile says no gain."""
    from dataclasses import replace

    res = problem.res
    r = res.residual_um.copy()
    r[:, 2] = 0.0
    p2 = make_problem(replace(res, residual_um=r))
    assert 2 not in p2.axes
    cand = next(c for c in all_candidates(res) if c.cause == "periodic" and c.keys["axis"] == "z")
    y = p2.y.reshape(-1)
    rss, rank = profile_rss(p2, cand, cand.thetas[:5], slice(None), None, y)
    np.testing.assert_allclose(rss, float(y @ y))
    assert np.all(rank == 0)


def test_a_start_up_transient_is_extrapolated_back_at_most_twofold(problem) -> None:
    """Held-out rows earlier than every training row get the start-up transient at most at twice
    its value at the first training time (a first-order decay seen by later blocks fixes its
    size only where it had not decayed much; the state at the start of a fast one they did not
    see is unknown); the lag law itself is kept, and rows inside the training span keep the
    transient."""
    from cmm_comp.compensation.diagnosis.fitting import _held_out_design

    lag = next(c for c in all_candidates(problem.res) if c.cause == "thermal_lag")
    assert lag.transient_columns == (0, 1, 2)
    t = problem.res.signals["t"]
    order = np.argsort(t)
    early, late = order[: len(t) // 3], order[len(t) // 3 :]
    tau = 1800.0
    term = Term(lag, tau)
    plain = problem.stacked([term], early)
    held = _held_out_design(problem, [term], late, early)
    cols = problem.n_nuisance + np.arange(3)
    assert np.abs(plain[:, cols]).max() > 0
    # the transient of each row at the first training time, by the e-folding law
    t_lo = float(np.min(t[late]))
    n_ax = len(problem.axes)
    t_rows = np.repeat(t[early], n_ax)
    at_lo = plain[:, cols] * np.exp(-(t_lo - t_rows) / tau)[:, None]
    within = t_rows >= t_lo - tau * np.log(2.0)
    assert within.any() and (~within).any()  # both kinds of rows are checked
    np.testing.assert_allclose(held[within][:, cols], plain[within][:, cols], rtol=1e-12)
    np.testing.assert_allclose(held[~within][:, cols], 2.0 * at_lo[~within], rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(held[:, problem.n_nuisance + 3], plain[:, problem.n_nuisance + 3])
    inside = _held_out_design(problem, [term], early, late[: len(late) // 2])
    np.testing.assert_array_equal(inside, problem.stacked([term], late[: len(late) // 2]))


def test_time_folds_never_hide_a_position_of_a_repeated_cycle() -> None:
    """An ISO 230-2 run repeats one cycle of positions (9 targets out and back, 5 cycles: 90
    points in time order). Time blocks dealt to the folds in turn would give each fold the
    same phase of every cycle — targets no training fold ever saw. Brute force: every position
    of every time fold is measured somewhere in the other folds."""
    m = Machine.from_toml(NPL)
    _, data = simulate(m, [], [], seed=5, n_points=150)
    data = data.subset(np.arange(90))
    targets = np.linspace(100.0, 900.0, 9)
    cycle = np.concatenate([targets, targets[::-1]])
    x = np.tile(cycle, 5)
    for arr in (data.indicated_mm, data.reference_mm):
        arr[:, 0] = x
    data.t_s = np.arange(90, dtype=float) * 20.0
    problem = make_problem(compute_residuals(m, data))
    assert problem.time_folds is not None
    for fold in problem.time_folds:
        train = np.setdiff1d(np.arange(90), fold)
        assert set(np.round(x[fold], 6)) <= set(np.round(x[train], 6))
