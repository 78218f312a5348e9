"""A period is named only if it is one (docs/discovery.md, "A period is named only if it is one").

A sine fitted to a smooth curve always finds *some* period: the outline of a curve that rises
and falls once or twice over the travel, or a single sine in a chirp that happens to match the
local period somewhere. A cyclic error (``periodic``, ``reference_ripple``) is therefore named
only when two tests pass, given the other terms at their joint fit:

* **a peak, not a flank**: the gain of the term at its period against its gain with the phase
  changed by 2–4 cycles over the travel (its period law scaled; ``SHOULDERS``; further by the
  order E of its envelope, whose amplitude changes spread the line by ~E/2 cycles), on the part of
  the residual it explains *plus* the smooth tables of its axis (a smooth curve's spectrum falls
  with frequency: a sine on its flank gains less than the same sine a few cycles lower), with
  constant amplitudes (an envelope could follow the shifted phase). The ratio must reach
  :data:`PEAK_RATIO`; a shoulder below one cycle over the travel, or within half a cycle of the
  error's own 2nd or 3rd harmonic (:data:`HARMONIC_CLEARANCE`), is not used.
* **the same period, amplitude and phase in every subset**: the term refitted (amplitudes, and
  the period re-profiled within ±1 cycle over the travel) on each half of the session in time,
  each direction of travel, and each half of the travel (only when each half holds ≥ 2 cycles;
  the period alone where the term has an envelope, an amplitude and phase that may change along
  the travel). Two subsets
  disagree when their periods differ by more than half the subsets' resolution (and 3σ), their
  amplitudes by more than a factor 2 (and 3σ), or their phases by more than 45° (and 3σ) — the
  last two only when the two first harmonics also differ beyond their joint covariance
  (:data:`CHI2_DISTINCT`; σ's from each subset's fit covariance, so a subset whose points crowd
  into a small part of a long period does not pass off a poorly determined phase as a precise
  one).

The figures (peak ratio, per subset n, period, amplitude, phase, σ's) go into the effect's
``evidence``; a refused period's figures go into the entry that took its shape (a smooth
table).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..parametric_errors import AXIS_INDEX
from .fitting import Problem, Term, fit, predictions
from .reference_candidates import law_of
from .residuals import FloatArray

__all__ = [
    "CYCLIC",
    "PeriodCheck",
    "check_period",
    "cyclic_axis",
    "partial_residual",
    "scaled",
]

#: Causes that are cyclic errors.
CYCLIC = ("periodic", "reference_ripple")
#: A peak's gain must be this many times its largest shoulder's.
PEAK_RATIO = 2.0
#: Shoulders: the phase changed by this many cycles over the travel.
SHOULDERS = (-4, -3, -2, 2, 3, 4)
#: Tolerances of the subset agreement (besides 3σ): amplitude ratio, phase (degrees), period
#: (fraction of the subsets' resolution, in cycles over the travel).
AMPLITUDE_RATIO = 2.0
PHASE_DEG = 45.0
PERIOD_RESOLUTION = 0.5
#: χ² (2 degrees of freedom, p = 0.001) above which two subsets' first harmonics differ.
CHI2_DISTINCT = 13.8
#: A shoulder closer than this (cycles over the travel) to the error's own harmonic is not used.
HARMONIC_CLEARANCE = 0.5
#: Cycles each half of the travel must hold to be a subset.
MIN_HALF_CYCLES = 2.0


@dataclass
class PeriodCheck:
    """The outcome for one cyclic term (module docstring)."""

    ok: bool
    peak_ratio: float
    subsets: list[dict[str, Any]] = field(default_factory=list)
    disagreements: list[str] = field(default_factory=list)

    def evidence(self) -> dict[str, Any]:
        return {
            "peak_ratio": self.peak_ratio,
            "peak_ratio_required": PEAK_RATIO,
            "subsets": self.subsets,
            "disagreements": self.disagreements,
        }


def cyclic_axis(term: Term) -> int | None:
    """The axis index of a cyclic term (None for any other)."""
    if term.candidate.cause not in CYCLIC:
        return None
    return AXIS_INDEX[term.candidate.keys["axis"]]


def _span(problem: Problem, k: int) -> tuple[float, float]:
    q = problem.res.q_mm[:, k]
    return float(np.min(q)), float(np.max(q))


def cycles(problem: Problem, k: int, theta: Any) -> float:
    """Cycles of the term's first harmonic over the measured travel of axis ``k``."""
    lo, hi = _span(problem, k)
    law = law_of(theta, 0.5 * (lo + hi), (lo, hi))
    phi = law.phase(np.array([lo, hi]))
    return float(abs(phi[1] - phi[0]) / (2.0 * np.pi))


