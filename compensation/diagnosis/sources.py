"""Which instrument carries each effect, and which coordinate it is locked to: the test.

Every named term has *twins*: the same shape carried by the other instrument, or locked to
another coordinate (:data:`TWINS`) — a cyclic error of the axis' position and one of the
reference's reading with the same period law; a positional table and a smooth nonlinearity of
the reading (or a scale of the reference); a reversal and a latency (an error ∝ velocity); a
drift that changes along the axis and a reference drift the same everywhere. After selection,
each named term is refitted as each of its twins (the other named terms kept, the twin's
nonlinear parameter re-profiled about the term's; the twin at its default and at its rich shape,
the better kept), and the residual sums of squares compared
(the difference in parameters counted both ways, one noise variance σ² each: a twin with more
parameters charged for them, as :mod:`.alternatives` does, and one with fewer credited — a term
at its rich shape fits ~one σ² better per extra parameter by chance alone, which must not refute
a leaner twin; a drift shaped along the axis with 21 parameters refuted a reference drift of 10
by Δχ² = 17 on a session that hides only the reference drift; σ² per *effective* observation: neighbouring residuals of a dense
record are correlated, and a difference of fits is then worth fewer independent points — the
variance is inflated by (1 + ρ)/(1 − ρ), ρ the residual's lag-one correlation in time):

Two figures per twin, both in units of that σ²: Δχ², how much worse the twin fits, and the
*separability*, how badly the twin (the other terms free) can imitate the named term's fitted
contribution — what the session could at best show. With ``band = χ²₁(1 − α)``:

* separable (beyond the band, and — for a twin in the other coordinate, through the map between
  position and reading — missing at least 1 % of the term's energy — a cyclic error moved by
  ~3 % of its period (misfit sin²(π·shift)) between the directions: below that the difference is the map's own
  imperfection in a quiet session, not a physical one) and Δχ² > band: the twin is refuted; the term's own source and coordinate stand;
* separable and Δχ² < −band: the twin replaces the term (the data say which object it is) and
  is then tested against its own twins — except a smooth function of the reading
  (:data:`READING_SHAPES`), which is never named in place of a machine term;
* otherwise (within the band, or not separable: the difference comes from elsewhere in the
  model) the twin is an explanation the session cannot refuse: the entry's source is ``either``
  (when the twin's instrument differs) and its ``locked_to`` ``undetermined`` (when its
  coordinate differs); the twin is listed among ``alternatives`` with its source; the primary
  stays the term selected.

With bidirectional passes the test is the physics of the contract (docs/formats.md §4): a
reference-locked cyclic error shifts by the reversal in axis coordinates, a position-locked one
by nothing, so with a reversal that moves the phase clearly the two coordinates fit very
differently; a latency differs from a reversal at rest and between speeds; a reference drift
cannot follow a drift that changes along the axis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from ..parametric_errors import AXIS_INDEX
from .candidate import Candidate
from .coordinate_map import through_map
from .fitting import Problem, Term, best_theta, fit
from .locking import shift_noncentrality
from .reference_candidates import cyclic_builder, cyclic_design
from .residuals import Residuals

#: A smooth twin through the map (a table ↔ a nonlinearity of the reading) is separable only
#: when it misses at least this share of the term's energy: a smooth curve moved by a reversal
#: changes by f′·r, far below its own size, and what separates it in a quiet session is the
#: map's imperfection. (Cyclic twins are judged by their phase shift against its noise.)
SEPARATION_FLOOR = 0.01

#: Twins that are smooth functions of the reference's reading: never named in place of a machine
#: term (a smooth function of the reading beside smooth functions of the position spans the
#: observed error itself, ``(ref − indicated)·1000``: the model would explain the data by the
#: data); they can only make an entry ``either``.
READING_SHAPES = ("reference_nonlinearity", "reference_scale")

__all__ = [
    "TWINS",
    "SourceCall",
    "contribution",
    "decide_sources",
    "direction_factor",
    "residual_in_time",
    "twins_of",
]

#: cause → the causes that may be its twins (same axis).
TWINS: dict[str, tuple[str, ...]] = {
    "periodic": ("reference_ripple",),
    "reference_ripple": ("periodic",),
    "parametric": ("reference_nonlinearity", "reference_scale"),
    "reference_nonlinearity": ("parametric",),
    "reference_scale": ("parametric", "scale_expansion"),
    "scale_expansion": ("reference_scale",),
    "reversal": ("latency",),
    "latency": ("reversal",),
    "drift": ("reference_drift",),
    "reference_drift": ("drift",),
}


def _axis_of(c: Candidate) -> str | None:
    """The axis a candidate is a function of: its ``axis``, or that of a table's component
    (``dx_x``, ``ey_x`` … → x: a table is a function of its axis' position; through the Abbe
    arms it may act on the other components too, which a twin of the reading then cannot
    imitate)."""
    axis = c.keys.get("axis")
    if isinstance(axis, str):
        return axis
    comp = c.keys.get("component")
    if isinstance(comp, str) and len(comp) == 4 and comp[2] == "_" and comp[3] in "xyz":
        return comp[3]
    return None


def twins_of(cand: Candidate, pool: Sequence[Candidate], theta: Any = None) -> list[Candidate]:
    """The twins of ``cand`` in ``pool`` (same axis, a twin cause, a cyclic error's twin with
    the same kind of period law, scanning the period ``theta`` when given)."""
    axis = _axis_of(cand)
    if axis is None:
        return []
    chirped = cand.theta_step is not None
    out = []
    for c in pool:
        if c.cause not in TWINS.get(cand.cause, ()) or _axis_of(c) != axis:
            continue
        if c.cause in ("periodic", "reference_ripple") and (c.theta_step is not None) != chirped:
            continue
        if theta is not None and isinstance(theta, float) and not _covers(c, theta):
            continue  # a scan of other periods (the dense record's short ones)
        out.append(c)
    return out


def _covers(c: Candidate, theta: float) -> bool:
    grid = [v for v in c.thetas if isinstance(v, float)]
    return not grid or min(grid) * 0.9 <= theta <= max(grid) * 1.1


@dataclass
class SourceCall:
    """The decision for one named term: its source, coordinate, and the twins' figures."""

    source: str
    locked_to: str
    twins: list[dict[str, Any]] = field(default_factory=list)
    alternatives: list[tuple[Term, float]] = field(default_factory=list)  # (twin, Δχ²) within
    replaced: str | None = None  # the label of the term a better twin replaced

    def summary(self, label: str) -> str:
        if not self.twins:
            return f"{label}: no other instrument or coordinate has a term of this shape"
        parts = ", ".join(
            f"{t['cause']} ({t['source']}, locked to {t['locked_to']}) Δχ² = {t['delta_chi2']:+.1f}"
            for t in self.twins
        )
        if self.source == "either":
            verdict = "the session cannot tell which instrument carries it"
        elif self.locked_to == "undetermined":
            verdict = "the session cannot tell which coordinate it is locked to"
        else:
            verdict = f"it is the {self.source}'s, locked to {self.locked_to}"
        head = f"refitted as its twins: {parts}"
        if self.replaced:
            head = f"first selected as {self.replaced}; " + head
        return f"{head}; {verdict}"


