"""Candidate terms of the reference instrument (:mod:`.reference_effects`), fitted beside the
machine's, and the machine's terms that only a locking test can tell from them.

Two lists:

* :func:`forward_candidates` — terms that compete in the forward selection like any cause: a
  chirped cyclic error (its law found by :mod:`.ripple`) locked to the reference's reading
  *and* the same law locked to the axis' position (dense records only); a latency (error ∝
  velocity, when the session has ``v_<axis>``); a drift whose change depends on the position
  along the axis (``shape: smooth``: a thermal bend or a shaped expansion of an unlogged
  temperature).
* :func:`twin_candidates` — the other instrument's version of every machine term
  (a constant-period cyclic error of the reading, a smooth nonlinearity of the reading, a
  reference scale, a reference drift the same at every position) and the machine's uniform drift:
  after selection each named term is refitted as its twins (:mod:`.sources`); a twin that fits
  as well makes the entry ``either``, one that fits decisively better replaces it.

Designs: columns on the axis' own error component (a positional error along the axis), in µm
per unit amplitude; the coordinate is ``res.ref_mm`` (reading) or ``res.q_mm`` (position).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.polynomial import legendre

from ..effects import DriftEffect, PeriodicEffect, PeriodLaw, ripple_columns, ripple_terms
from ..parametric_errors import AXES, AXIS_INDEX
from .candidate import Candidate, EffectBuilder, kept_scan, span_of
from .reference_effects import (
    LatencyEffect,
    ReferenceDriftEffect,
    ReferenceNonlinearityEffect,
    ReferenceRippleEffect,
    ReferenceScaleEffect,
)
from .residuals import FloatArray, Residuals
from .ripple import Chirp, find_chirp

__all__ = [
    "CHIRP_SHAPES",
    "cyclic_builder",
    "cyclic_design",
    "forward_candidates",
    "law_of",
    "twin_candidates",
]

#: (harmonics, envelope order) of a chirped cyclic error: default and rich. A triangulation
#: sensor's ripple is rarely a pure sine, and its amplitude changes with the distance.
CHIRP_SHAPES = ((2, 3), (3, 5))
#: (harmonics, envelope order) of the rich constant-period cyclic error of the reading.
RIPPLE_RICH = (3, 2)
#: A record with at least this many points (a one-axis stream: ``CHIRP_ONE_AXIS``) is searched
#: for a chirped cyclic error.
CHIRP_POINTS = 2000
CHIRP_ONE_AXIS = 400
#: Drift shapes along the axis (Legendre orders of position per time order): default and rich.
SMOOTH_DRIFT = ((1, 3), (2, 4))
#: Time orders of the drift twins (the same at every position).
DRIFT_TWIN_ORDERS = (1, 2, 3)
#: Orders of the reference's smooth nonlinearity (as the machine's positional table).
NONLINEARITY_ORDERS = ((1, 2, 3, 4), tuple(range(1, 9)))


def _coord(res: Residuals, axis: str, locked: str) -> FloatArray:
    k = AXIS_INDEX[axis]
    return res.ref_mm[:, k] if locked == "reference" else res.q_mm[:, k]


def _on_axis(res: Residuals, axis: str, cols: Any) -> FloatArray:
    x = np.zeros((res.n, 3, cols.shape[1]))
    x[:, AXIS_INDEX[axis], :] = cols
    return x


def law_of(theta: Any, centre: float, span: tuple[float, float]) -> PeriodLaw:
    """The period law of a chirped candidate's ``theta`` (``("triangulation", P, r0)`` or
    ``("smooth", P, g1, g2)``: log p = log P + g1·s + g2·s² over ``span``; a float: constant)."""
    if not isinstance(theta, tuple):
        return PeriodLaw("constant", float(theta))
    kind, p_c = theta[0], float(theta[1])
    if kind == "triangulation":
        return PeriodLaw(kind, p_c, centre, r0_mm=float(theta[2]))
    lo, hi = span
    knots = np.sort(np.r_[np.linspace(lo, hi, 5), centre])
    knots = np.unique(knots)
    s = 2.0 * (knots - 0.5 * (lo + hi)) / (hi - lo)
    p = p_c * np.exp(float(theta[2]) * s + float(theta[3]) * s**2)
    p[np.argmin(np.abs(knots - centre))] = p_c  # the law's period at the centre is P exactly
    return PeriodLaw(
        "smooth", p_c, centre, knots_mm=tuple(float(v) for v in knots), period_at_knots_mm=tuple(p)
    )


def _chirp_thetas(
    chirp: Chirp, span: tuple[float, float]
) -> tuple[tuple[Any, ...], tuple[float, ...]]:
    """A small grid about the law found (the period at the centre stepped by a quarter cycle
    of phase over the travel) and the steps of the continuous refinement."""
    law = chirp.law
    cycles = (span[1] - span[0]) / law.period_mm
    step = 0.25 / max(cycles, 1.0) * law.period_mm
    if law.kind == "triangulation":
        r0 = float(law.r0_mm)  # type: ignore[arg-type]
        tri: tuple[Any, ...] = tuple(
            ("triangulation", law.period_mm + k * step, r0) for k in range(-2, 3)
        )
        return tri, (step, 0.05 * abs(law.centre_mm - r0))
    lo, hi = span
    s = 2.0 * (np.asarray(law.knots_mm) - lo) / (hi - lo) - 1.0
    g = np.polynomial.polynomial.polyfit(s, np.log(law.period_at_knots_mm), 2)
    grid = tuple(
        ("smooth", law.period_mm + k * step, float(g[1]), float(g[2])) for k in range(-2, 3)
    )
    return grid, (step, 0.02, 0.02)


def cyclic_design(
    axis: str,
    locked: str,
    shape: tuple[int, int],
    centre: float,
    span: tuple[float, float],
    ref_point: float,
) -> Callable[[Residuals, Any], FloatArray]:
    """The design of a cyclic error of ``shape`` (harmonics, envelope order) locked to
    ``locked`` (``position``: the machine's, zero at the reference point ``ref_point``;
    ``reference``: the sensor's), its period law ``law_of(theta, centre, span)``."""
    h, e = shape

    def design(r: Residuals, theta: Any) -> FloatArray:
        law = law_of(theta, centre, span)
        cols = ripple_columns(_coord(r, axis, locked), law, h, e, span)
        if locked == "position":  # the machine's term is zero at the reference point
            cols = cols - ripple_columns(np.array([ref_point]), law, h, e, span)
        return _on_axis(r, axis, cols)

    return design


def cyclic_builder(
    axis: str, locked: str, shape: tuple[int, int], centre: float, span: tuple[float, float]
) -> EffectBuilder:
    """The effect of :func:`cyclic_design`'s columns for fitted amplitudes: the sensor's
    :class:`ReferenceRippleEffect` or the machine's :class:`PeriodicEffect`."""
    h, e = shape

    def build(a: list[float], theta: Any) -> Any:
        law = law_of(theta, centre, span)
        terms = ripple_terms(a, h, e)
        if locked == "reference":
            return ReferenceRippleEffect(axis, law, terms, span)
        first = [t for t in terms if t[1] == 0]
        return PeriodicEffect(
            axis,
            law.period_mm,
            first[0][2],
            first[0][3],
            [(t[2], t[3]) for t in first[1:]],
            law,
            [t for t in terms if t[1] > 0],
            span,
        )

    return build


def _chirp_candidate(
    res: Residuals, axis: str, chirp: Chirp, locked: str, centre: float, span: tuple[float, float]
) -> Candidate:
    """The chirped cyclic error locked to ``locked`` (``position``: the machine's ``periodic``
    with that law; ``reference``: ``reference_ripple``)."""
    thetas, steps = _chirp_thetas(chirp, span)
    k = AXIS_INDEX[axis]
    ref_point = float(res.machine.volume.reference_mm[k])

    def design_for(shape: tuple[int, int]) -> Callable[[Residuals, Any], FloatArray]:
        return cyclic_design(axis, locked, shape, centre, span, ref_point)

    def builder(shape: tuple[int, int]) -> EffectBuilder:
        return cyclic_builder(axis, locked, shape, centre, span)

    (h0, e0), (h1, e1) = CHIRP_SHAPES
    cause = "reference_ripple" if locked == "reference" else "periodic"
    return Candidate(
        cause,
        {"axis": axis},
        2 * h0 * (e0 + 1),
        builder((h0, e0)),
        thetas=thetas,
        # the windows' period scan and the law's parameters: as many independent tries as the
        # dense periodic scan, times the law's
        look_elsewhere=float(len(chirp.windows)) * 40.0,
        design_fn=design_for((h0, e0)),
        source="reference" if locked == "reference" else "machine",
        locked_to=locked,
        theta_step=steps,
        envelope=e0,
    ).with_rich(
        n_params=2 * h1 * (e1 + 1),
        build=builder((h1, e1)),
        design_fn=design_for((h1, e1)),
        envelope=e1,
    )


def _nyquist_mm(q: FloatArray, length: float) -> float:
    distinct = np.unique(np.round(q / (1e-3 * length)))
    gap = float(np.median(np.diff(distinct))) * 1e-3 * length if len(distinct) > 1 else length
    return 2.5 * gap


def _chirp_candidates(res: Residuals, axis: str) -> list[Candidate]:
    k = AXIS_INDEX[axis]
    # the law is sought on the raw reading (its own sampling, the harmonics its ripple puts in
    # it); the candidates are evaluated at the distance the sensor looked at (:mod:`.reading`)
    q, r = res.q_mm[:, k], res.data.reference_mm[:, k]
    span = (float(np.min(q)), float(np.max(q)))
    length = span[1] - span[0]
    moved = sum(float(np.ptp(res.q_mm[:, j])) > 1e-6 for j in range(3))
    dense = res.n >= CHIRP_POINTS or (moved == 1 and res.n >= CHIRP_ONE_AXIS)
    if not dense or length <= 0:
        return []
    groups = res.signals.get(f"dir_{axis}", np.zeros(res.n))
    chirp = find_chirp(
        r, res.residual_um[:, k], groups, res.signals.get("t"), _nyquist_mm(q, length)
    )
    if chirp is None:
        return []
    centre = 0.5 * (span[0] + span[1])
    return [_chirp_candidate(res, axis, chirp, c, centre, span) for c in ("reference", "position")]


def _dense_bidirectional(res: Residuals, axis: str) -> bool:
    """A dense record (the chirp search's rule) with each direction on ≥ 10 % of the points."""
    moved = sum(float(np.ptp(res.q_mm[:, j])) > 1e-6 for j in range(3))
    if not (res.n >= CHIRP_POINTS or (moved == 1 and res.n >= CHIRP_ONE_AXIS)):
        return False
    d = res.signals.get(f"dir_{axis}")
    return d is not None and 0.1 <= float(np.mean(d > 0)) <= 0.9


def _latency_candidate(res: Residuals, axis: str) -> Candidate | None:
    v = res.signals.get(f"v_{axis}")
    if v is None or float(np.ptp(v)) <= 0:
        return None

    def design(r: Residuals, _theta: Any) -> FloatArray:
        return _on_axis(r, axis, -r.signals[f"v_{axis}"][:, None])

    return Candidate(
        "latency",
        {"axis": axis},
        1,
        lambda a, _t: LatencyEffect(axis, a[0]),
        design_fn=design,
        source="reference",
        locked_to="velocity",
    )


def _smooth_drift_builder(
    axis: str, t_span: tuple[float, float], span: tuple[float, float], k_t: int, j_max: int
) -> EffectBuilder:
    def build(a: list[float], _theta: Any) -> Any:
        rows = [list(a[i * (j_max + 1) : (i + 1) * (j_max + 1)]) for i in range(k_t)]
        return DriftEffect(axis, t_span, [0.0] * k_t, [0.0] * (k_t + 1), rows, span)

    return build


def _smooth_drift(res: Residuals, axis: str) -> Candidate | None:
    t = res.signals.get("t")
    if t is None or float(np.ptp(t)) <= 0:
        return None
    t_span = (float(np.min(t)), float(np.max(t)))
    span = span_of(res, axis)
    (k0, j0), (k1, j1) = SMOOTH_DRIFT

    def build_for(k_t: int, j_max: int) -> tuple[EffectBuilder, int]:
        return _smooth_drift_builder(axis, t_span, span, k_t, j_max), k_t * (j_max + 1)

    b0, n0 = build_for(k0, j0)
    b1, n1 = build_for(k1, j1)
    return Candidate(
        "drift", {"axis": axis}, n0, b0, drivers=("t",), hold_time=True, locked_to="time"
    ).with_rich(n_params=n1, build=b1)


def forward_candidates(
    res: Residuals,
    moved: dict[str, bool],
    periodic_scans: dict[str, list[tuple[Any, float]]] | None = None,
) -> list[Candidate]:
    """The reference's terms (and their position-locked versions) that compete in selection:
    the chirped ripples, the latency, the position-shaped drift, and — on a dense record run in
    both directions, where a constant-period ripple of the reading is smeared in position
    coordinates by the reversal (a fifth of a period moves it by 72°) and the machine's scan
    would miss it, unless the chirp search proposed the reading's ripple with its law — the
    reading's constant-period scan (``periodic_scans``: the machine's
    period grids, the same look-elsewhere charge)."""
    out: list[Candidate] = []
    for a in AXES:
        if not moved[a]:
            continue
        chirps = _chirp_candidates(res, a)
        out += chirps
        # (a chirp found: the reading's ripple is proposed with its law already)
        if not chirps and periodic_scans and _dense_bidirectional(res, a):
            for periods, n_eff in periodic_scans.get(a, []):
                if periods:
                    out.append(_ripple_twin(res, a, periods, n_eff))
        latency = _latency_candidate(res, a)
        if latency is not None:
            out.append(latency)
        drift = _smooth_drift(res, a)
        if drift is not None:
            out.append(drift)
    return out


# ----------------------------------------------------------------------------- twins
def _ripple_twin(res: Residuals, axis: str, periods: Sequence[float], n_eff: float) -> Candidate:
    """A constant-period cyclic error of the reading; rich: 3 harmonics and an amplitude that
    changes along the reading (:data:`RIPPLE_RICH`: a sensor's nonlinearity is rarely as large
    at both ends of its range)."""
    k = AXIS_INDEX[axis]
    h1, e1 = RIPPLE_RICH
    span = (float(np.min(res.q_mm[:, k])), float(np.max(res.q_mm[:, k])))

    def design_for(h: int, e: int) -> Callable[[Residuals, Any], FloatArray]:
        def design(r: Residuals, period: Any) -> FloatArray:
            law = PeriodLaw("constant", float(period))
            return _on_axis(r, axis, ripple_columns(r.ref_mm[:, k], law, h, e, span))

        return design

    def builder(h: int, e: int) -> EffectBuilder:
        return lambda a, period: ReferenceRippleEffect(
            axis, PeriodLaw("constant", float(period)), ripple_terms(a, h, e), span
        )

    return Candidate(
        "reference_ripple",
        {"axis": axis},
        2,
        builder(1, 0),
        thetas=tuple(periods),
        look_elsewhere=n_eff,
        design_fn=design_for(1, 0),
        design_many=_reading_scan(k),
        design_component=k,
        source="reference",
        locked_to="reference",
    ).with_rich(
        n_params=2 * h1 * (e1 + 1),
        build=builder(h1, e1),
        design_fn=design_for(h1, e1),
        envelope=e1,
    )


def _reading_scan(k: int) -> Callable[[Residuals, Sequence[Any]], FloatArray]:
    """(N, T, 2) cos/sin of the reading for T periods at once (the scan's profile: the same
    span as :func:`ripple_columns` of a constant law, whose phase origin only rotates them)."""

    def design(r: Residuals, periods: Sequence[Any]) -> FloatArray:
        ph = np.outer(r.ref_mm[:, k], 2.0 * np.pi / np.asarray([float(p) for p in periods]))
        return np.stack([np.cos(ph), np.sin(ph)], axis=2)

    return kept_scan(design)


def _nonlinearity_twin(res: Residuals, axis: str) -> Candidate:
    span = span_of(res, axis)

    def design_for(orders: Sequence[int]) -> Callable[[Residuals, Any], FloatArray]:
        def design(r: Residuals, _theta: Any) -> FloatArray:
            s = 2.0 * (r.ref_mm[:, AXIS_INDEX[axis]] - span[0]) / (span[1] - span[0]) - 1.0
            v = legendre.legvander(s, max(orders))[:, list(orders)]
            return _on_axis(r, axis, v)

        return design

    def builder(orders: Sequence[int]) -> EffectBuilder:
        return lambda a, _t: ReferenceNonlinearityEffect(axis, a, orders, span)

    o0, o1 = NONLINEARITY_ORDERS
    return Candidate(
        "reference_nonlinearity",
        {"axis": axis},
        len(o0),
        builder(o0),
        design_fn=design_for(o0),
        source="reference",
        locked_to="reference",
    ).with_rich(n_params=len(o1), build=builder(o1), design_fn=design_for(o1))


def _scale_twin(res: Residuals, axis: str) -> Candidate:
    k = AXIS_INDEX[axis]
    centre = float(res.machine.volume.reference_mm[k])

    def design(r: Residuals, _theta: Any) -> FloatArray:
        return _on_axis(r, axis, (r.ref_mm[:, k : k + 1] - centre) / 1000.0)

    return Candidate(
        "reference_scale",
        {"axis": axis},
        1,
        lambda a, _t: ReferenceScaleEffect(axis, a[0], centre),
        design_fn=design,
        source="reference",
        locked_to="reference",
    )


def _drift_twins(res: Residuals, axis: str) -> list[Candidate]:
    """The reference's drift (the same at every position) and the machine's uniform drift: the
    same term, one per instrument (a session cannot tell them apart)."""
    t = res.signals.get("t")
    if t is None or float(np.ptp(t)) <= 0:
        return []
    t_span = (float(np.min(t)), float(np.max(t)))

    def design_for(order: int) -> Callable[[Residuals, Any], FloatArray]:
        def design(r: Residuals, _theta: Any) -> FloatArray:
            tau = 2.0 * (r.signals["t"] - t_span[0]) / (t_span[1] - t_span[0]) - 1.0
            return _on_axis(r, axis, legendre.legvander(tau, order)[:, 1:])

        return design

    def reference(order: int) -> EffectBuilder:
        return lambda a, _t: ReferenceDriftEffect(axis, t_span, a)

    def machine(order: int) -> EffectBuilder:
        return lambda a, _t: DriftEffect(axis, t_span, a, [0.0] * (order + 1))

    out = []
    for source, builder in (("reference", reference), ("machine", machine)):
        cause = "reference_drift" if source == "reference" else "drift"
        # one per time order of the machine's drifts (linear, quadratic, cubic): a drift that
        # changes along the axis is compared with the same change in time, uniform
        for order in DRIFT_TWIN_ORDERS:
            out.append(
                Candidate(
                    cause,
                    {"axis": axis},
                    order,
                    builder(order),
                    design_fn=design_for(order),
                    drivers=("t",),
                    hold_time=True,
                    source=source,
                    locked_to="time",
                ).with_rich(n_params=10, build=builder(10), design_fn=design_for(10))
            )
    return out


def twin_candidates(
    res: Residuals, moved: dict[str, bool], periodic_scans: dict[str, list[tuple[Any, float]]]
) -> list[Candidate]:
    """The other instrument's version of the machine's terms (module docstring);
    ``periodic_scans`` the machine's period grids per axis (the reading's twin scans the same)."""
    out: list[Candidate] = []
    for a in AXES:
        if not moved[a]:
            continue
        for periods, n_eff in periodic_scans.get(a, []):
            out.append(_ripple_twin(res, a, periods, n_eff))
        out += [_nonlinearity_twin(res, a), _scale_twin(res, a), *_drift_twins(res, a)]
    return out
