"""Straightness criteria: exact min zone against a brute force, hand-built cases, invariants."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cmm_comp.compensation.straightness import (
    CRITERIA,
    END_POINTS,
    LEAST_SQUARES,
    MIN_ZONE,
    apply_criterion,
    reference_line,
    straightness_um,
)


def brute_force_zone_um(s: np.ndarray, e: np.ndarray) -> float:
    """Independent oracle: dense slope grid, then two rounds of local refinement.

    For every slope k the zone width is max − min of e − k·s; the min-zone value is its minimum.
    """
    spread = np.ptp(e) / max(np.ptp(s), 1e-12)
    lo, hi = -4.0 * spread - 1.0, 4.0 * spread + 1.0
    best_k = 0.0
    for _ in range(4):
        ks = np.linspace(lo, hi, 4001)
        resid = e[None, :] - ks[:, None] * s[None, :]
        widths = resid.max(axis=1) - resid.min(axis=1)
        i = int(np.argmin(widths))
        best_k = ks[i]
        step = ks[1] - ks[0]
        lo, hi = best_k - 2 * step, best_k + 2 * step
    r = e - best_k * s
    return float(r.max() - r.min())


profiles = st.integers(min_value=2, max_value=25).flatmap(
    lambda n: st.tuples(
        st.lists(
            st.floats(-500.0, 500.0, allow_nan=False, allow_subnormal=False),
            min_size=n,
            max_size=n,
        ),
        st.lists(
            st.floats(-50.0, 50.0, allow_nan=False, allow_subnormal=False),
            min_size=n,
            max_size=n,
        ),
    )
)


@settings(max_examples=150, deadline=None)
@given(profiles)
# positions 2e-308 mm apart: one position, never a slope of 1e308 (found by hypothesis)
@example(([0.0, 2.0, 2.2250738585072014e-308], [0.0, 0.0, 2.0]))
@example(([0.0, 1.0, 2.2250738585072014e-308], [0.0, 0.0, 4.0]))
def test_min_zone_matches_brute_force(profile: tuple[list[float], list[float]]) -> None:
    s, e = (np.asarray(v) for v in profile)
    if np.ptp(s) < 1e-3:
        s = s + np.arange(s.size)  # need two distinct positions
    exact = straightness_um(s, e, MIN_ZONE)
    brute = brute_force_zone_um(s, e)
    # brute force can only be worse (it is a min over a subset of slopes), and not by much
    assert exact <= brute + 1e-9
    assert brute - exact <= 1e-6 * max(1.0, brute)


@settings(max_examples=100, deadline=None)
@given(profiles)
def test_min_zone_is_smallest_and_end_points_pass_through_ends(
    profile: tuple[list[float], list[float]],
) -> None:
    s, e = (np.asarray(v) for v in profile)
    if np.ptp(s) < 1e-3:
        s = s + np.arange(s.size)
    widths = {c: straightness_um(s, e, c) for c in CRITERIA}
    tol = 1e-9 * max(1.0, float(np.ptp(e)))
    assert widths[MIN_ZONE] <= widths[LEAST_SQUARES] + tol
    assert widths[MIN_ZONE] <= widths[END_POINTS] + tol
    # min-zone residuals are centred: ±width/2
    r = apply_criterion(s, e, MIN_ZONE)
    assert r.max() == pytest.approx(-r.min(), abs=tol)
    # the end-points line passes through the (mean) end values
    k, c = reference_line(s, e, END_POINTS)
    for end in (s.min(), s.max()):
        assert k * end + c == pytest.approx(e[s == end].mean(), abs=1e-9 * max(1.0, abs(k) * 500))


def test_v_shape_is_exact() -> None:
    # V: e = |s| on s = -2..2. Min zone: horizontal lines 0 and 2 → width 2, mid-line e = 1.
    s = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
    e = np.abs(s)
    assert straightness_um(s, e, MIN_ZONE) == 2.0
    assert reference_line(s, e, MIN_ZONE) == (0.0, 1.0)
    # end points (−2,2) and (2,2): horizontal line at 2 → residuals 0..−2, width 2 too
    assert reference_line(s, e, END_POINTS) == (0.0, 2.0)
    # least squares: slope 0, intercept mean 1.2 → residuals from −1.2 to 0.8, width 2
    k, c = reference_line(s, e, LEAST_SQUARES)
    assert (k, c) == pytest.approx((0.0, 1.2))


def test_tilted_line_with_one_outlier() -> None:
    # points on e = 3 s + 5 except one raised by 4 µm: min zone is exactly 4 µm wide
    s = np.linspace(0.0, 100.0, 11)
    e = 3.0 * s + 5.0
    e[4] += 4.0
    assert straightness_um(s, e, MIN_ZONE) == pytest.approx(4.0, abs=1e-9)
    k, c = reference_line(s, e, MIN_ZONE)
    assert k == pytest.approx(3.0)
    assert c == pytest.approx(7.0)
    # a straight line has zero straightness under every criterion
    for crit in CRITERIA:
        assert straightness_um(s, 3.0 * s + 5.0, crit) == pytest.approx(0.0, abs=1e-9)


def test_least_squares_matches_polyfit() -> None:
    rng = np.random.default_rng(7)
    s = np.sort(rng.uniform(0, 900, 30))
    e = rng.normal(0, 2, 30) + 0.01 * s
    k, c = reference_line(s, e, LEAST_SQUARES)
    k_ref, c_ref = np.polyfit(s, e, 1)
    assert (k, c) == pytest.approx((k_ref, c_ref), rel=1e-9)


def test_bad_input_is_named() -> None:
    with pytest.raises(ValueError, match=r"'minimum_zone'.*least_squares, end_points, min_zone"):
        straightness_um([0, 1], [0, 1], "minimum_zone")
    with pytest.raises(ValueError, match="two distinct positions"):
        straightness_um([1.0, 1.0], [0.0, 1.0], MIN_ZONE)
    with pytest.raises(ValueError, match="shapes"):
        straightness_um([0.0, 1.0, 2.0], [0.0, 1.0], MIN_ZONE)
    with pytest.raises(ValueError, match="finite"):
        straightness_um([0.0, 1.0], [0.0, np.nan], LEAST_SQUARES)