def _twin_fit(
    problem: Problem, others: list[Term], term: Term, cand: Candidate
) -> tuple[Term, float]:
    """The twin ``cand`` (one of its shapes), its parameter profiled about the term's; a twin
    in the other coordinate (position ↔ reading) through the session's map between them
    (:func:`.coordinate_map.through_map`: a function of the reading beside functions of
    the position would otherwise span the observed error itself)."""
    if {cand.locked_to, term.candidate.locked_to} == {"position", "reference"}:
        cand = through_map(cand, problem.res)
    near = term.theta if isinstance(term.theta, float) else None
    if isinstance(term.theta, tuple) and cand.theta_step is not None:
        # the same law to start from: only its continuous refinement is needed
        cand = replace(cand, thetas=(term.theta,), _cache={}, _statics={})
    theta, rss, _ = best_theta(problem, others, cand, near=near)
    return Term(cand, theta), rss


def _cyclic_shape(cand: Candidate) -> tuple[int, int]:
    """(harmonics, envelope order) of a cyclic candidate's columns."""
    return cand.n_params // (2 * (cand.envelope + 1)), cand.envelope


def mirror(res: Residuals, term: Term, twin: Candidate) -> Candidate | None:
    """The cyclic twin at the *term's own* shape (harmonics and envelope), or ``None`` when
    the pair is not two constant-period cyclic errors or the twin already has that shape.

    Without a reversal a position has one reading, and a cyclic error of one coordinate *is*
    the same columns of the other: the twin must be offered the term's shape, or the test
    compares two shapes instead of two coordinates (a sensor's ripple whose amplitude changes
    along its range, fitted with its envelope, refuted the machine's constant-amplitude twin
    by Δχ² ≈ 5 000–60 000 in sessions without a reversal, where the physics has Δχ² = 0)."""
    if {term.candidate.cause, twin.cause} != {"periodic", "reference_ripple"}:
        return None
    if twin.theta_step is not None or not isinstance(term.theta, float):
        return None  # chirped laws: both instruments already have the same shapes
    shape = _cyclic_shape(term.candidate)
    own = [twin] + ([twin.rich] if twin.rich is not None else [])
    if any(_cyclic_shape(c) == shape for c in own):
        return None
    axis = _axis_of(twin)
    assert axis is not None
    k = AXIS_INDEX[axis]
    span = (float(np.min(res.q_mm[:, k])), float(np.max(res.q_mm[:, k])))
    centre = 0.5 * (span[0] + span[1])
    ref_point = float(res.machine.volume.reference_mm[k])
    h, e = shape
    return Candidate(
        twin.cause,
        dict(twin.keys),
        2 * h * (e + 1),
        cyclic_builder(axis, twin.locked_to, shape, centre, span),
        thetas=twin.thetas,
        look_elsewhere=twin.look_elsewhere,
        design_fn=cyclic_design(axis, twin.locked_to, shape, centre, span, ref_point),
        design_component=k,
        source=twin.source,
        locked_to=twin.locked_to,
        envelope=e,
    )