def scaled(theta: Any, factor: float) -> Any:
    """``theta`` with its period (at the centre) multiplied by ``factor``."""
    if isinstance(theta, tuple):
        return (theta[0], float(theta[1]) * factor, *theta[2:])
    return float(theta) * factor


def partial_residual(
    problem: Problem, terms: Sequence[Term], beta: FloatArray, keep: set[int]
) -> FloatArray:
    """(N, 3) residual with the terms at indices ``keep`` (and the offsets) added back."""
    b = beta.copy()
    b[: problem.n_nuisance] = 0.0
    start = problem.n_nuisance
    for i, t in enumerate(terms):
        if i in keep:
            b[start : start + t.candidate.n_params] = 0.0
        start += t.candidate.n_params
    return problem.res.residual_um - predictions(problem, terms, b)


def _smooth_tables(terms: Sequence[Term], axis: str) -> set[int]:
    out = set()
    for i, t in enumerate(terms):
        c = t.candidate
        if (c.cause == "parametric" and c.keys.get("component") == f"d{axis}_{axis}") or (
            c.cause == "reference_nonlinearity" and c.keys.get("axis") == axis
        ):
            out.add(i)
    return out


def _gain(
    x: FloatArray, y: FloatArray, t: FloatArray | None = None
) -> tuple[float, FloatArray, float]:
    """RSS reduction of ``[1, x]`` over a constant fitted to ``y``; the coefficients of ``x``
    and the residual's σ per effective observation (with times ``t``: inflated by
    (1 + ρ)/(1 − ρ), ρ the residual's lag-one correlation in time — what other, unmodelled
    structure leaves in a subset is not independent noise)."""
    a = np.column_stack([np.ones(len(y)), x])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    r = y - a @ coef
    rss1 = float(np.sum(r**2))
    rss0 = float(np.sum((y - np.mean(y)) ** 2))
    var = rss1 / max(len(y) - a.shape[1], 1)
    if t is not None and len(r) > 2 and rss1 > 0:
        r = r[np.argsort(t, kind="stable")]
        rho = min(max(float(np.sum(r[1:] * r[:-1])) / rss1, 0.0), 0.95)
        var *= (1.0 + rho) / (1.0 - rho)
    return rss0 - rss1, np.asarray(coef[1:], float), float(np.sqrt(var))


def _columns(
    problem: Problem, term: Term, theta: Any, k: int, rows: Any = slice(None), plain: bool = False
) -> Any:
    """The term's columns on axis ``k``; ``plain``: only its first harmonic at constant
    amplitude (an envelope could follow a phase drifting by a few cycles over the travel, and
    a harmonic of a period twice as long lands on the period itself: a period test must let
    neither stand in for the period tested)."""
    x = term.candidate.design_uncached(problem.res, theta)[rows, k, :]
    return x[:, :2] if plain else x


def _first_harmonic(coef: FloatArray, envelope: int, s: float) -> tuple[float, float]:
    """(amplitude µm, phase rad) of the first harmonic at the normalised position ``s``."""
    pj = np.polynomial.legendre.legvander(np.array([s]), envelope)[0]
    a = float(pj @ coef[0 : 2 * (envelope + 1) : 2])
    b = float(pj @ coef[1 : 2 * (envelope + 1) : 2])
    return float(np.hypot(a, b)), float(np.arctan2(b, a))


def _harmonic_cov(x: FloatArray, sigma: float, envelope: int, s: float) -> FloatArray:
    """2 × 2 covariance (µm²) of the first harmonic's quadratures at ``s`` from the fit's
    covariance (columns ``[1, x]``, residual σ ``sigma``): a subset whose points crowd into a
    small part of a long period determines its amplitude and phase poorly, whatever its number
    of points."""
    a = np.column_stack([np.ones(len(x)), x])
    cov = np.linalg.pinv(a.T @ a)[1:, 1:] * sigma**2
    pj = np.polynomial.legendre.legvander(np.array([s]), envelope)[0]
    rows = np.zeros((2, cov.shape[0]))
    rows[0, 0 : 2 * (envelope + 1) : 2] = pj
    rows[1, 1 : 2 * (envelope + 1) : 2] = pj
    return np.asarray(rows @ cov @ rows.T, float)


