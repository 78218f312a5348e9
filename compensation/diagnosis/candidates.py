"""Candidate causes of the machine (docs/formats.md §4), each a model term linear in its
amplitude parameters: table changes, couplings, reversal, cyclic errors, drifts and probe lobing
here; the thermal causes in :mod:`.thermal_candidates`; the reference instrument's terms in
:mod:`.reference_candidates`. :func:`all_candidates` gathers every family the session can show.

The term itself, its shapes and its source: :mod:`.candidate`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..effects import (
    CouplingEffect,
    DriftEffect,
    ParametricEffect,
    PeriodicEffect,
    ProbeLobingEffect,
    ReversalEffect,
    default_orders,
)
from ..effects.harmonic_kernel import harmonic_columns
from ..parametric_errors import ANGULAR, AXES, AXIS_INDEX, LINEAR, SQUARENESS, TABLE_COMPONENTS
from .candidate import (
    Candidate,
    EffectBuilder,
    contract_keys,
    effect_displacement_um,
    is_finite_design,
    kept_scan,
    span_of,
    with_static_image,
)
from .reference_candidates import forward_candidates, twin_candidates
from .residuals import FloatArray, Residuals
from .thermal_candidates import LAG_TIME_CONSTANTS_S, thermal_candidates

LOBES: tuple[int, ...] = (2, 3, 4, 5, 6)


def _periodic_columns(
    res: Residuals, axis: str, periods: Sequence[Any], harmonics: int
) -> FloatArray:
    """(N, T, 2·harmonics) cos/sin columns of harmonics 1…H for each of T periods, on the axis'
    positional error (that component only), each minus its value at the reference point
    (PeriodicEffect)."""
    k = AXIS_INDEX[axis]
    ref = float(res.machine.volume.reference_mm[k])
    return harmonic_columns(res.q_mm[:, k], periods, ref, harmonics)


def _periodic_design(axis: str, harmonics: int = 1) -> Callable[[Residuals, Any], FloatArray]:
    k = AXIS_INDEX[axis]

    def design(res: Residuals, period: Any) -> FloatArray:
        x = np.zeros((res.n, 3, 2 * harmonics))
        x[:, k, :] = _periodic_columns(res, axis, [period], harmonics)[:, 0, :]
        return x

    return design


def _periodic_design_many(
    axis: str, harmonics: int = 1
) -> Callable[[Residuals, Sequence[Any]], FloatArray]:
    def design(res: Residuals, periods: Sequence[Any]) -> FloatArray:
        return _periodic_columns(res, axis, periods, harmonics)

    return kept_scan(design)


#: Cycles per travel scanned by the periodic candidate; a dense record (:func:`dense_record`)
#: also gets a short-period candidate up to ``DENSE_CYCLES`` (a screw's pitch, an encoder's or a
#: sensor's interpolation error), never beyond what the positions' spacing resolves.
PERIODIC_CYCLES = 80.0
DENSE_CYCLES = 2000.0
DENSE_POINTS = 2000
DENSE_ONE_AXIS = 400
#: Spacing of the period scan in cycles per travel: 5 grid values per resolution element 1/L
#: (a peak between two of them loses at most 3 % of its power before refinement).
PERIOD_STEP_CYCLES = 0.2


def periodic_periods(
    span_mm: tuple[float, float],
    positions_mm: FloatArray | None = None,
    cycles: tuple[float, float] = (1.5, PERIODIC_CYCLES),
) -> tuple[tuple[float, ...], float]:
    """Scan grid of periods (mm) for an axis of travel L: 1.5 to 80 periods within L, spaced
    :data:`PERIOD_STEP_CYCLES`/L in spatial frequency (5× finer than a record of length L
    resolves; the best grid value is then refined continuously), and never shorter than 2.5× the typical gap between the
    distinct positions measured (Nyquist: a few fixed targets alias short periods); and the
    effective number of independent periods tried (≈ the span of cycles per travel)."""
    length = span_mm[1] - span_mm[0]
    f_min, f_max = cycles[0] / length, cycles[1] / length
    if positions_mm is not None and len(positions_mm) > 1:
        distinct = np.unique(np.round(np.asarray(positions_mm) / (1e-6 * length)))
        if len(distinct) > 1:
            gap = float(np.median(np.diff(distinct))) * 1e-6 * length
            f_max = min(
                f_max, 1.0 / (2.5 * gap)
            )  # margin: at 2 samples per period a sine aliases to ~0
    f = np.arange(f_min, f_max, PERIOD_STEP_CYCLES / length)
    return tuple(float(v) for v in 1.0 / f), max(1.0, (f_max - f_min) * length)


def _parametric_builder(comp: str, span: tuple[float, float], orders: list[int]) -> EffectBuilder:
    return lambda a, _t: ParametricEffect(comp, a, span, orders)


def _coupling_builder(
    comp: str,
    other: str,
    sa: tuple[float, float],
    sb: tuple[float, float],
    orders: tuple[int, ...],
    with_orders: tuple[int, ...],
    n_along: int,
) -> EffectBuilder:
    # a: offset, the part along a at b's reference (orders 1…n_along), then the products
    return lambda a, _t: CouplingEffect(
        comp, other, a[1 + n_along :], sa, sb, orders, with_orders, a[0], a[1 : 1 + n_along]
    )


#: A guideway's bend that changes with another axis' position, its carriage following the
#: slope: orders along the guideway (default, rich) and along the other axis.
BEND_ORDERS = ((1, 2, 3, 4), (1, 2, 3, 4, 5, 6))
BEND_WITH = (1, 2)


def _bend_candidate(
    comp: str, other: str, sa: tuple[float, float], sb: tuple[float, float]
) -> Candidate:
    """A guideway of ``comp``'s axis bent by an amount that changes with ``other``'s position
    (a load that moves, a ram whose moment grows as it extends), its carriage pitching by the
    local slope of the bend (:func:`cmm_comp.compensation.effects.parametric.slope_of`): one
    physical cause, the straightness and the angle tied, named as the straightness coupling."""

    def builder(orders: tuple[int, ...]) -> EffectBuilder:
        # a: the bend where the other axis is at its reference (orders along the guideway),
        # then how it changes with the other axis (with_orders-major, along the guideway also
        # uniformly: the deflection at the reference point itself changes with it)
        n = len(orders)
        return lambda a, _t: CouplingEffect(
            comp, other, a[n:], sa, sb, (0, *orders), BEND_WITH, 0.0, a[:n], with_slope=True
        )

    def size(orders: tuple[int, ...]) -> int:
        return len(orders) + (1 + len(orders)) * len(BEND_WITH)

    lo, hi = BEND_ORDERS
    return Candidate(
        "coupling",
        {"component": comp, "varies_with": other},
        size(lo),
        builder(lo),
        static_columns=len(lo),
    ).with_rich(n_params=size(hi), build=builder(hi), static_columns=len(hi))


def _drift_builder(a: str, span: tuple[float, float], order: int) -> EffectBuilder:
    return lambda p, _t: DriftEffect(a, span, p[:order], p[order:])  # K offsets, K + 1 scales


#: Shapes of each family: (default, rich). The default is what a cause usually looks like; the
#: rich one absorbs what a mis-shaped default leaves behind and is reported when the data need it.
COUPLING_ORDERS = (((0, 1, 2), (1, 2)), ((0, 1, 2, 3), (1, 2)))
#: Orders of the part along a at b's reference position (default, rich).
COUPLING_ALONG = (2, 3)
PERIODIC_HARMONICS = (1, 3)
DRIFT_ORDERS = (3, 10)
DRIFT_LINEAR = (1, 10)


def candidate_orders(component: str) -> list[int]:
    """Legendre orders of a table correction's default shape: the effect's defaults, and for an
    angular table also a constant (a carriage tilted by the same angle everywhere: the table was
    zeroed elsewhere than at the reference point, which a stylus offset reveals)."""
    if component in ANGULAR:
        return [0, *default_orders(component)]
    return default_orders(component)


def rich_orders(component: str) -> list[int]:
    """Legendre orders of a table correction's rich shape (up to 8 along the axis; a straightness
    with its line)."""
    base = default_orders(component)
    if component in SQUARENESS:
        return base
    if component in ANGULAR:  # a constant too: the carriage tilted by the same angle everywhere
        return list(range(0, 7))
    if component[1] != component[-1]:
        # a straightness with its line: what a squareness would carry beside a straightness
        # change whose reference line was fitted on other points (the default names the line a
        # squareness; the rich shape keeps it with the table, so it is never a second cause)
        return list(range(1, 9))
    return list(range(base[0], 9))


def _reversal_builder(a: str, span: tuple[float, float]) -> EffectBuilder:
    return lambda p, _t: ReversalEffect(a, p, span)


def _periodic_builder(a: str) -> EffectBuilder:
    return lambda p, period: PeriodicEffect(
        a, float(period), p[0], p[1], [p[i : i + 2] for i in range(2, len(p), 2)]
    )


def periodic_scans(res: Residuals, axis: str) -> list[tuple[tuple[float, ...], float]]:
    """The period grids scanned on ``axis`` (and their look-elsewhere factors): the usual one,
    and for a dense record the short periods too."""
    q = res.q_mm[:, AXIS_INDEX[axis]]
    scans = [periodic_periods(span_of(res, axis), q)]
    if dense_record(res):
        scans.append(periodic_periods(span_of(res, axis), q, (PERIODIC_CYCLES, DENSE_CYCLES)))
    return [sc for sc in scans if sc[0]]


def dense_record(res: Residuals) -> bool:
    """A record dense along its axis: ``DENSE_POINTS`` points or more, or a one-axis stream of
    ``DENSE_ONE_AXIS`` or more (a laser or sensor calibration of one axis): short periods and a
    period that changes along the travel can show there."""
    moved = sum(float(np.ptp(res.q_mm[:, k])) > 1e-6 for k in range(3))
    return res.n >= DENSE_POINTS or (moved == 1 and res.n >= DENSE_ONE_AXIS)


#: A reversal needs each direction of travel on at least this share of the points (a session
#: run one way, with a few points from the move that set it up, shows none: its "reversal" would
#: only be a scale term times the direction).
MIN_DIRECTION_SHARE = 0.1


def _both_directions(d: FloatArray) -> bool:
    share = float(np.mean(d > 0))
    return MIN_DIRECTION_SHARE <= share <= 1.0 - MIN_DIRECTION_SHARE


def _moved(res: Residuals) -> dict[str, bool]:
    return {a: float(np.ptp(res.q_mm[:, k])) > 1e-6 for k, a in enumerate(AXES)}


def all_twins(res: Residuals) -> list[Candidate]:
    """The other instrument's version of the machine's terms (:mod:`.reference_candidates`)."""
    moved = _moved(res)
    scans = {a: periodic_scans(res, a) for a in AXES if moved[a]}
    return twin_candidates(res, moved, scans)


def _table_candidates(res: Residuals, moved: dict[str, bool]) -> list[Candidate]:
    """A table (Legendre shape along its axis) of each component whose axis moved, and the
    squareness angles."""
    out: list[Candidate] = []
    for comp in (*TABLE_COMPONENTS, *SQUARENESS):
        orders = candidate_orders(comp)
        if comp not in SQUARENESS and not moved[comp[-1]]:
            continue
        span = span_of(res, comp[-1]) if comp not in SQUARENESS else (0.0, 1.0)
        cand = Candidate(
            "parametric", {"component": comp}, len(orders), _parametric_builder(comp, span, orders)
        )
        if comp not in SQUARENESS:
            r_orders = rich_orders(comp)
            cand.with_rich(n_params=len(r_orders), build=_parametric_builder(comp, span, r_orders))
        out.append(cand)
    return out


def _coupling_candidates(res: Residuals, moved: dict[str, bool]) -> list[Candidate]:
    """A carriage's tilt or straightness that changes with another moved axis' position."""
    out: list[Candidate] = []
    # a carriage's tilt or its straightness that changes with another axis' position (a bridge
    # twist; a ram or beam whose bow depends on where the carriage stands)
    straightness = tuple(c for c in LINEAR if c[1] != c[-1])
    for comp in (*ANGULAR, *straightness):
        for other in AXES:
            if other == comp[-1] or not (moved[other] and moved[comp[-1]]):
                continue
            sa, sb = span_of(res, comp[-1]), span_of(res, other)
            keys = {"component": comp, "varies_with": other}
            (o1_all, w1), (o2, w2) = COUPLING_ORDERS
            o1: tuple[int, ...] = o1_all
            if comp in LINEAR:
                # a straightness that varies with b by the same amount all along a is a
                # translation that depends on b alone: a table of b, whatever the chain — not a
                # coupling's default shape (a table of b competes with it as itself); the rich
                # shape keeps it, so a coupling that has such a part is still one cause
                o1 = tuple(k for k in o1 if k)
            n1, n2 = COUPLING_ALONG
            out.append(
                Candidate(
                    "coupling",
                    keys,
                    1 + n1 + len(o1) * len(w1),
                    _coupling_builder(comp, other, sa, sb, o1, w1, n1),
                    static_columns=1 + n1,
                ).with_rich(
                    n_params=1 + n2 + len(o2) * len(w2),
                    build=_coupling_builder(comp, other, sa, sb, o2, w2, n2),
                    static_columns=1 + n2,
                )
            )
            if comp in LINEAR:
                out.append(_bend_candidate(comp, other, sa, sb))
    return out


def _axis_candidates(res: Residuals, moved: dict[str, bool]) -> list[Candidate]:
    """Per moved axis: its reversal (both directions seen), its drift in time (a time column),
    its cyclic errors (the period scans)."""
    out: list[Candidate] = []
    for a in AXES:
        if not moved[a]:
            continue
        if res.has(f"dir_{a}") and _both_directions(res.signals[f"dir_{a}"]):
            span = span_of(res, a)
            out.append(Candidate("reversal", {"axis": a}, 2, _reversal_builder(a, span)))
        if res.has("t") and float(np.ptp(res.signals["t"])) > 0:
            t_span = (float(np.min(res.signals["t"])), float(np.max(res.signals["t"])))
            # a steady drift (linear in time) and a wandering one (cubic), both with the wandering
            # shape of order 10 as rich variant: where folds are blocks of time, only a line extrapolates
            for lo_k, hi_k in (DRIFT_LINEAR, DRIFT_ORDERS):
                out.append(
                    Candidate(
                        "drift",
                        {"axis": a},
                        2 * lo_k + 1,
                        _drift_builder(a, t_span, lo_k),
                        drivers=("t",),
                        hold_time=True,
                        locked_to="time",
                    ).with_rich(n_params=2 * hi_k + 1, build=_drift_builder(a, t_span, hi_k))
                )
        h_lo, h_hi = PERIODIC_HARMONICS
        for periods, n_eff in periodic_scans(res, a):
            if not periods:
                continue
            out.append(
                Candidate(
                    "periodic",
                    {"axis": a},
                    2 * h_lo,
                    _periodic_builder(a),
                    thetas=periods,
                    look_elsewhere=n_eff,
                    design_fn=_periodic_design(a, h_lo),
                    design_many=_periodic_design_many(a, h_lo),
                    design_component=AXIS_INDEX[a],
                ).with_rich(
                    n_params=2 * h_hi,
                    design_fn=_periodic_design(a, h_hi),
                    design_many=_periodic_design_many(a, h_hi),
                )
            )
    return out


def all_candidates(res: Residuals) -> list[Candidate]:
    """Every cause of docs/formats.md §4 that the measurements can show (signals present, axis moved)."""
    moved = _moved(res)
    out = _table_candidates(res, moved) + _coupling_candidates(res, moved)
    out += _axis_candidates(res, moved)
    out += thermal_candidates(res, moved)
    out += forward_candidates(res, moved, {a: periodic_scans(res, a) for a in AXES if moved[a]})
    if res.has("nx", "ny", "nz"):
        out.append(
            Candidate(
                "probe_lobing",
                {},
                2,
                lambda p, th: ProbeLobingEffect(int(th[0]), p[0], p[1], int(th[1])),
                # (lobes, radial power): the lobing fading as ρⁿ or as ρ towards vertical probing
                thetas=tuple((k, r) for k in LOBES for r in sorted({k, 1})),
                look_elsewhere=float(2 * len(LOBES)),
            )
        )
    return out


__all__ = [
    "LAG_TIME_CONSTANTS_S",
    "LOBES",
    "Candidate",
    "all_candidates",
    "all_twins",
    "contract_keys",
    "effect_displacement_um",
    "is_finite_design",
    "periodic_periods",
    "rich_orders",
    "with_static_image",
]