def _best_twin_shape(
    problem: Problem,
    others: list[Term],
    term: Term,
    twin: Candidate,
    rss_full: float,
    sigma2: float,
) -> tuple[Term, float]:
    """The twin at its default and at its rich shape (when it has one) — and a cyclic twin at
    the term's own shape (:func:`mirror`) — each charged one σ² per parameter beyond the
    term's (credited one per parameter fewer): the better and its Δχ² (in units of σ²). The
    twin's fair shape is not the term's: a drift selected with its rich (position-dependent)
    shape has a reference drift as twin that is the same everywhere, and a default
    reading-locked shape may imitate a rich positional one with fewer parameters."""
    shapes = [twin] + ([twin.rich] if twin.rich is not None else [])
    same = mirror(problem.res, term, twin)
    if same is not None:
        shapes.append(same)
    best: tuple[Term, float] | None = None
    for cand in shapes:
        t_term, rss = _twin_fit(problem, others, term, cand)
        extra = t_term.candidate.n_params - term.candidate.n_params
        delta = (rss - rss_full) / sigma2 + extra
        if best is None or delta < best[1]:
            best = (t_term, delta)
    assert best is not None
    return best


#: Twins that may carry a table of their axis: a drift that changes along the axis can take in
#: a uniform drift *and* a smooth curve of the position (a table, a sensor's linearity) at once;
#: its twin the same everywhere can only match that with the curve beside it.
CARRIES_TABLE = {("drift", "reference_drift")}


def _table_of(axis: str, pool: Sequence[Candidate], others: Sequence[Term]) -> Term | None:
    """The positional table of ``axis`` (``d<a>_<a>``, its default shape) from ``pool``, or
    ``None`` when one of ``others`` is already a table of that axis or none is in the pool."""
    comp = f"d{axis}_{axis}"
    if any(t.candidate.cause == "parametric" and _axis_of(t.candidate) == axis for t in others):
        return None
    for c in pool:
        if c.cause == "parametric" and c.keys.get("component") == comp:
            return Term(c, c.thetas[0])
    return None


