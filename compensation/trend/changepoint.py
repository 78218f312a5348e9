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

import functools
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
    tab = _xlogx(np.arange(n + 1, dtype=float))  # x·log x of every count that can occur
    k = np.arange(1, n)
    a = np.cumsum(rows, axis=1, dtype=np.int32)[:, :-1]  # named before each split
    m = a[:, -1:] + rows[:, -1:]
    b = m - a
    ll = tab[a] + tab[k - a] - tab[k] + tab[b] + tab[n - k - b] - tab[n - k]
    ll0 = tab[m] + tab[n - m] - tab[n]
    g = 2.0 * (ll - ll0)
    best = np.argmax(g, axis=1)
    return g[np.arange(len(rows)), best], best + 1


@functools.lru_cache(maxsize=512)
def _null_g(n: int, m: int, seed: int) -> tuple[np.ndarray, bool]:
    """The sorted null distribution of the statistic for ``m`` named of ``n`` (it depends on
    nothing else): every arrangement, or :data:`PERMUTATIONS` random ones."""
    if n <= EXACT_MAX_SESSIONS:  # every n-bit pattern with m ones
        codes = np.arange(1 << n, dtype=np.uint32)
        bits = ((codes[:, None] >> np.arange(n, dtype=np.uint32)) & 1).astype(np.int8)
        rows = bits[bits.sum(axis=1) == m]
        exact = True
    else:
        x = np.zeros(n, dtype=np.int8)
        x[:m] = 1
        rows = np.random.default_rng(seed).permuted(np.tile(x, (PERMUTATIONS, 1)), axis=1)
        exact = False
    g, _ = _max_g(rows)
    g.sort()
    g.flags.writeable = False
    return g, exact


def presence_change(named: np.ndarray, seed: int = 0) -> PresenceChange:
    """Test a 0/1 series for one change of the naming rate (module docstring)."""
    x = np.asarray(named, dtype=np.int8)
    n, m = len(x), int(x.sum())
    if n < 2 or m in (0, n):
        return PresenceChange(1.0, 0, 0, m, n, True)
    g_obs, split = _max_g(x[None, :])
    g_null, exact = _null_g(n, m, seed)
    hits = len(g_null) - int(np.searchsorted(g_null, g_obs[0] - 1e-9, side="left"))
    p = hits / len(g_null) if exact else (1 + hits) / (1 + len(g_null))
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
    k = np.arange(2, n - 1)  # values before each split (≥ 2 each side)
    centre = float(v.mean())  # sums of squares about the mean: no cancellation
    c1, c2 = np.cumsum(v - centre), np.cumsum((v - centre) ** 2)
    mean_a = c1[k - 1] / k
    mean_b = (c1[-1] - c1[k - 1]) / (n - k)
    rss_a = c2[k - 1] - k * mean_a**2
    rss_b = (c2[-1] - c2[k - 1]) - (n - k) * mean_b**2
    rss = np.maximum(rss_a + rss_b, 0.0)
    sd = np.sqrt(rss / (n - 2))
    se = sd * np.sqrt(1.0 / k + 1.0 / (n - k))
    diff = np.abs(mean_b - mean_a)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(se > 0, 2.0 * stats.t.sf(diff / se, n - 2), np.where(diff > 0, 0.0, 1.0))
    i = int(np.argmin(p))
    return StepChange(
        min(1.0, float(p[i]) * len(k)),
        int(k[i]),
        float(mean_a[i]) + centre,
        float(sd[i] / math.sqrt(k[i])),
        float(mean_b[i]) + centre,
        float(sd[i] / math.sqrt(n - k[i])),
        float(rss[i]),
    )
