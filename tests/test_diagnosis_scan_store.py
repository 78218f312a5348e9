"""Work the diagnosis keeps instead of redoing, against what it must equal. The period scans'
kept columns (``candidate.kept_scan``): what a periodic or a reference reading candidate returns
for a block of periods is, bit for bit, the columns computed afresh by the same formula written
out here (cos/sin of 2π·q/period minus their value at the reference point), whether it is the
first call or a repeat; kept columns cannot be written to; another data set gets its own
columns. A cross-validation fold's training rows (kept per fold): a set difference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.diagnosis import compute_residuals
from cmm_comp.compensation.diagnosis.candidate import SCAN_STORE_VALUES, kept_scan
from cmm_comp.compensation.diagnosis.candidates import all_candidates
from cmm_comp.compensation.machine import Machine
from cmm_comp.sim_controller.true_machine import simulate

NPL = Path(__file__).resolve().parents[1] / "examples" / "machines" / "npl-bridge.toml"


def _residuals(seed: int):
    m = Machine.from_toml(NPL)
    _, data = simulate(m, ["periodic"], [2.0], seed=seed, n_points=120)
    return compute_residuals(m, data)


def _oracle(res, k: int, periods, harmonics: int) -> np.ndarray:
    """(N, T, 2H) columns written out in numpy, one period and harmonic at a time."""
    q = res.q_mm[:, k]
    ref = float(res.machine.volume.reference_mm[k])
    out = np.empty((len(q), len(periods), 2 * harmonics))
    for j, p in enumerate(periods):
        for h in range(1, harmonics + 1):
            w = h * 2.0 * np.pi / float(p)
            out[:, j, 2 * h - 2] = np.cos(w * q) - np.cos(w * ref)
            out[:, j, 2 * h - 1] = np.sin(w * q) - np.sin(w * ref)
    return out


def test_periodic_scan_is_the_same_when_repeated() -> None:
    res = _residuals(3)
    cands = [c for c in all_candidates(res) if c.cause == "periodic" and c.design_many]
    assert cands
    for cand in cands:
        k = cand.design_component
        harmonics = cand.n_params // 2
        block = cand.thetas[:40]
        first = cand.design_many(res, block)
        again = cand.design_many(res, block)
        expected = _oracle(res, k, block, harmonics)
        np.testing.assert_allclose(first, expected, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(again, first)
        with pytest.raises(ValueError):
            again[0, 0, 0] = 1.0  # kept columns are read-only
        # another data set (same candidate): its own columns, not the kept ones
        other = _residuals(4)
        np.testing.assert_allclose(
            cand.design_many(other, block), _oracle(other, k, block, harmonics), atol=1e-12
        )


def test_store_is_bounded_and_recomputes_beyond_it() -> None:
    calls: list[int] = []

    def design(_res, thetas):
        calls.append(len(thetas))
        return np.ones((1000, len(thetas), 2))

    scan = kept_scan(design)
    res = object()
    big = tuple(range(SCAN_STORE_VALUES // 2000 + 1))  # more values than the store holds
    scan(res, big)
    scan(res, big)
    assert len(calls) == 2  # never kept: computed each time
    small = (1.0, 2.0)
    x = scan(res, small)
    assert scan(res, small) is x and len(calls) == 3
    assert scan(object(), small) is not x and len(calls) == 4  # another data set


def test_training_rows_are_the_rows_not_held_out() -> None:
    """``Problem.training_rows`` (kept per fold) against a set difference written out."""
    from cmm_comp.compensation.diagnosis.fitting import make_problem

    problem = make_problem(_residuals(3))
    for test in problem.folds:
        expected = sorted(set(range(problem.res.n)) - set(test.tolist()))
        first = problem.training_rows(test)
        assert first.tolist() == expected
        assert problem.training_rows(test.copy()) is first  # same fold: kept
        with pytest.raises(ValueError):
            first[0] = -1