def _twin_with_table(
    problem: Problem,
    others: list[Term],
    term: Term,
    twin: Candidate,
    plain: tuple[Term, float],
    table: Term | None,
    rss_full: float,
    sigma2: float,
) -> tuple[Term, float, list[Term]]:
    """The better of the twin alone (``plain``: term, Δχ²) and the twin carrying the table it
    competes with (:data:`CARRIES_TABLE`; the table's parameters charged one σ² each, as the
    twin's own extra ones): (twin term, Δχ², the others it was judged with)."""
    if table is None:
        return plain[0], plain[1], others
    with_table = [*others, table]
    t_term, delta = _best_twin_shape(problem, with_table, term, twin, rss_full, sigma2)
    delta += table.candidate.n_params
    if delta < plain[1]:
        return t_term, delta, with_table
    return plain[0], plain[1], others


#: Largest variance inflation for dependent neighbours (ρ ≈ 0.95).
MAX_DEPENDENCE = 40.0


def dependence_factor(problem: Problem, terms: Sequence[Term], beta: Any) -> float:
    """(1 + ρ)/(1 − ρ) for the lag-one correlation ρ of the model's residual in time order (row
    order without times), pooled over the measured axes; 1 for independent residuals."""
    r = problem.y - (problem.stacked(terms) @ beta).reshape(problem.y.shape)
    t = problem.res.data.t_s
    order = np.argsort(t, kind="stable") if t is not None else np.arange(len(r))
    r = r[order]
    num = float(np.sum(r[1:] * r[:-1]))
    den = float(np.sum(r * r))
    rho = min(max(num / den if den > 0 else 0.0, 0.0), 0.95)
    return float(min((1.0 + rho) / (1.0 - rho), MAX_DEPENDENCE))


def _time_order(problem: Problem) -> Any:
    t = problem.res.data.t_s
    return np.argsort(t, kind="stable") if t is not None else np.arange(problem.res.n)


def residual_in_time(problem: Problem, terms: Sequence[Term], beta: Any) -> Any:
    """(N, axes) the model's residual in time order."""
    r = problem.y - (problem.stacked(terms) @ beta).reshape(problem.y.shape)
    return r.reshape(problem.res.n, -1)[_time_order(problem)]


def _autocorrelation(x: Any, max_lag: int) -> Any:
    """Lag 1…``max_lag`` autocorrelation of the columns of ``x`` (N, a) pooled (FFT)."""
    n = x.shape[0]
    size = 1 << int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(x, size, axis=0)
    acov = np.fft.irfft(f * np.conj(f), size, axis=0)[: max_lag + 1].sum(axis=1)
    return acov[1:] / acov[0] if acov[0] > 0 else np.zeros(max_lag)


#: Longest lag (share of the record) of the residual's autocorrelation summed.
MAX_LAG_SHARE = 0.25


def initial_positive_lags(rho: Any) -> int:
    """How many lags (1…) of the autocorrelation ``rho`` (lags 1, 2, …) Geyer's initial
    positive sequence keeps: the sums of adjacent pairs Γ_m = ρ_2m + ρ_2m+1 (ρ_0 = 1) are
    positive for any stationary series; the sequence stops before the first Γ_m ≤ 0 (m ≥ 1).
    Single lags of a weak, long correlation dip below zero by chance (ρ ≈ 0.04 ± 0.03 over 88
    lags of an Ornstein–Uhlenbeck part of 2.3 s at 38 Hz: cut at lag 5, a factor 1.4 for a
    drift's slow direction where the noise holds ~20)."""
    full = np.r_[1.0, np.asarray(rho, float)]
    m = 1
    while 2 * m + 1 < len(full) and full[2 * m] + full[2 * m + 1] > 0.0:
        m += 1
    return min(2 * m - 1, len(rho))