def _fit_subset(
    problem: Problem, term: Term, k: int, y: FloatArray, rows: Any, s_at: float
) -> dict[str, Any]:
    """Period (re-profiled within ±1 cycle over the travel), amplitude and phase on ``rows``.

    Amplitude and phase are fitted at the term's own period law: phases fitted at two subsets'
    own periods would differ by the period difference times the distance from the phase origin
    (a half of the travel a quarter-travel off centre turns 30° for 0.3 cycles) — a period
    difference the period test judges on its own resolution."""
    n_cyc = cycles(problem, k, term.theta)
    best: tuple[float, float, Any] | None = None
    for dk in np.linspace(-1.0, 1.0, 21):
        th = scaled(term.theta, n_cyc / (n_cyc + dk))
        g, _, _ = _gain(_columns(problem, term, th, k, rows, plain=True), y[rows])
        if best is None or g > best[0]:
            best = (g, float(dk), th)
    assert best is not None
    _, dk, _ = best
    t = problem.res.data.t_s
    x = _columns(problem, term, term.theta, k, rows)
    _, coef, sigma = _gain(x, y[rows], None if t is None else t[rows])
    amp, phase = _first_harmonic(coef, term.candidate.envelope, s_at)
    n = len(rows)
    cov = _harmonic_cov(x, sigma, term.candidate.envelope, s_at)
    sigma_a = max(sigma * np.sqrt(2.0 / max(n, 1)), float(np.sqrt(np.max(np.diag(cov)))))
    period = scaled(term.theta, n_cyc / (n_cyc + dk))
    return {
        "n": int(n),
        "period_mm": float(period[1] if isinstance(period, tuple) else period),
        "cycles_offset": dk,
        "amplitude_um": amp,
        "phase_deg": float(np.degrees(phase)),
        "sigma_amplitude_um": float(sigma_a),
        "sigma_phase_deg": float(np.degrees(sigma_a / max(amp, 1e-12))),
        "_harmonic": (amp * np.array([np.cos(phase), np.sin(phase)]), cov),
    }


def _subsets(problem: Problem, k: int, term: Term) -> list[tuple[str, list[tuple[str, Any]]]]:
    """Pairs of complementary subsets: halves in time, directions, halves of the travel."""
    res = problem.res
    out: list[tuple[str, list[tuple[str, Any]]]] = []
    t = res.data.t_s
    if t is not None and float(np.ptp(t)) > 0:
        early = t <= np.median(t)
        out.append(("time", [("first half", early), ("second half", ~early)]))
    d = res.signals.get(f"dir_{'xyz'[k]}")
    if d is not None and np.any(d > 0) and np.any(d < 0):
        out.append(("direction", [("+", d > 0), ("−", d < 0)]))
    q = res.q_mm[:, k]
    if cycles(problem, k, term.theta) >= 2 * MIN_HALF_CYCLES:
        low = q <= np.median(q)
        out.append(("travel", [("lower half", low), ("upper half", ~low)]))
    return out


