"""Candidate causes (docs/formats.md §4): each a model term linear in its amplitude parameters.

A :class:`Candidate` gives, for a value ``theta`` of its nonlinear parameter (period, time
constant, number of lobes; None when it has none), the design ``X`` (N, 3, p): the displacement
(µm) of each point per unit of each amplitude parameter, and builds the :class:`Effect` for fitted
amplitudes. Designs come from the effects' own hooks evaluated on a zero model and mapped through
the chain's first-order Jacobian at each point's stylus offset (:func:`effect_displacement_um`), so
the fitted term is exactly the term the extended machine evaluates (up to second-order small terms).
The thermal lag acts on the machine's own expansion terms and the periodic scan is vectorised; both
are written out explicitly and checked against the effects in the tests.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..effects import (
    CouplingEffect,
    Effect,
    EvalContext,
    ParametricEffect,
    PeriodicEffect,
    ProbeLobingEffect,
    ReversalEffect,
    default_orders,
)
from ..parametric_errors import ANGULAR, AXES, AXIS_INDEX, SQUARENESS, TABLE_COMPONENTS
from ..thermal import (
    ScaleExpansionEffect,
    SquarenessDriftEffect,
    ThermalGradientEffect,
    ThermalLagEffect,
    WorkpieceExpansionEffect,
    lag_filter,
)
from .residuals import FloatArray, Residuals

LAG_TIME_CONSTANTS_S: tuple[float, ...] = tuple(
    float(v) for v in np.geomspace(120.0, 4 * 3600.0, 28)
)
LOBES: tuple[int, ...] = (2, 3, 4, 5, 6)

#: ``(amplitudes, theta) → Effect``: builds a candidate's effect for fitted amplitudes.
EffectBuilder = Callable[[list[float], Any], Effect]


def effect_displacement_um(res: Residuals, effect: Effect) -> FloatArray:
    """(N, 3) µm that ``effect`` alone adds at the points of ``res`` (first order in the chain)."""
    n = res.n
    ctx = EvalContext(
        q_mm=res.q_mm,
        u_mm=res.u_mm,
        signals={k: v.copy() for k, v in res.signals.items()},
        errors=np.zeros((n, 3, 6)),
        squareness_urad=np.zeros((n, 3)),
        direct_um=np.zeros((n, 3)),
        reference_C=res.machine.thermal.reference_C,
        reference_mm=res.machine.volume.reference_mm,
    )
    effect.transform_signals(ctx)
    effect.modify_errors(ctx)
    effect.add_direct(ctx)
    return (
        np.einsum("nias,nas->ni", res.jacobian, ctx.errors)
        + np.einsum("nij,nj->ni", res.squareness_jacobian, ctx.squareness_urad)
        + ctx.direct_um
    )


@dataclass
class Candidate:
    """One candidate cause with its identifying keys (``component``, ``axis`` …)."""

    cause: str
    keys: dict[str, Any]
    n_params: int
    build: EffectBuilder  # (amplitudes, theta) → Effect
    thetas: tuple[Any, ...] = (None,)
    look_elsewhere: float = 1.0  # effective number of independent theta values tried
    design_fn: Callable[[Residuals, Any], FloatArray] | None = None
    _cache: dict[tuple[int, Any], FloatArray] = field(default_factory=dict, repr=False)

    @property
    def label(self) -> str:
        extra = ",".join(f"{k}={v}" for k, v in self.keys.items())
        return f"{self.cause}({extra})" if extra else self.cause

    def design(self, res: Residuals, theta: Any = None) -> FloatArray:
        """(N, 3, p) displacement per unit amplitude (cached per data set and theta)."""
        key = (id(res), theta)
        if key not in self._cache:
            if self.design_fn is not None:
                x = self.design_fn(res, theta)
            else:
                cols = []
                for j in range(self.n_params):
                    amps = [0.0] * self.n_params
                    amps[j] = 1.0
                    cols.append(effect_displacement_um(res, self.build(amps, theta)))
                x = np.stack(cols, axis=2)
            self._cache[key] = x
        return self._cache[key]


def _span(res: Residuals, axis: str) -> tuple[float, float]:
    k = AXIS_INDEX[axis]
    lo, hi = float(res.machine.volume.lower_mm[k]), float(res.machine.volume.upper_mm[k])
    return (lo, hi) if hi > lo else (lo - 0.5, lo + 0.5)


def _lag_design(res: Residuals, tau: Any) -> FloatArray:
    """Displacement per unit ``fraction``: α_j·(lag_τ(T_j) − T_j)·u_j/1000 on axis j."""
    x = np.zeros((res.n, 3, 1))
    t = res.signals["t"]
    for k, a in enumerate(AXES):
        alpha = float(res.machine.thermal.expansion[k])
        temp = res.signals.get(f"T_{a}")
        if alpha and temp is not None:
            x[:, k, 0] = alpha * (lag_filter(t, temp, float(tau)) - temp) * res.u_mm[:, k] / 1000.0
    return x


def _periodic_design(axis: str) -> Callable[[Residuals, Any], FloatArray]:
    def design(res: Residuals, period: Any) -> FloatArray:
        k = AXIS_INDEX[axis]
        eff = PeriodicEffect(axis, float(period), 1.0, 0.0)
        c, s = eff.shape(res.q_mm[:, k], float(res.machine.volume.reference_mm[k]))
        x = np.zeros((res.n, 3, 2))
        x[:, k, 0], x[:, k, 1] = c, s
        return x

    return design


def periodic_periods(
    span_mm: tuple[float, float], positions_mm: FloatArray | None = None
) -> tuple[tuple[float, ...], float]:
    """Scan grid of periods (mm) for an axis of travel L: 1.5 to 80 periods within L, spaced
    0.1/L in spatial frequency, and never shorter than 2.5× the typical gap between the
    distinct positions measured (Nyquist: a few fixed targets alias short periods); and the
    effective number of independent periods tried (≈ the span of cycles per travel)."""
    length = span_mm[1] - span_mm[0]
    f_max = 80.0 / length
    if positions_mm is not None and len(positions_mm) > 1:
        distinct = np.unique(np.round(np.asarray(positions_mm) / (1e-3 * length)))
        if len(distinct) > 1:
            gap = float(np.median(np.diff(distinct))) * 1e-3 * length
            f_max = min(
                f_max, 1.0 / (2.5 * gap)
            )  # margin: at 2 samples per period a sine aliases to ~0
    f = np.arange(1.5 / length, f_max, 0.1 / length)
    return tuple(float(v) for v in 1.0 / f), max(1.0, (f_max - 1.5 / length) * length)


def _parametric_builder(comp: str, span: tuple[float, float], orders: list[int]) -> EffectBuilder:
    return lambda a, _t: ParametricEffect(comp, a, span, orders)


def _coupling_builder(
    comp: str, other: str, sa: tuple[float, float], sb: tuple[float, float]
) -> EffectBuilder:
    return lambda a, _t: CouplingEffect(comp, other, a, sa, sb)


def _reversal_builder(a: str, span: tuple[float, float]) -> EffectBuilder:
    return lambda p, _t: ReversalEffect(a, p, span)


def _periodic_builder(a: str) -> EffectBuilder:
    return lambda p, period: PeriodicEffect(a, float(period), p[0], p[1])


def all_candidates(res: Residuals) -> list[Candidate]:
    """Every cause of docs/formats.md §4 that the measurements can show (signals present, axis moved)."""
    m = res.machine
    ref_c = m.thermal.reference_C
    moved = {a: float(np.ptp(res.q_mm[:, k])) > 1e-6 for k, a in enumerate(AXES)}
    out: list[Candidate] = []
    for comp in (*TABLE_COMPONENTS, *SQUARENESS):
        orders = default_orders(comp)
        if comp not in SQUARENESS and not moved[comp[-1]]:
            continue
        span = _span(res, comp[-1]) if comp not in SQUARENESS else (0.0, 1.0)
        out.append(
            Candidate(
                "parametric",
                {"component": comp},
                len(orders),
                _parametric_builder(comp, span, orders),
            )
        )
    for comp in ANGULAR:
        for other in AXES:
            if other == comp[-1] or not (moved[other] and moved[comp[-1]]):
                continue
            sa, sb = _span(res, comp[-1]), _span(res, other)
            out.append(
                Candidate(
                    "coupling",
                    {"component": comp, "varies_with": other},
                    2,
                    _coupling_builder(comp, other, sa, sb),
                )
            )

    def thermal(eff: Any) -> Effect:
        eff.reference_C = ref_c
        return eff

    def gradient_builder(a: str) -> EffectBuilder:
        return lambda p, _t: thermal(ThermalGradientEffect(a, p[0]))

    def scale_builder(a: str) -> EffectBuilder:
        return lambda p, _t: thermal(ScaleExpansionEffect(a, p[0]))

    def squareness_drift_builder(comp: str) -> EffectBuilder:
        return lambda p, _t: thermal(SquarenessDriftEffect(comp, p[0], "T_air"))

    for a in AXES:
        if not moved[a]:
            continue
        if res.has("T_top", "T_bottom"):
            out.append(
                Candidate(
                    "thermal_gradient",
                    {"axis": a},
                    1,
                    gradient_builder(a),
                )
            )
        if res.has(f"T_{a}"):
            out.append(
                Candidate(
                    "scale_expansion",
                    {"axis": a},
                    1,
                    scale_builder(a),
                )
            )
        if res.has(f"dir_{a}"):
            span = _span(res, a)
            out.append(Candidate("reversal", {"axis": a}, 2, _reversal_builder(a, span)))
        periods, n_eff = periodic_periods(_span(res, a), res.q_mm[:, AXIS_INDEX[a]])
        if not periods:
            continue
        out.append(
            Candidate(
                "periodic",
                {"axis": a},
                2,
                _periodic_builder(a),
                thetas=periods,
                look_elsewhere=n_eff,
                design_fn=_periodic_design(a),
            )
        )
    if res.has("T_wp"):
        fixture = (
            m.thermal.workpiece_fixture_mm
            if m.thermal.workpiece_fixture_mm is not None
            else m.volume.reference_mm
        )
        fx = [float(v) for v in fixture]
        out.append(
            Candidate(
                "workpiece_expansion",
                {},
                1,
                lambda p, _t: thermal(WorkpieceExpansionEffect(p[0], fx)),
            )
        )
    if res.has("T_air"):
        for comp in SQUARENESS:
            out.append(
                Candidate(
                    "squareness_drift",
                    {"component": comp},
                    1,
                    squareness_drift_builder(comp),
                )
            )
    if (
        res.has("t")
        and any(m.thermal.expansion)
        and res.has("T_x") | res.has("T_y") | res.has("T_z")
    ):
        out.append(
            Candidate(
                "thermal_lag",
                {},
                1,
                lambda p, tau: ThermalLagEffect(float(tau), p[0]),
                thetas=LAG_TIME_CONSTANTS_S,
                look_elsewhere=4.0,
                design_fn=_lag_design,
            )
        )
    if res.has("nx", "ny", "nz"):
        out.append(
            Candidate(
                "probe_lobing",
                {},
                2,
                lambda p, lobes: ProbeLobingEffect(int(lobes), p[0], p[1]),
                thetas=LOBES,
                look_elsewhere=float(len(LOBES)),
            )
        )
    return out


def contract_keys(effect: Effect) -> dict[str, Any]:
    """The docs/formats.md §4 identifying keys of an effect (cause plus component/axis/…)."""
    d = effect.describe()
    return {k: v for k, v in d.items() if k != "parameters"}


def is_finite_design(x: FloatArray) -> bool:
    return bool(np.all(np.isfinite(x))) and float(np.max(np.abs(x), initial=0.0)) > 0.0


def period_refine_bounds(period: float, span_mm: tuple[float, float]) -> tuple[float, float]:
    """±half a grid step in frequency around ``period`` (mm)."""
    length = span_mm[1] - span_mm[0]
    f = 1.0 / period
    return 1.0 / (f + 0.05 / length), 1.0 / max(f - 0.05 / length, 1e-12)


__all__ = [
    "LAG_TIME_CONSTANTS_S",
    "LOBES",
    "Candidate",
    "all_candidates",
    "contract_keys",
    "effect_displacement_um",
    "is_finite_design",
    "periodic_periods",
]