def direction_factor(problem: Problem, resid_t: Any, gap: Any, fallback: float) -> float:
    """The variance inflation of a difference of fits along ``gap`` (stacked) for the
    residual ``resid_t`` (in time order): 1 + 2·Σ_k ρ_k·c_k, ρ_k the residual's
    autocorrelation at lag k (Geyer's initial positive sequence, :func:`initial_positive_lags`) and
    c_k that of ``gap`` — noise correlated over seconds inflates a slow difference (a
    reversal's change along the travel, a drift's shape) by its whole correlation time and a
    cyclic one of a short period hardly at all. The lag-one factor :func:`dependence_factor`
    (``fallback``) said 1.2 where the slow difference between a reversal and a latency
    (a 0.05 µm Ornstein–Uhlenbeck noise of 2.9 s at 22 Hz) was ~12 times noisier than white
    (``latency/bidirectional-one-speed/s4002``: Δχ² +18 where physics says the two are one)."""
    g = np.asarray(gap, float).reshape(problem.res.n, -1)[_time_order(problem)]
    if not np.any(g) or resid_t.shape[0] < 3:
        return fallback
    max_lag = max(int(MAX_LAG_SHARE * resid_t.shape[0]), 1)
    rho = _autocorrelation(resid_t, max_lag)
    rho = rho[: initial_positive_lags(rho)]
    if not len(rho):
        return 1.0
    c = _autocorrelation(g, len(rho))
    return float(min(max(1.0 + 2.0 * float(rho @ c), 1.0), MAX_DEPENDENCE))


@dataclass
class _Judged:
    """The term a twin is judged against: the other terms, the term, its family, its fitted
    contribution (stacked, µm) and the model's residual in time order."""

    others: list[Term]
    term: Term
    root: Candidate
    target: Any
    resid_t: Any
    terms: list[Term]  # the full model (the term at ``index``) and its fit ``beta``
    index: int
    beta: Any


def _judge_twin(
    problem: Problem,
    j: _Judged,
    twin: Candidate,
    pool: Sequence[Candidate],
    figures: tuple[float, float, float, float],
) -> tuple[Term, float, float, list[Term]]:
    """One twin refitted in place of the term (``figures``: the full model's RSS, σ² with the
    lag-one factor, that factor, the χ²₁ band): (twin term, Δχ², separability, the others it was
    judged with) — both figures in σ² along the difference the twin cannot follow."""
    rss_full, sigma2, kappa, band = figures
    others, term, root, target = j.others, j.term, j.root, j.target
    plain = _best_twin_shape(problem, others, term, twin, rss_full, sigma2)
    axis = _axis_of(root)
    table = (
        _table_of(axis, pool, others)
        if (root.cause, twin.cause) in CARRIES_TABLE and axis is not None
        else None
    )
    t_term, delta, judged_with = _twin_with_table(
        problem, others, term, twin, plain, table, rss_full, sigma2
    )
    gap = _imitation_gap(problem, judged_with, t_term, target)
    misfit = float(gap @ gap)
    # σ² per effective observation *along the difference the twin cannot follow*: slow
    # differences (a reversal's slope, a drift's shape) are as noisy as the residual's slow
    # part, a cyclic one is not (:func:`direction_factor`)
    k_gap = direction_factor(problem, j.resid_t, gap, kappa)
    extra = t_term.candidate.n_params - term.candidate.n_params
    extra += sum(t.candidate.n_params for t in judged_with[len(others) :])
    delta = (delta - extra) * kappa / k_gap + extra
    apart = misfit / (sigma2 / kappa * k_gap)
    # a twin through the map between position and reading is separable only by the physical
    # difference between the coordinates, not by the map's imperfections in a quiet session
    # (a reversal and a latency, or two drifts, differ by their own columns: no map)
    mapped = {twin.locked_to, root.locked_to} == {"position", "reference"}
    if mapped and {root.cause, twin.cause} == {"periodic", "reference_ripple"}:
        # two cyclic errors of the two coordinates are told apart only by how far the
        # coordinates move apart between the directions (the reversal), as the term's own
        # phase shows it against its noise — not by the map's imperfections in a quiet session
        z2 = shift_noncentrality(problem, j.terms, j.index, j.beta, twin, np.sqrt(sigma2))
        apart = min(apart, z2)
    elif mapped and misfit < SEPARATION_FLOOR * float(target @ target):
        apart = min(apart, band)
    return t_term, delta, apart, judged_with