def _distinct(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """The two subsets' first harmonics (both quadratures) differ beyond their joint
    uncertainty (χ² with 2 degrees of freedom above :data:`CHI2_DISTINCT`)."""
    (va, ca), (vb, cb) = a["_harmonic"], b["_harmonic"]
    d = va - vb
    return float(d @ np.linalg.pinv(ca + cb) @ d) > CHI2_DISTINCT


def _disagree(kind: str, a: dict[str, Any], b: dict[str, Any], envelope: int) -> list[str]:
    out = []
    distinct = _distinct(a, b)
    resolution = 2.0 if kind == "travel" else 1.0  # cycles over the travel a subset resolves
    if abs(a["cycles_offset"] - b["cycles_offset"]) > PERIOD_RESOLUTION * resolution:
        out.append(f"{kind}: period {a['period_mm']:.4g} vs {b['period_mm']:.4g} mm")
    sa = np.hypot(a["sigma_amplitude_um"], b["sigma_amplitude_um"])
    hi, lo = max(a["amplitude_um"], b["amplitude_um"]), min(a["amplitude_um"], b["amplitude_um"])
    if (
        (kind != "travel" or envelope == 0)
        and distinct
        and hi > AMPLITUDE_RATIO * lo
        and hi - lo > 3 * sa
    ):
        out.append(f"{kind}: amplitude {a['amplitude_um']:.3g} vs {b['amplitude_um']:.3g} µm")
    dphi = abs((a["phase_deg"] - b["phase_deg"] + 180.0) % 360.0 - 180.0)
    sphi = np.hypot(a["sigma_phase_deg"], b["sigma_phase_deg"])
    # (an envelope lets the phase drift along the travel: halves of it are not compared)
    if (kind != "travel" or envelope == 0) and distinct and dphi > PHASE_DEG and dphi > 3 * sphi:
        out.append(f"{kind}: phase {a['phase_deg']:.0f}° vs {b['phase_deg']:.0f}°")
    return out


def _shoulders(n_cyc: float, envelope: int) -> list[float]:
    """The phase changes (cycles over the travel) whose gains are the peak's shoulders: an
    envelope of order E spreads the line over ~E/2 cycles each side, so shoulders lie beyond it;
    none below one cycle over the travel; none within half a cycle of the error's own 2nd or
    3rd harmonic (a cyclic error with harmonics is one object: its harmonic is a peak of its
    own, not a flank of the first — a period of 2.2 cycles has its 2nd harmonic where the
    shoulder 2 cycles up would sit). If that leaves none, every usable shoulder is kept."""
    away = [dk + np.sign(dk) * envelope for dk in SHOULDERS]
    usable = [dk for dk in away if n_cyc + dk >= 1.0]
    clear = [
        dk
        for dk in usable
        if all(abs(n_cyc + dk - h * n_cyc) >= HARMONIC_CLEARANCE for h in (2, 3))
    ]
    return clear or usable


#: Positions closer than this (mm) are one position of the peak test (an encoder's jitter
#: at rest: ≤ 0.04 µm on the ESS record).
SAME_POSITION_MM = 1e-4


class _Positions:
    """Rows grouped by position along the axis (:data:`SAME_POSITION_MM`): the peak test
    weighs each position sampled once. Many rows at one position (a stop of an ISO 230-2 run,
    repeated cycles) sample a short period at a handful of points, where any smooth curve
    added back (the tables) correlates with the sine by chance: a 35 µm sensor linearity
    put the gain of shoulders 2–7 cycles away at 0.65× that of a 3 µm triangulation ripple of
    63 cycles over the travel (``mixed/bidirectional/s4000``, 330 of 2686 rows at 11 stops);
    on the moving rows alone the shoulders were below 0.06×."""

    def __init__(self, q_mm: FloatArray) -> None:
        _, self.index, counts = np.unique(
            np.round(q_mm / SAME_POSITION_MM), return_inverse=True, return_counts=True
        )
        self.index = self.index.reshape(-1)
        self.counts = counts.astype(float)

    def mean(self, v: FloatArray) -> FloatArray:
        """Per-position means of ``v`` (rows first; any trailing shape)."""
        out = np.zeros((len(self.counts), *v.shape[1:]))
        np.add.at(out, self.index, v)
        return out / self.counts.reshape(-1, *([1] * (v.ndim - 1)))


def check_period(
    problem: Problem,
    terms: Sequence[Term],
    index: int,
    beta: FloatArray | None = None,
    subsets: bool = True,
) -> PeriodCheck:
    """Both tests of the module docstring for the cyclic ``terms[index]`` (the peak alone
    without ``subsets``: while other causes are still to be named, what they leave in a subset
    would move its phase)."""
    if beta is None:
        beta, _, _ = fit(problem, terms)
    term = terms[index]
    k = cyclic_axis(term)
    assert k is not None
    axis = "xyz"[k]
    y_term = partial_residual(problem, terms, beta, {index})[:, k]
    y_peak = partial_residual(problem, terms, beta, {index} | _smooth_tables(terms, axis))[:, k]
    n_cyc = cycles(problem, k, term.theta)
    at = _Positions(problem.res.q_mm[:, k])
    y_at = at.mean(y_peak)
    g0, _, _ = _gain(at.mean(_columns(problem, term, term.theta, k, plain=True)), y_at)
    shoulders = [
        _gain(
            at.mean(
                _columns(problem, term, scaled(term.theta, n_cyc / (n_cyc + dk)), k, plain=True)
            ),
            y_at,
        )[0]
        for dk in _shoulders(n_cyc, term.candidate.envelope)
    ]
    ratio = float(g0 / max(max(shoulders, default=0.0), 1e-300))
    lo, hi = _span(problem, k)
    out = PeriodCheck(ok=ratio >= PEAK_RATIO, peak_ratio=ratio)
    if not out.ok:
        out.disagreements.append(
            f"no spectral peak: gain at the period {ratio:.2f}× the largest 2–4 cycles away"
        )
    envelope = term.candidate.envelope
    q = problem.res.q_mm[:, k]
    for kind, pair in _subsets(problem, k, term) if subsets else []:
        fits = []
        for name, mask in pair:
            rows = np.flatnonzero(mask)
            s_at = 0.0
            if kind == "travel":
                s_at = float(2.0 * (np.mean(q[rows]) - lo) / (hi - lo) - 1.0)
            f = _fit_subset(problem, term, k, y_term, rows, s_at)
            fits.append(f)
            public = {key: v for key, v in f.items() if not key.startswith("_")}
            out.subsets.append({"subset": kind, "part": name, **public})
        bad = _disagree(kind, fits[0], fits[1], envelope)
        out.disagreements += bad
        out.ok = out.ok and not bad
    return out
