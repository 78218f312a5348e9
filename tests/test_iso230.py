"""ISO 230-2 evaluator: a hand-computed case, a plain-loop oracle, invariants, report and plot."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_comp.compensation.reports.iso230 import evaluate_iso230, format_iso230_report, plot_iso230


def _hand_case() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    target = np.array([0.0, 10.0, 20.0])
    dev_up = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [-1.0, -3.0, -2.0]])  # µm
    dev_down = np.array([[5.0, 6.0, 7.0], [2.0, 4.0, 6.0], [0.0, 0.0, 0.0]])
    return target, target[:, None] + dev_up / 1000, target[:, None] + dev_down / 1000


def test_hand_computed_example() -> None:
    # Worked by hand (docs/iso230.md formulas):
    # x̄↑ = [2, 0, −2], s↑ = [1, 0, 1]; x̄↓ = [6, 4, 0], s↓ = [1, 2, 0]
    # B_i = [−4, −4, −2] → B = 4, B̄ = −10/3; x̄ = [4, 2, −1] → M = 5
    # R↑_i = [4, 0, 4], R↓_i = [4, 8, 0], R_i = [2+2+4, max(0+4+4, 8), max(2+0+2, 4)] = [8, 8, 4]
    # E↑ = 4, E↓ = 6, E = 6 − (−2) = 8
    # A↑ = max(4, 0, 0) − min(0, 0, −4) = 8; A↓ = max(8, 8, 0) − min(4, 0, 0) = 8
    # A = max(4, 8) − min(−4, 0) = 12
    r = evaluate_iso230(*_hand_case())
    approx = pytest.approx
    assert r.mean_fwd_um == approx([2.0, 0.0, -2.0], abs=1e-9)
    assert r.mean_bwd_um == approx([6.0, 4.0, 0.0], abs=1e-9)
    assert r.s_fwd_um == approx([1.0, 0.0, 1.0], abs=1e-9)
    assert r.s_bwd_um == approx([1.0, 2.0, 0.0], abs=1e-9)
    assert r.reversal_um == approx([-4.0, -4.0, -2.0], abs=1e-9)
    assert r.repeat_bidir_um == approx([8.0, 8.0, 4.0], abs=1e-9)
    expected = {
        "B_um": 4.0,
        "B_mean_um": -10.0 / 3.0,
        "M_um": 5.0,
        "R_fwd_um": 4.0,
        "R_bwd_um": 8.0,
        "R_um": 8.0,
        "E_fwd_um": 4.0,
        "E_bwd_um": 6.0,
        "E_um": 8.0,
        "A_fwd_um": 8.0,
        "A_bwd_um": 8.0,
        "A_um": 12.0,
    }
    for key, value in expected.items():
        assert getattr(r, key) == approx(value, abs=1e-9), key


def _oracle(target: list[float], up: list[list[float]], down: list[list[float]]) -> dict:
    """Independent plain-loop implementation of ISO 230-2:2014 (µm out, mm in)."""
    m = len(target)

    def stats(runs: list[list[float]]) -> tuple[list[float], list[float]]:
        means, sds = [], []
        for i in range(m):
            xs = [(v - target[i]) * 1000.0 for v in runs[i]]
            mu = sum(xs) / len(xs)
            means.append(mu)
            sds.append(math.sqrt(sum((x - mu) ** 2 for x in xs) / (len(xs) - 1)))
        return means, sds

    mu_u, s_u = stats(up)
    mu_d, s_d = stats(down)
    b = [mu_u[i] - mu_d[i] for i in range(m)]
    r_i = [max(2 * s_u[i] + 2 * s_d[i] + abs(b[i]), 4 * s_u[i], 4 * s_d[i]) for i in range(m)]
    mid = [(mu_u[i] + mu_d[i]) / 2 for i in range(m)]
    return {
        "B_um": max(abs(v) for v in b),
        "B_mean_um": sum(b) / m,
        "R_fwd_um": max(4 * v for v in s_u),
        "R_bwd_um": max(4 * v for v in s_d),
        "R_um": max(r_i),
        "E_fwd_um": max(mu_u) - min(mu_u),
        "E_bwd_um": max(mu_d) - min(mu_d),
        "E_um": max(mu_u + mu_d) - min(mu_u + mu_d),
        "M_um": max(mid) - min(mid),
        "A_fwd_um": max(mu_u[i] + 2 * s_u[i] for i in range(m))
        - min(mu_u[i] - 2 * s_u[i] for i in range(m)),
        "A_bwd_um": max(mu_d[i] + 2 * s_d[i] for i in range(m))
        - min(mu_d[i] - 2 * s_d[i] for i in range(m)),
        "A_um": max(max(mu_u[i] + 2 * s_u[i], mu_d[i] + 2 * s_d[i]) for i in range(m))
        - min(min(mu_u[i] - 2 * s_u[i], mu_d[i] - 2 * s_d[i]) for i in range(m)),
    }


runs = st.tuples(st.integers(2, 8), st.integers(2, 6), st.integers(0, 2**32 - 1))


def _random_run(m: int, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    target = np.sort(rng.uniform(-500, 500, m)) + np.arange(m)
    systematic = rng.normal(0, 0.02, m)
    reversal = rng.normal(0, 0.01, m)
    up = target[:, None] + (systematic + reversal)[:, None] + rng.normal(0, 0.003, (m, n))
    down = target[:, None] + (systematic - reversal)[:, None] + rng.normal(0, 0.003, (m, n))
    return target, up, down


@settings(max_examples=60, deadline=None)
@given(runs)
def test_matches_plain_loop_oracle_and_invariants(args: tuple[int, int, int]) -> None:
    target, up, down = _random_run(*args)
    r = evaluate_iso230(target, up, down)
    want = _oracle(target.tolist(), up.tolist(), down.tolist())
    for key, value in want.items():
        assert getattr(r, key) == pytest.approx(value, rel=1e-9, abs=1e-9), key
    tol = 1e-9
    assert r.E_um >= max(r.E_fwd_um, r.E_bwd_um, r.M_um) - tol
    assert r.A_um >= max(r.A_fwd_um, r.A_bwd_um, r.E_um) - tol
    assert r.A_fwd_um >= r.E_fwd_um - tol and r.A_bwd_um >= r.E_bwd_um - tol
    assert r.R_um >= max(r.R_fwd_um, r.R_bwd_um, r.B_um) - tol
    assert r.B_um >= abs(r.B_mean_um) - tol
    # swapping the directions flips the reversal and swaps ↑/↓, the rest is unchanged
    s = evaluate_iso230(target, down, up)
    assert s.reversal_um == pytest.approx(-r.reversal_um)
    assert (s.E_fwd_um, s.R_fwd_um, s.A_fwd_um) == pytest.approx(
        (r.E_bwd_um, r.R_bwd_um, r.A_bwd_um)
    )
    assert (s.A_um, s.E_um, s.M_um, s.R_um, s.B_um) == pytest.approx(
        (r.A_um, r.E_um, r.M_um, r.R_um, r.B_um)
    )


def test_to_dict_is_json_ready() -> None:
    d = evaluate_iso230(*_hand_case()).to_dict()
    again = json.loads(json.dumps(d))
    assert again["A_um"] == pytest.approx(12.0)
    assert again["mean_bidir_um"] == pytest.approx([4.0, 2.0, -1.0])
    assert len(again["deviation_fwd_um"]) == 3 and len(again["deviation_fwd_um"][0]) == 3


def test_report_and_plot(tmp_path) -> None:
    r = evaluate_iso230(*_hand_case())
    text = format_iso230_report(r, title="hand case")
    assert text.startswith("# hand case")
    assert "| A | 12.000 |" in text and "| E | 8.000 |" in text and "| B̄ | -3.333 |" in text
    assert text.count("\n| ") >= 12 + 3
    out = plot_iso230(r, tmp_path / "hand.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_shapes_are_named() -> None:
    target, up, down = _hand_case()
    with pytest.raises(ValueError, match=r"forward measurements must have shape \(positions=3"):
        evaluate_iso230(target, up[:2], down)
    with pytest.raises(ValueError, match="same cycles"):
        evaluate_iso230(target, up, down[:, :2])
    with pytest.raises(ValueError, match="finite"):
        evaluate_iso230(target, np.where(up > 5, np.nan, up), down)
