"""The Monte Carlo method of JCGM 101 (GUM Supplement 1): summary statistics of the outputs and
the adaptive choice of the number of trials (§7.9).

Adaptive procedure (JCGM 101 §7.9.4), for every output quantity at once: runs of M trials each
(M = max(J, 10⁴), J = ⌈100/(1 − p)⌉, unless told otherwise); after each run h ≥ 2 the standard
deviations of the run averages of the estimate y, its standard uncertainty u(y) and the ends of
the probabilistically symmetric coverage interval (y_low, y_high) are formed,
``s = √(Σ_r (x_r − x̄)² / (h(h − 1)))``; the computation has stabilised when 2s ≤ δ for all of
them, δ the numerical tolerance of u(y): ``u(y) = c·10^l`` with c an integer of ``ndig``
significant digits, ``δ = ½·10^l`` (§7.9.2), or a tolerance given in the output's unit. The
results then use all h·M values (the interval from the averaged run quantiles when keeping every
value would need too much memory; stated in :attr:`McResult.interval_method`).

Besides y, u(y) and [y_low, y_high], every output gets ``U95``: the half-width of the smallest
interval *symmetric about zero* that holds the coverage probability (the ±U to put around a
corrected value), and U = 2·u(y) (k = 2).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "JCGM_MIN_BATCH",
    "McResult",
    "MonteCarloSettings",
    "numerical_tolerance",
    "run_monte_carlo",
]

FloatArray = NDArray[np.float64]
JCGM_MIN_BATCH = 10_000
ProgressFn = Callable[[int, float], None]


#: most trials in one run (held in memory at once): a larger --batch ran out of memory
MAX_RUN = 1_000_000


@dataclass(frozen=True)
class MonteCarloSettings:
    """How many trials: ``trials`` fixed (no stopping rule; split into runs of about ``batch``,
    as equal as possible, so the run-to-run stability is still reported), or adaptive (JCGM 101 §7.9) with
    runs of ``batch`` trials (None: max(J, 10⁴)) until stable to ``ndig`` significant digits of
    u (or to ``tolerance`` in the output's unit), at most ``max_trials``. ``probability`` p of the
    coverage interval. ``keep_values_limit``: most output values (trials × outputs) kept in memory."""

    probability: float = 0.95
    trials: int | None = None
    ndig: int = 2
    tolerance: float | None = None
    batch: int | None = None
    max_trials: int = 1_000_000
    keep_values_limit: int = 30_000_000

    def __post_init__(self) -> None:
        if not 0.5 <= self.probability < 1.0:
            raise ValueError(f"coverage probability must be in [0.5, 1), got {self.probability}")
        if self.trials is not None and self.trials < 2:
            raise ValueError(f"trials must be ≥ 2, got {self.trials}")
        if not 1 <= self.ndig <= 6:
            raise ValueError(f"ndig (significant digits) must be 1…6, got {self.ndig}")
        if self.tolerance is not None and not (
            math.isfinite(self.tolerance) and self.tolerance > 0
        ):
            raise ValueError(f"tolerance must be finite and > 0, got {self.tolerance}")
        if self.batch is not None and not 2 <= self.batch <= MAX_RUN:
            raise ValueError(f"batch (trials per run) must be 2…{MAX_RUN}, got {self.batch}")
        if self.j_min > MAX_RUN:  # a run holds at least J trials: p = 0.9999999 made J = 1e9
            raise ValueError(
                f"coverage probability {self.probability} needs runs of {self.j_min} trials "
                f"(J = 100/(1 − p)), more than {MAX_RUN}: use p below {1 - 100 / MAX_RUN:g}"
            )
        if self.max_trials < 2:
            raise ValueError(f"max_trials must be ≥ 2, got {self.max_trials}")

    @property
    def j_min(self) -> int:
        """J = ⌈100/(1 − p)⌉: the fewest trials for a 100p % interval (JCGM 101 §7.2.2)."""
        return math.ceil(100.0 / (1.0 - self.probability) - 1e-9)

    def run_size(self) -> int:
        """Trials per run: ``batch``, or max(J, 10⁴) (JCGM 101 §7.9.4 b); at most ``trials``."""
        size = self.batch if self.batch is not None else max(self.j_min, JCGM_MIN_BATCH)
        return min(size, self.trials) if self.trials is not None else size

    def with_batch_for(self, n_points: int, rows: int = 2_000_000) -> MonteCarloSettings:
        """These settings with the run size lowered for many points (a run of ``rows`` point
        evaluations, never below J) when no batch was chosen."""
        if self.batch is not None:
            return self
        size = max(self.j_min, min(JCGM_MIN_BATCH, rows // max(1, n_points)))
        return replace(self, batch=size)


@dataclass(frozen=True)
class McResult:
    """Summary of K output quantities over all trials (arrays (K,), output unit).

    ``mean`` y, ``u`` u(y), ``low``/``high`` the probabilistically symmetric 100p % interval,
    ``U95`` the half-width of the zero-centred 100p % interval, ``trials`` = runs × run size,
    ``stable`` whether the stopping rule was met (always False for a single run),
    ``tolerance`` δ per output, ``worst`` max over outputs and statistics of 2s/δ.
    ``values`` (trials, K) when kept."""

    mean: FloatArray
    u: FloatArray
    low: FloatArray
    high: FloatArray
    U95: FloatArray
    trials: int
    runs: int
    stable: bool
    tolerance: FloatArray
    worst: float
    probability: float
    interval_method: str
    values: FloatArray | None

    @property
    def U(self) -> FloatArray:
        """Expanded uncertainty with coverage factor k = 2."""
        return 2.0 * self.u

    def info(self) -> dict[str, Any]:
        """JSON-able: trials, runs, whether stable, the worst 2s/δ (None when not finite), the
        coverage probability and the interval method."""
        return {
            "trials": self.trials,
            "runs": self.runs,
            "stable": self.stable,
            "worst_2s_over_tolerance": None if not np.isfinite(self.worst) else float(self.worst),
            "coverage_probability": self.probability,
            "interval_method": self.interval_method,
        }


def numerical_tolerance(u: FloatArray, ndig: int) -> FloatArray:
    """δ = ½·10^l with u = c·10^l, c an ``ndig``-digit integer (JCGM 101 §7.9.2); ∞ where u = 0."""
    u = np.asarray(u, dtype=float)
    out = np.full(u.shape, np.inf)
    pos = u > 0
    exp = np.floor(np.log10(u[pos])) - (ndig - 1)
    out[pos] = 0.5 * 10.0**exp
    return out


def _run_stats(y: FloatArray, p: float) -> FloatArray:
    """(5, K): mean, std, low, high, U95 of one run's values y (M, K)."""
    lo, hi = (1.0 - p) / 2.0, (1.0 + p) / 2.0
    q = np.quantile(y, [lo, hi], axis=0)
    return np.stack(
        [y.mean(axis=0), y.std(axis=0, ddof=1), q[0], q[1], np.quantile(np.abs(y), p, axis=0)]
    )


def run_monte_carlo(
    draw: Callable[[int, np.random.Generator], FloatArray],
    rng: np.random.Generator,
    settings: MonteCarloSettings | None = None,
    progress: ProgressFn | None = None,
) -> McResult:
    """Run ``draw(M, rng) → (M, K)`` output values in runs until stable (or the fixed number of
    trials); see the module docstring. ``progress(trials_done, worst)`` after every run
    (``worst`` = max 2s/δ, NaN before the second run). Non-finite outputs raise ValueError."""
    s = settings or MonteCarloSettings()
    stats: list[FloatArray] = []
    sizes: list[int] = []
    kept: list[FloatArray] = []
    keep = True
    done = 0
    worst = math.nan
    stable = False
    tol = np.zeros(0)
    for m in _run_sizes(s):
        y = np.asarray(draw(m, rng), dtype=float)
        if y.ndim != 2 or y.shape[0] != m:
            raise ValueError(f"a run must give ({m}, K) values, got {y.shape}")
        if not np.all(np.isfinite(y)):
            raise ValueError("the Monte Carlo model gave non-finite values")
        stats.append(_run_stats(y, s.probability))
        sizes.append(m)
        done += m
        if keep and (done * y.shape[1] <= s.keep_values_limit):
            kept.append(y)
        else:
            keep, kept = False, []
        if len(stats) >= 2:
            tol = _tolerance(s, _pooled(stats, sizes)[1])
            worst = _worst(stats, tol)
            stable = worst <= 1.0
        if progress is not None:
            progress(done, worst)
        if stable and s.trials is None:
            break
    if not stats:
        raise ValueError("no trials were run")
    mean, u = _pooled(stats, sizes)
    values = np.concatenate(kept) if kept else None
    low, high, u95, method = _interval(stats, values, s.probability)
    return McResult(
        mean=mean,
        u=u,
        low=low,
        high=high,
        U95=u95,
        trials=done,
        runs=len(stats),
        stable=bool(stable),
        tolerance=tol if tol.size else _tolerance(s, u),
        worst=worst,
        probability=s.probability,
        interval_method=method,
        values=values,
    )


def _run_sizes(s: MonteCarloSettings) -> list[int]:
    """Trials per run: a fixed number in runs as equal as possible (none tiny), or (adaptive)
    runs of one size, as many as fit under ``max_trials``."""
    size = s.run_size()
    if s.trials is not None:
        n_runs = max(1, round(s.trials / size))
        base, extra = divmod(s.trials, n_runs)  # np.array_split's sizes, without an arange of
        return [base + (i < extra) for i in range(n_runs)]  # all trials (1e9: a 7.45 GiB array)
    return [size] * max(1, s.max_trials // size) if s.max_trials >= size else [s.max_trials]


def _tolerance(s: MonteCarloSettings, u: FloatArray) -> FloatArray:
    """The numerical tolerance δ of each output: the given one, else from ``ndig`` digits of u."""
    if s.tolerance is not None:
        return np.full(u.shape, s.tolerance)
    return numerical_tolerance(u, s.ndig)


def _worst(stats: list[FloatArray], tol: FloatArray) -> float:
    """max 2s/δ over the outputs and the four statistics (s: standard deviation of the runs'
    means, deviations and interval ends divided by √runs); 0 with no outputs."""
    arr = np.stack(stats)  # (h, 5, K)
    sd = arr[:, :4].std(axis=0, ddof=1) / math.sqrt(arr.shape[0])  # (4, K)
    ratio = np.where(np.isfinite(tol), 2.0 * sd / tol, 0.0)
    return float(ratio.max()) if ratio.size else 0.0


def _interval(
    stats: list[FloatArray], values: FloatArray | None, p: float
) -> tuple[FloatArray, FloatArray, FloatArray, str]:
    """Low and high ends of the probabilistically symmetric interval, the zero-centred U95 and
    how they were found: from all trials' ``values`` when kept, else the runs' quantiles
    averaged."""
    if values is not None:
        st = _run_stats(values, p)
        return st[2], st[3], st[4], "all trials"
    arr = np.stack(stats)
    low, high, u95 = arr[:, 2].mean(axis=0), arr[:, 3].mean(axis=0), arr[:, 4].mean(axis=0)
    return low, high, u95, "mean of the runs' quantiles"


def _pooled(stats: list[FloatArray], sizes: list[int]) -> tuple[FloatArray, FloatArray]:
    """Mean and standard deviation of all trials from the runs' means and deviations."""
    arr = np.stack(stats)
    m = np.asarray(sizes, dtype=float)[:, None]
    total = float(m.sum())
    means, sds = arr[:, 0], arr[:, 1]
    mean = (m * means).sum(axis=0) / total
    within = ((m - 1.0) * sds**2).sum(axis=0)
    between = (m * (means - mean) ** 2).sum(axis=0)
    return mean, np.sqrt((within + between) / (total - 1.0))
