"""Local spectral analysis: does a cyclic error keep its period along the travel, and if not,
which law does its period follow?

A dense record (thousands of samples along an axis) shows a cyclic error's *local* period: the
strongest cyclic error of the whole record is found first, then the travel is cut into up to 10
windows holding at least 3.5 of its cycles each (4 windows at least; when these show no law, the
windows are sized again by the median of the strongest periods of 10 equal windows: a chirped
error is strong locally but spread in the whole record, where a weaker constant one outshines it), the smooth part of the error (a curve per direction of travel, a slow
drift) is removed, and in each window the period of the strongest sine is found (a least-squares
periodogram, refined between grid values), with its Cramér–Rao uncertainty
σ_f = √12·σ/(2π·A·L_w·√N_w) inflated by the scatter the law leaves. Windows whose period is far off a
smooth law through the others (an alias of the sampling, a spurious peak) are left out. The
local periods are then fitted by the laws of :mod:`cmm_comp.compensation.effects.period_law`:

* ``constant``: one period;
* ``triangulation``: √p linear in the reading (p = P·((r − r0)/(c − r0))²): a weighted straight
  line, r0 where it crosses zero — the physical law of a triangulation sensor;
* ``smooth``: log p a polynomial of degree ≤ 2 in the normalised reading.

A chirp is reported only when the constant law is refused (χ² test at ``alpha``) *and* the law
changes the phase across the travel by at least :data:`MIN_CHIRP_CYCLES` against the best
constant period (less than that a constant-period candidate follows it); ``triangulation`` (the
physical law) is preferred to ``smooth`` unless the smooth law fits the local periods
significantly better and their phases part by more than :data:`MAX_LAW_GAP_CYCLES` over the
travel (beyond a linear difference, which the refinement of the period at the centre takes up).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import legendre
from scipy import stats

from ..effects import PeriodLaw
from .residuals import FloatArray

__all__ = ["MIN_CHIRP_CYCLES", "Chirp", "LocalPeriod", "find_chirp", "local_periods"]

#: A chirped law must change the phase across the travel by this many cycles against the best
#: constant period (below it, a constant-period candidate follows the cyclic error anyway; the
#: period test refuses a constant period whose halves of the travel part by one cycle).
MIN_CHIRP_CYCLES = 0.5
#: Windows along the travel (at most; each holds ≥ ``WINDOW_CYCLES`` of the record's strongest
#: cyclic error, and a law needs ``MIN_WINDOWS``), the longest period searched (at least this many
#: cycles over the travel) and how far a window's period may be from the record's (factor).
WINDOWS = 10
WINDOW_CYCLES = 3.5
MIN_WINDOWS = 4
MIN_CYCLES_PER_TRAVEL = 15.0
PERIOD_RANGE = 2.5
#: Frequency step of a window's periodogram (in units of its resolution 1/L_w).
STEP = 0.2


@dataclass(frozen=True)
class LocalPeriod:
    """The strongest sine of one window: centre (mm), period (mm) ± σ, amplitude (µm)."""

    centre_mm: float
    period_mm: float
    sigma_mm: float
    amplitude_um: float


@dataclass(frozen=True)
class Chirp:
    """A chirped cyclic error found along a coordinate: its law, the local periods it was fitted
    to, and χ² per degree of freedom of the constant and of the chosen law."""

    law: PeriodLaw
    windows: tuple[LocalPeriod, ...]
    chi2_constant: float
    chi2_law: float
    cycles_gained: float


def _detrend(r: FloatArray, y: FloatArray, groups: FloatArray, t: FloatArray | None) -> FloatArray:
    """``y`` minus a smooth curve of order 8 per group (direction of travel) and a cubic in time."""
    lo, hi = float(np.min(r)), float(np.max(r))
    s = 2.0 * (r - lo) / max(hi - lo, 1e-12) - 1.0
    cols = []
    for g in np.unique(groups):
        m = (groups == g).astype(float)
        cols += list((legendre.legvander(s, 8) * m[:, None]).T)
    if t is not None and float(np.ptp(t)) > 0:
        tau = 2.0 * (t - np.min(t)) / np.ptp(t) - 1.0
        cols += list(legendre.legvander(tau, 3)[:, 1:].T)
    x = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    return np.asarray(y - x @ coef, float)


def _window_peak(r: FloatArray, y: FloatArray, f_lo: float, f_hi: float) -> LocalPeriod | None:
    """The strongest sine in one window (None when it is not significant at 1e-3 over the
    frequencies searched)."""
    n = len(r)
    width = float(np.ptp(r))
    if n < 40 or width <= 0:
        return None
    rc = r - np.mean(r)
    y = y - np.mean(y)
    freqs = np.arange(f_lo, f_hi, STEP / width)
    if len(freqs) < 3:
        return None
    ph = 2.0 * np.pi * np.outer(rc, freqs)  # (n, F)
    c, s = np.cos(ph), np.sin(ph)
    c -= c.mean(axis=0)
    s -= s.mean(axis=0)
    cc, ss, cs = np.sum(c * c, 0), np.sum(s * s, 0), np.sum(c * s, 0)
    yc, ys = y @ c, y @ s
    det = cc * ss - cs**2
    det[det <= 0] = np.inf
    a = (ss * yc - cs * ys) / det
    b = (cc * ys - cs * yc) / det
    gain = a * yc + b * ys
    i = int(np.argmax(gain))
    rss0 = float(y @ y)
    rss1 = rss0 - float(gain[i])
    if rss1 <= 0:
        return None
    f_stat = (gain[i] / 2.0) / (rss1 / max(n - 3, 1))
    if float(stats.f.sf(f_stat, 2, max(n - 3, 1))) * len(freqs) >= 1e-3:
        return None
    f = float(freqs[i])
    if 0 < i < len(freqs) - 1:  # parabolic refinement of the peak
        g0, g1, g2 = gain[i - 1], gain[i], gain[i + 1]
        den = g0 - 2 * g1 + g2
        if den < 0:
            f += 0.5 * (g0 - g2) / den * (freqs[1] - freqs[0])
    amp = float(np.hypot(a[i], b[i]))
    sigma = np.sqrt(rss1 / max(n - 3, 1))
    sigma_f = np.sqrt(12.0) * sigma / (2.0 * np.pi * max(amp, 1e-12) * width * np.sqrt(n))
    return LocalPeriod(float(np.mean(r)), 1.0 / f, float(sigma_f / f**2), amp)


def _pass_nyquist_mm(r: FloatArray, t: FloatArray | None) -> float:
    """2.5× the median step between consecutive samples in time (0 without times)."""
    if t is None or len(r) < 3:
        return 0.0
    step = np.abs(np.diff(r[np.argsort(t, kind="stable")]))
    step = step[step > 0]
    return 2.5 * float(np.median(step)) if len(step) else 0.0


def local_periods(
    r: FloatArray,
    y: FloatArray,
    groups: FloatArray,
    t: FloatArray | None,
    p_min_mm: float,
    windows: int = WINDOWS,
) -> list[LocalPeriod]:
    """The significant local periods of ``y`` along ``r`` (module docstring); ``groups`` one
    label per point (the direction of travel) for the smooth curves removed first."""
    lo, hi = float(np.min(r)), float(np.max(r))
    length = hi - lo
    p_max = length / MIN_CYCLES_PER_TRAVEL
    if p_max <= p_min_mm or length <= 0:
        return []
    z = _detrend(r, y, groups, t)
    # the strongest cyclic error of the whole record sets the windows: each holds at least
    # WINDOW_CYCLES of it, and each searches a factor PERIOD_RANGE either side of it. It is
    # sought above 2.5× the spacing of consecutive samples in time (a pass samples regularly:
    # shorter periods alias there, whatever the passes resolve together)
    p_pass = _pass_nyquist_mm(r, t)
    whole = _window_peak(r, z, 1.0 / p_max, 1.0 / max(p_min_mm, p_pass))
    if whole is None:
        return []
    return _windows_about(r, z, whole.period_mm, p_min_mm, windows)


def _windows_about(
    r: FloatArray, z: FloatArray, period_mm: float, p_min_mm: float, windows: int
) -> list[LocalPeriod]:
    """The strongest local period of each window, the windows holding ≥ ``WINDOW_CYCLES`` of
    ``period_mm`` each and searching a factor ``PERIOD_RANGE`` either side of it."""
    lo, hi = float(np.min(r)), float(np.max(r))
    length = hi - lo
    n_win = int(min(windows, length / (WINDOW_CYCLES * period_mm)))
    if n_win < MIN_WINDOWS:
        return []
    f_lo = max(1.0 / (period_mm * PERIOD_RANGE), WINDOW_CYCLES / 2 * n_win / length)
    f_hi = min(PERIOD_RANGE / period_mm, 1.0 / p_min_mm)
    edges = np.linspace(lo, hi, n_win + 1)
    out: list[LocalPeriod] = []
    for a, b in itertools.pairwise(edges):
        m = (r >= a) & (r <= b)
        peak = _window_peak(r[m], z[m], f_lo, f_hi)
        if peak is not None:
            out.append(peak)
    return out


def _local_seed_mm(r: FloatArray, z: FloatArray, p_min_mm: float) -> float | None:
    """The median of the strongest periods of ``WINDOWS`` equal windows, searched over the
    whole range (a chirped cyclic error is strong locally but spread over many frequencies in
    the whole record, where a weaker constant one can outshine it), or None."""
    lo, hi = float(np.min(r)), float(np.max(r))
    length = hi - lo
    p_max = length / MIN_CYCLES_PER_TRAVEL
    if p_max <= p_min_mm or length <= 0:
        return None
    periods = []
    for a, b in itertools.pairwise(np.linspace(lo, hi, WINDOWS + 1)):
        m = (r >= a) & (r <= b)
        peak = _window_peak(r[m], z[m], 1.0 / p_max, 1.0 / p_min_mm)
        if peak is not None:
            periods.append(peak.period_mm)
    return float(np.median(periods)) if len(periods) >= MIN_WINDOWS else None


def _wls_line(x: FloatArray, y: FloatArray, w: FloatArray, deg: int) -> tuple[FloatArray, float]:
    """Weighted polynomial fit: (coefficients low→high, χ²)."""
    v = np.vander(x, deg + 1, increasing=True)
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(v * sw[:, None], y * sw, rcond=None)
    return np.asarray(coef, float), float(np.sum(w * (y - v @ coef) ** 2))


def _cycles(law: PeriodLaw, period: float, lo: float, hi: float) -> float:
    """Phase difference across [lo, hi] between ``law`` and a constant ``period``, in cycles
    (the constant's phase slope matched to the law's mean: the largest residual excursion)."""
    r = np.linspace(lo, hi, 401)
    dphi = law.phase(r) - 2.0 * np.pi * r / period
    dphi -= np.polyval(np.polyfit(r, dphi, 1), r)
    return float(np.ptp(dphi) / (2.0 * np.pi))


#: A window whose period is this many (inflated) σ off the triangulation law fitted to the
#: others is an alias or a spurious peak: left out (at most a quarter of the windows).
OUTLIER_Z = 4.0


def _without_outliers(win: list[LocalPeriod]) -> list[LocalPeriod]:
    """The windows minus those far off a smooth law fitted to the rest (log p quadratic in r:
    any law of interest is that smooth over a window spacing)."""
    win = list(win)
    for _ in range(max(len(win) // 4, 0)):
        if len(win) < 5:
            break
        x = np.array([w.centre_mm for w in win])
        lp = np.log([w.period_mm for w in win])
        sig = np.array([max(w.sigma_mm / w.period_mm, 1e-9) for w in win])
        z = np.empty(len(win))
        for i in range(len(win)):  # each window against the law of the others
            keep = np.arange(len(win)) != i
            coef, _ = _wls_line(x[keep], lp[keep], 1.0 / sig[keep] ** 2, 2)
            scatter = lp[keep] - np.polyval(coef[::-1], x[keep])
            spread = max(float(np.median(np.abs(scatter / sig[keep]))), 1.0)
            z[i] = abs(lp[i] - np.polyval(coef[::-1], x[i])) / (sig[i] * spread)
        worst = int(np.argmax(z))
        if z[worst] < OUTLIER_Z:
            break
        del win[worst]
    return win


#: The triangulation law is kept when its phase stays within this many cycles of the smooth
#: law's over the travel (a linear phase difference aside: the period at the centre is
#: refined on all the data afterwards).
MAX_LAW_GAP_CYCLES = 0.5


def _law_gap_cycles(a: PeriodLaw, b: PeriodLaw, lo: float, hi: float) -> float:
    r = np.linspace(lo, hi, 401)
    d = a.phase(r) - b.phase(r)
    d -= np.polyval(np.polyfit(r, d, 1), r)
    return float(np.ptp(d) / (2.0 * np.pi))


def find_chirp(
    r: FloatArray,
    y: FloatArray,
    groups: FloatArray,
    t: FloatArray | None,
    p_min_mm: float,
    alpha: float = 1e-3,
) -> Chirp | None:
    """A chirped cyclic error along ``r`` (module docstring), or None: the windows about the
    record's strongest cyclic error first, then — when they show no law — those about the
    strongest *local* one (a chirp outshone in the whole record by a constant cyclic error)."""
    chirp = _chirp_of(r, local_periods(r, y, groups, t, p_min_mm), alpha)
    if chirp is not None:
        return chirp
    z = _detrend(r, y, groups, t)
    seed = _local_seed_mm(r, z, p_min_mm)
    if seed is None:
        return None
    return _chirp_of(r, _windows_about(r, z, seed, p_min_mm, WINDOWS), alpha)


def _chirp_of(r: FloatArray, windows: list[LocalPeriod], alpha: float) -> Chirp | None:
    """The period law the local periods ``windows`` follow along ``r``, or None."""
    win = _without_outliers(windows)
    if len(win) < 4:
        return None
    x = np.array([w.centre_mm for w in win])
    p = np.array([w.period_mm for w in win])
    sp = np.array([max(w.sigma_mm, 1e-9) for w in win])
    lo, hi = float(np.min(r)), float(np.max(r))
    centre = 0.5 * (lo + hi)
    w = 1.0 / sp**2
    p_const, chi_c = _wls_line(x, p, w, 0)
    dof_c = len(win) - 1
    # triangulation: sqrt(p) linear in r
    sq = np.sqrt(p)
    coef_t, chi_t = _wls_line(x, sq, w * 4.0 * p, 1)
    laws: list[tuple[float, int, PeriodLaw]] = []
    if abs(coef_t[1]) > 0:
        r0 = -coef_t[0] / coef_t[1]
        p_c = float((coef_t[0] + coef_t[1] * centre) ** 2)
        margin = 0.05 * (hi - lo)
        if (r0 < lo - margin or r0 > hi + margin) and p_c > 0:
            laws.append((chi_t, len(win) - 2, PeriodLaw("triangulation", p_c, centre, r0_mm=r0)))
    s = 2.0 * (x - lo) / (hi - lo) - 1.0
    deg = min(2, len(win) - 2)
    coef_s, chi_s = _wls_line(s, np.log(p), w * p**2, deg)
    knots = np.unique(np.sort(np.r_[np.linspace(lo, hi, 5), centre]))
    sk = 2.0 * (knots - lo) / (hi - lo) - 1.0
    pk = np.exp(np.polynomial.polynomial.polyval(sk, coef_s))
    p_mid = float(pk[np.argmin(np.abs(knots - centre))])
    laws.append(
        (
            chi_s,
            len(win) - deg - 1,
            PeriodLaw("smooth", p_mid, centre, knots_mm=tuple(knots), period_at_knots_mm=tuple(pk)),
        )
    )
    # the scatter the best law leaves inflates every window's σ (real data are never white)
    best_chi, best_dof, _ = min(laws, key=lambda c: c[0] / max(c[1], 1))
    inflate = max(1.0, best_chi / max(best_dof, 1))
    if float(stats.chi2.sf((chi_c - best_chi) / inflate, dof_c - best_dof)) >= alpha:
        return None
    chosen = laws[0]
    # the physical law unless the smooth one fits the windows significantly better *and* their
    # phases part by a sizeable part of a cycle over the travel (window periods are far more
    # precise than a law needs to be: the term's envelope follows a slow phase drift)
    if chosen[2].kind == "triangulation" and len(laws) > 1:
        smooth = laws[1]
        extra = max(chosen[1] - smooth[1], 1)
        better = stats.chi2.sf(max(chosen[0] - smooth[0], 0.0) / inflate, extra) < alpha
        if better and _law_gap_cycles(chosen[2], smooth[2], lo, hi) > MAX_LAW_GAP_CYCLES:
            chosen = smooth
    cycles = _cycles(chosen[2], float(p_const[0]), lo, hi)
    if cycles < MIN_CHIRP_CYCLES:
        return None
    return Chirp(
        chosen[2], tuple(win), chi_c / max(dof_c, 1), chosen[0] / max(chosen[1], 1), cycles
    )
