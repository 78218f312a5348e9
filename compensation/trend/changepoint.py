"""Change tests on one effect's series: did it appear or vanish, does a parameter creep or jump.

Three tests, each returning a p-value that is valid (≤ its nominal level under its null) for any
number of sessions:

* :func:`presence_change`: is the 0/1 series "named in session i" exchangeable (the chance of
  naming the effect the same in every session), against "it changed once"? Statistic: the
  largest binomial likelihood-ratio G over every split point; p-value from the exact conditional
  distribution given the number of sessions that named it (every arrangement enumerated up to
  :data:`EXACT_MAX_SESSIONS` sessions, else :data:`PERMUTATIONS` random ones with a fixed seed). No
  distributional assumption; with few sessions the smallest p-value reachable is
  ``2 / C(n, n/2)`` (:func:`smallest_presence_p`), so a change cannot be shown on too short a
  series — it is said, never guessed.
* :func:`trend_change`: a straight line in time through the values of the sessions that named
  the effect; two-sided t-test of its slope (Gaussian scatter about the line, n − 2 degrees of
  freedom).
* :func:`step_change`: one jump: for every split with ≥ 2 values each side a pooled two-sample
  t-test; the smallest p-value times the number of splits (Bonferroni, so valid for the chosen
  split).

The uncertainty of every figure is the session-to-session scatter (Type A): a diagnosis reports a
parameter without its uncertainty, and the scatter between sessions is the one that matters for a
trend anyway (it holds the reproducibility of the session itself).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

__all__ = [
    "EXACT_MAX_SESSIONS",
    "PERMUTATIONS",
    "LineFit",
    "PresenceChange",
    "StepChange",
    "line_fit",
    "presence_change",
    "smallest_presence_p",
    "step_change",
    "trend_change",
]

EXACT_MAX_SESSIONS = 18
"""Up to this many sessions the presence test enumerates every arrangement (exact p-value)."""
PERMUTATIONS = 20_000
"""Random arrangements drawn beyond :data:`EXACT_MAX_SESSIONS` (seeded: the same series gives the same
p-value); the p-value is then ``(1 + count) / (1 + PERMUTATIONS)``."""


@dataclass(frozen=True)
class PresenceChange:
    """Best split of a 0/1 series: sessions ``[:split]`` vs ``[split:]``."""

    p_value: float
    split: int
    before: int
    """Sessions before the split that named the effect (of ``split``)."""
    after: int
    """Sessions from the split on that named it (of ``n − split``)."""
    n: int
    exact: bool


def _xlogx(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(x > 0, x * np.log(np.where(x > 0, x, 1.0)), 0.0)


def _max_g(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a (R, n) 0/1 matrix: the largest binomial G over splits 1…n−1, and where."""
    n = rows.shape[1]
    k = np.arange(1, n)
    a = np.cumsum(rows, axis=1)[:, :-1].astype(float)  # named before each split
    m = rows.sum(axis=1, keepdims=True).astype(float)
    b = m - a
    ll = (
        _xlogx(a)
        + _xlogx(k - a)
        - _xlogx(k + 0.0)
        + _xlogx(b)
        + _xlogx(n - k - b)
        - _xlogx(n - k + 0.0)
    )
    ll0 = _xlogx(m) + _xlogx(n - m) - _xlogx(np.full_like(m, n))
    g = 2.0 * (ll - ll0)
    best = np.argmax(g, axis=1)
    return g[np.arange(len(rows)), best], best + 1


def presence_change(named: np.ndarray, seed: int = 0) -> PresenceChange:
    """Test a 0/1 series for one change of the naming rate (module docstring)."""
    x = np.asarray(named, dtype=np.int8)
    n, m = len(x), int(x.sum())
    if n < 2 or m in (0, n):
        return PresenceChange(1.0, 0, 0, m, n, True)
    g_obs, split = _max_g(x[None, :])
    count = math.comb(n, m)
    exact = n <= EXACT_MAX_SESSIONS
    if exact:  # every n-bit pattern with m ones
        codes = np.arange(1 << n, dtype=np.uint32)
        bits = ((codes[:, None] >> np.arange(n, dtype=np.uint32)) & 1).astype(np.int8)
        rows = bits[bits.sum(axis=1) == m]
    else:
        rng = np.random.default_rng(seed)
        rows = rng.permuted(np.tile(x, (PERMUTATIONS, 1)), axis=1)
    g_null, _ = _max_g(rows)
    hits = int(np.sum(g_null >= g_obs[0] - 1e-9))
    p = hits / count if exact else (1 + hits) / (1 + PERMUTATIONS)
    s = int(split[0])
    return PresenceChange(float(p), s, int(x[:s].sum()), int(x[s:].sum()), n, exact)


