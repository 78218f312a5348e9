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
    ``tolerance`` δ per output, ``worst`` max over the watched outputs (``stop_on``) and
    statistics of 2s/δ; ``ratio`` (4, K) 2s/δ of y, u, y_low, y_high per output after the last
    run (NaN before a second run). ``values`` (trials, len(value_columns)) of the outputs
    ``value_columns`` when kept; ``interval_all_trials`` (K,) whether an output's interval comes
    from all its values (else from the mean of the runs' quantiles)."""

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
    value_columns: tuple[int, ...] = ()
    stop_on: tuple[int, ...] = ()
    ratio: FloatArray | None = None
    interval_all_trials: NDArray[np.bool_] | None = None

    @property
    def U(self) -> FloatArray:
        """Expanded uncertainty with coverage factor k = 2."""
        return 2.0 * self.u

    def column(self, output: int) -> FloatArray | None:
        """All trials' values of output ``output`` (trials,), None when they were not kept."""
        if self.values is None or output not in self.value_columns:
            return None
        return self.values[:, self.value_columns.index(output)]

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


def _plan(s: MonteCarloSettings) -> list[int]:
    """Run sizes: a fixed number split into runs as equal as possible (none tiny), or runs of
    one size, as many as fit under ``max_trials`` (the loop stops once stable)."""
    size = s.run_size()
    if s.trials is not None:
        n_runs = max(1, round(s.trials / size))
        base, extra = divmod(s.trials, n_runs)  # np.array_split's sizes, without an arange of
        return [base + (i < extra) for i in range(n_runs)]  # all trials (1e9: 7.45 GiB)
    return [size] * max(1, s.max_trials // size) if s.max_trials >= size else [s.max_trials]


def _tolerance(s: MonteCarloSettings, u: FloatArray) -> FloatArray:
    return (
        np.full(u.shape, s.tolerance) if s.tolerance is not None else numerical_tolerance(u, s.ndig)
    )


def _stability(
    stats: list[FloatArray], sizes: list[int], s: MonteCarloSettings
) -> tuple[FloatArray, FloatArray]:
    """δ per output and 2s/δ (4, K) of the run averages of y, u, y_low, y_high (§7.9.4)."""
    tol = _tolerance(s, _pooled(stats, sizes)[1])
    arr = np.stack(stats)  # (h, 5, K)
    sd = arr[:, :4].std(axis=0, ddof=1) / math.sqrt(arr.shape[0])  # (4, K)
    return tol, np.where(np.isfinite(tol), 2.0 * sd / tol, 0.0)


class _Kept:
    """The values held for the final interval and for plots: every output while trials × K
    fits ``limit``, then only the outputs ``keep`` (while they fit), then none."""

    def __init__(self, k: int, keep: tuple[int, ...], limit: int) -> None:
        self.columns: tuple[int, ...] = tuple(range(k))
        self.keep, self.limit = keep, limit
        self.parts: list[FloatArray] = []

    def add(self, y: FloatArray, done: int) -> None:
        if self.columns and done * len(self.columns) > self.limit:
            cols = self.keep if done * len(self.keep) <= self.limit else ()
            idx = [self.columns.index(c) for c in cols]
            self.parts = [part[:, idx] for part in self.parts] if cols else []
            self.columns = cols
        if self.columns:
            self.parts.append(y[:, list(self.columns)] if len(self.columns) < y.shape[1] else y)

    def values(self) -> FloatArray | None:
        return np.concatenate(self.parts) if self.columns and self.parts else None


def run_monte_carlo(
    draw: Callable[[int, np.random.Generator], FloatArray],
    rng: np.random.Generator,
    settings: MonteCarloSettings | None = None,
    progress: ProgressFn | None = None,
    *,
    stop_on: tuple[int, ...] | None = None,
    keep: tuple[int, ...] | None = None,
    extra_ratio: Callable[[], float] | None = None,
) -> McResult:
    """Run ``draw(M, rng) → (M, K)`` output values in runs until stable (or the fixed number of
    trials); see the module docstring. ``stop_on``: the outputs the stopping rule watches (None:
    all; the others are reported with the precision the watched ones needed, their 2s/δ in
    :attr:`McResult.ratio`). ``keep``: the outputs whose values are kept when all of them do
    not fit ``keep_values_limit`` (None: ``stop_on``). ``extra_ratio()``: a further 2s/δ the
    rule must bring to ≤ 1, called after every run from the second (a statistic the draw keeps
    itself, e.g. a share of trials). ``progress(trials_done, worst)`` after
    every run (``worst`` = max 2s/δ of the watched outputs, NaN before the second run).
    Non-finite outputs raise ValueError."""
    s = settings or MonteCarloSettings()
    stats: list[FloatArray] = []
    sizes: list[int] = []
    kept: _Kept | None = None
    watch: list[int] = []
    done = 0
    worst = math.nan
    stable = False
    ratio: FloatArray | None = None
    for m in _plan(s):
        y = np.asarray(draw(m, rng), dtype=float)
        if y.ndim != 2 or y.shape[0] != m:
            raise ValueError(f"a run must give ({m}, K) values, got {y.shape}")
        if not np.all(np.isfinite(y)):
            raise ValueError("the Monte Carlo model gave non-finite values")
        if kept is None:
            watch = list(range(y.shape[1])) if stop_on is None else sorted(set(stop_on))
            if any(not 0 <= i < y.shape[1] for i in watch):
                raise ValueError(f"stop_on {stop_on} names outputs beyond the {y.shape[1]} given")
            cols = tuple(watch) if keep is None else tuple(sorted(set(keep)))
            kept = _Kept(y.shape[1], cols, s.keep_values_limit)
        stats.append(_run_stats(y, s.probability))
        sizes.append(m)
        done += m
        kept.add(y, done)
        if len(stats) >= 2:
            _, ratio = _stability(stats, sizes, s)
            worst = float(ratio[:, watch].max()) if watch else 0.0
            if extra_ratio is not None:
                worst = max(worst, float(extra_ratio()))
            stable = worst <= 1.0
        if progress is not None:
            progress(done, worst)
        if stable and s.trials is None:
            break
    if not stats or kept is None:
        raise ValueError("no trials were run")
    return _result(stats, sizes, s, kept, done, stable, worst, ratio, tuple(watch))


def _result(
    stats: list[FloatArray],
    sizes: list[int],
    s: MonteCarloSettings,
    kept: _Kept,
    done: int,
    stable: bool,
    worst: float,
    ratio: FloatArray | None,
    watch: tuple[int, ...],
) -> McResult:
    """The summary of all runs: pooled y and u; the interval of each output from all its values
    when they were kept, else from the mean of the runs' quantiles."""
    arr = np.stack(stats)
    k = arr.shape[2]
    mean, u = _pooled(stats, sizes)
    low, high, u95 = arr[:, 2].mean(axis=0), arr[:, 3].mean(axis=0), arr[:, 4].mean(axis=0)
    values = kept.values()
    from_all = np.zeros(k, dtype=bool)
    if values is not None:
        st = _run_stats(values, s.probability)
        cols = list(kept.columns)
        low[cols], high[cols], u95[cols] = st[2], st[3], st[4]
        from_all[cols] = True
    if from_all.all():
        method = "all trials"
    elif from_all.any():
        method = "all trials for the kept outputs, mean of the runs' quantiles for the others"
    else:
        method = "mean of the runs' quantiles"
    tol = _tolerance(s, u) if len(stats) < 2 else _stability(stats, sizes, s)[0]
    return McResult(
        mean=mean,
        u=u,
        low=low,
        high=high,
        U95=u95,
        trials=done,
        runs=len(stats),
        stable=bool(stable),
        tolerance=tol,
        worst=worst,
        probability=s.probability,
        interval_method=method,
        values=values,
        value_columns=kept.columns if values is not None else (),
        stop_on=watch,
        ratio=ratio if ratio is not None else np.full((4, k), np.nan),
        interval_all_trials=from_all,
    )


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