def decide_sources(
    problem: Problem,
    accepted: list[Term],
    roots: list[Candidate],
    pool: Sequence[Candidate],
    alpha: float,
) -> list[SourceCall]:
    """The source and coordinate of each accepted term (module docstring). ``roots`` are the
    accepted terms' family candidates (their twins are looked up from them); ``pool`` holds
    every candidate and twin. Terms replaced by a better twin are replaced in ``accepted`` and
    ``roots`` in place."""
    calls: list[SourceCall] = []
    n_obs = problem.y.size
    band = float(stats.chi2.ppf(1.0 - alpha, 1))
    for i in range(len(accepted)):
        call: SourceCall | None = None
        replaced: str | None = None
        for _ in range(2):  # a term replaced by its twin is tested once more, as the twin
            term, root = accepted[i], roots[i]
            beta, rss_full, rank = fit(problem, accepted)
            # neighbouring residuals of a dense record are not independent: one σ² per
            # effective observation (Bartlett: n·(1 − ρ)/(1 + ρ), ρ the lag-one correlation)
            kappa = dependence_factor(problem, accepted, beta)
            sigma2 = max(rss_full / max(n_obs - rank, 1), 1e-300) * kappa
            others = accepted[:i] + accepted[i + 1 :]
            target = contribution(problem, accepted, beta, i)
            resid_t = residual_in_time(problem, accepted, beta)
            call = SourceCall(root.source, root.locked_to, replaced=replaced)
            better: tuple[float, Term, Candidate] | None = None
            for twin in twins_of(root, pool, term.theta):
                t_term, delta, apart, judged_with = _judge_twin(
                    problem, _Judged(others, term, root, target, resid_t, accepted, i, beta),
                    twin, pool,
                    (rss_full, sigma2, kappa, band),
                )  # fmt: skip
                call.twins.append(
                    {
                        "cause": twin.cause,
                        "source": twin.source,
                        "locked_to": twin.locked_to,
                        "delta_chi2": float(delta),
                        "separable_chi2": float(apart),
                    }
                )
                if apart > band and delta > band:
                    continue  # refuted
                # a twin that carried a table fits better as two causes: it imitates the term
                # by construction (the shaped drift *is* a uniform drift and a curve), so the
                # fit decides, parameters charged
                carried = judged_with is not others
                if (apart > band or carried) and delta < -band and twin.cause not in READING_SHAPES:
                    if better is None or delta < better[0]:
                        better = (delta, t_term, twin)
                    continue
                call.alternatives.append((t_term, float(delta)))
                if twin.source != root.source:
                    call.source = "either"
                if twin.locked_to != root.locked_to:
                    call.locked_to = "undetermined"
            if better is None or replaced is not None:
                break
            replaced = f"{root.label} (Δχ² {-better[0]:+.1f} against it)"
            accepted[i], roots[i] = better[1], better[2]
        assert call is not None
        calls.append(call)
    return calls


def contribution(problem: Problem, terms: Sequence[Term], beta: Any, index: int) -> Any:
    """The stacked fitted contribution of ``terms[index]`` (µm)."""
    start = problem.n_nuisance + sum(t.candidate.n_params for t in terms[:index])
    stop = start + terms[index].candidate.n_params
    return problem.design(terms[index]) @ beta[start:stop]


def _imitation_gap(problem: Problem, others: list[Term], twin: Term, target: Any) -> Any:
    """How badly the twin (with the other terms free) imitates the named term's fitted
    contribution: the part of it the twin cannot follow (stacked, µm) — its sum of squares is
    what the data could at best show."""
    x = problem.stacked([*others, twin])
    coef, *_ = np.linalg.lstsq(x, target, rcond=None)
    return target - x @ coef