def smallest_presence_p(n: int) -> float:
    """The smallest p-value :func:`presence_change` can give on ``n`` sessions (the two most
    extreme arrangements of ``n/2`` sessions): a change is undetectable at a level below it."""
    if n < 2:
        return 1.0
    return min(1.0, 2.0 / math.comb(n, n // 2))


@dataclass(frozen=True)
class LineFit:
    """``value = intercept + slope · (t − t_mean)`` with standard uncertainties (k = 1)."""

    slope: float
    u_slope: float
    intercept: float
    t_mean: float
    residual_sd: float
    n: int

    def at(self, t: float) -> tuple[float, float]:
        """The line at ``t`` and its standard uncertainty."""
        value = self.intercept + self.slope * (t - self.t_mean)
        u_mean = self.residual_sd / math.sqrt(self.n)
        return value, math.hypot(u_mean, self.u_slope * (t - self.t_mean))


def line_fit(t: np.ndarray, v: np.ndarray) -> LineFit | None:
    """Least-squares line through ≥ 3 points (None with fewer or a single time)."""
    t, v = np.asarray(t, float), np.asarray(v, float)
    n = len(t)
    if n < 3 or np.ptp(t) == 0:
        return None
    tm = float(t.mean())
    dt = t - tm
    sxx = float(dt @ dt)
    slope = float(dt @ (v - v.mean())) / sxx
    intercept = float(v.mean())
    resid = v - intercept - slope * dt
    sd = math.sqrt(float(resid @ resid) / (n - 2))
    return LineFit(slope, sd / math.sqrt(sxx), intercept, tm, sd, n)


def trend_change(t: np.ndarray, v: np.ndarray) -> tuple[float, LineFit | None]:
    """Two-sided p-value of the slope of :func:`line_fit` (1.0 with fewer than 4 points)."""
    fit = line_fit(t, v)
    if fit is None or fit.n < 4:
        return 1.0, fit
    if fit.u_slope == 0.0:
        return (0.0 if fit.slope != 0.0 else 1.0), fit
    tstat = fit.slope / fit.u_slope
    return float(2.0 * stats.t.sf(abs(tstat), fit.n - 2)), fit


@dataclass(frozen=True)
class StepChange:
    """The best single jump: values ``[:split]`` vs ``[split:]`` (means and standard
    uncertainties, k = 1; pooled scatter)."""

    p_value: float
    split: int
    before: float
    u_before: float
    after: float
    u_after: float
    rss: float


def step_change(v: np.ndarray) -> StepChange | None:
    """Bonferroni-corrected best split of ``v`` into two constant parts (None below 4 values)."""
    v = np.asarray(v, float)
    n = len(v)
    if n < 4:
        return None
    best: StepChange | None = None
    splits = range(2, n - 1)
    for k in splits:
        a, b = v[:k], v[k:]
        rss = float(np.sum((a - a.mean()) ** 2) + np.sum((b - b.mean()) ** 2))
        sd = math.sqrt(rss / (n - 2))
        diff = float(b.mean() - a.mean())
        se = sd * math.sqrt(1.0 / len(a) + 1.0 / len(b))
        if se == 0.0:
            p = 0.0 if diff != 0.0 else 1.0
        else:
            p = float(2.0 * stats.t.sf(abs(diff) / se, n - 2))
        if best is None or p < best.p_value:
            best = StepChange(
                p,
                k,
                float(a.mean()),
                sd / math.sqrt(len(a)),
                float(b.mean()),
                sd / math.sqrt(len(b)),
                rss,
            )
    assert best is not None
    return StepChange(
        min(1.0, best.p_value * len(splits)),
        best.split,
        best.before,
        best.u_before,
        best.after,
        best.u_after,
        best.rss,
    )
