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

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..effects import (
    CouplingEffect,
    DriftEffect,
    Effect,
    EvalContext,
    ParametricEffect,
    PeriodicEffect,
    ProbeLobingEffect,
    ReversalEffect,
    StaticImageEffect,
    default_orders,
)
from ..parametric_errors import ANGULAR, AXES, AXIS_INDEX, LINEAR, SQUARENESS, TABLE_COMPONENTS
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
    float(v) for v in np.geomspace(120.0, 12 * 3600.0, 34)
)
LOBES: tuple[int, ...] = (2, 3, 4, 5, 6)
#: Plausible size (1σ) of a structure's start-up offset from its sensor (°C): a machine that has
#: stood in its room for hours is within a degree or two of what its sensors read.
START_STATE_SD_C = 2.0
#: Plausible size (1σ) of a squareness' temperature coefficient (µrad/°C).
SQUARENESS_DRIFT_SD_URAD_PER_C = 5.0

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
    #: The same cause with a richer shape (more orders, harmonics): used to absorb what a
    #: mis-shaped accepted cause leaves behind, and reported when the data need it.
    rich: Candidate | None = None
    #: Time-varying signals the cause is driven by (temperatures, time): the cause is only
    #: named when their *variation* during the session is seen, not just their mean — with the
    #: signals frozen at their session mean it is a static table change (:meth:`static`).
    drivers: tuple[str, ...] = ()
    #: For a cause driven by another axis' position (a coupling): its first columns are the part
    #: that does not vary with that axis (a table of its own axis); it must be needed beyond them.
    static_columns: int = 0
    #: (N, 3, T, p) designs for several thetas at once (fast profiles); optional. With
    #: ``design_component`` set, (N, T, p) on that error component only.
    design_many: Callable[[Residuals, Sequence[Any]], FloatArray] | None = None
    #: The one error component (0, 1, 2 for x, y, z) every column of the design lies on (a
    #: periodic error of one axis' scale), or None: lets profiles skip the other components.
    design_component: int | None = None
    #: Ridge penalty (in units of one observation per coefficient) on this term's coefficients
    #: in fits and cross-validation: a generic local basis must not extrapolate into regions
    #: the training points do not cover. 0 for the causes (plain least squares).
    ridge: float = 0.0
    #: A prior on some coefficients (their plausible size, in the coefficient's own unit; None:
    #: no prior), applied in fits and cross-validation like ``ridge`` with the weight σ²/prior²
    #: (σ² the training residual's mean square): a session's unknown start-up state (°C) is a
    #: few degrees at most, and a held-out block that holds the session's start must not be
    #: predicted by a transient the training blocks barely see.
    prior_sd: tuple[float | None, ...] | None = None
    #: A cause that is a function of time alone (a drift) is not extrapolated in time: where a
    #: held-out fold lies before or after every training point (folds are often blocks of time),
    #: it is predicted with the time held at the nearest end of the training span — a drift
    #: describes the session, and no polynomial in time says what happened beyond its data.
    hold_time: bool = False
    #: Columns that carry the session's unknown start-up state (a transient decaying from the
    #: first sample: a structure that was not in equilibrium with its sensors). Blocks of time
    #: that hold the session's start cannot be predicted from the others: the transient is not
    #: extrapolated back before a training span, and the term's held-out gain may also be shown
    #: on short time blocks dealt out in turn (as a drift's).
    transient_columns: tuple[int, ...] = ()
    _cache: dict[tuple[Any, Any], FloatArray] = field(default_factory=dict, repr=False)
    _statics: dict[tuple[int, Any], Candidate | None] = field(default_factory=dict, repr=False)

    @property
    def start_state(self) -> bool:
        """Whether the term carries the session's start-up state (``transient_columns``)."""
        return bool(self.transient_columns)

    @property
    def timed(self) -> bool:
        """A cause of time: a drift (no law beyond its session) or a term with the session's
        start-up state. Judged between neighbours in time as well (``Problem.judged_folds``)."""
        return self.hold_time or self.start_state

    @property
    def identity(self) -> tuple[Any, ...]:
        """(cause, component, axis, varies_with): what the diagnosis names (formats.md §4)."""
        k = self.keys
        return (self.cause, k.get("component"), k.get("axis"), k.get("varies_with"))

    @property
    def label(self) -> str:
        extra = ",".join(f"{k}={v}" for k, v in self.keys.items())
        return f"{self.cause}({extra})" if extra else self.cause

    def design(self, res: Residuals, theta: Any = None) -> FloatArray:
        """(N, 3, p) displacement per unit amplitude (cached per data set and theta: ``res`` must
        live as long as the candidate — use :meth:`design_uncached` for temporary data)."""
        key = (id(res), theta)
        if key not in self._cache:
            self._cache[key] = self.design_uncached(res, theta)
        return self._cache[key]

    def with_rich(self, **changes: Any) -> Candidate:
        """Give this family its rich shape: the same cause with ``changes`` (more parameters, a
        richer builder or design); returns ``self``."""
        self.rich = replace(self, rich=None, _cache={}, _statics={}, **changes)
        return self

    def static(self, res: Residuals, theta: Any = None) -> Candidate | None:
        """The part of this cause a session sees as a static error (None when it has none): for
        a signal-driven cause its design with the driving signals frozen at their session mean,
        for a coupling its columns that do not vary with the other axis. One object per data
        set (cached)."""
        # columns that depend on the nonlinear parameter (a lag's transient) are taken at it
        at = theta if self.static_columns and len(self.thetas) > 1 else self.thetas[0]
        key = (id(res), at)
        if key in self._statics:
            return self._statics[key]
        x: FloatArray | None = None
        if self.static_columns:
            x = self.design(res, at)[:, :, : self.static_columns]
            if self.drivers:  # a lagged, signal-driven cause: its transient and its mean
                rest = self.design_uncached(_frozen(res, self.drivers), at)
                rest = rest[:, :, self.static_columns :]
                x = np.concatenate([x, rest], axis=2)
        elif self.drivers:
            x = self.design_uncached(_frozen(res, self.drivers), self.thetas[0])
        static = None
        if x is not None and is_finite_design(x):
            fixed = x
            static = Candidate(
                f"{self.cause}_static",
                self.keys,
                x.shape[2],
                self.build,
                design_fn=lambda _r, _t: fixed,
            )
        self._statics[key] = static
        return static

    def design_uncached(self, res: Residuals, theta: Any = None) -> FloatArray:
        """(N, 3, p) displacement per unit amplitude, computed afresh."""
        if self.design_fn is not None:
            return self.design_fn(res, theta)
        cols = []
        for j in range(self.n_params):
            amps = [0.0] * self.n_params
            amps[j] = 1.0
            cols.append(effect_displacement_um(res, self.build(amps, theta)))
        return np.stack(cols, axis=2)


def _span(res: Residuals, axis: str) -> tuple[float, float]:
    k = AXIS_INDEX[axis]
    lo, hi = float(res.machine.volume.lower_mm[k]), float(res.machine.volume.upper_mm[k])
    return (lo, hi) if hi > lo else (lo - 0.5, lo + 0.5)


def _lag_design(res: Residuals, tau: Any) -> FloatArray:
    """Columns 0–2: the structure's unknown initial state (°C above the sensor at the session's
    first sample, axis j), decaying as exp(−(t − t₀)/τ): α_j·e^{−(t−t₀)/τ}·u_j/1000 on axis j —
    a machine is rarely in equilibrium when a session starts, and a lag filter started from
    the sensor's first value assumes it is. Column 3, per unit ``fraction``:
    α_j·(lag_τ(T_j) − T_j)·u_j/1000 on axis j (the lag filter started in equilibrium; exact
    superposition for the linear first-order lag)."""
    x = np.zeros((res.n, 3, 4))
    t = res.signals["t"]
    decay = np.exp(-(t - float(np.min(t))) / float(tau))
    for k, a in enumerate(AXES):
        alpha = float(res.machine.thermal.expansion[k])
        temp = res.signals.get(f"T_{a}")
        if alpha and temp is not None:
            arm = alpha * res.u_mm[:, k] / 1000.0
            x[:, k, k] = arm * decay
            x[:, k, 3] = arm * (lag_filter(t, temp, float(tau)) - temp)
    return x


def _lagged_squareness_builder(comp: str, reference_C: float) -> EffectBuilder:
    def build(p: list[float], tau: Any) -> Effect:
        eff = SquarenessDriftEffect(comp, p[1], "T_air", time_constant_s=float(tau))
        eff.reference_C = reference_C
        return eff

    return build


def _lagged_squareness_design(
    comp: str, reference_C: float
) -> Callable[[Residuals, Any], FloatArray]:
    """Column 0: the structure's unknown initial state (°C above the lagged air at the first
    sample) decaying as e^{−(t−t₀)/τ}, through the squareness' chain terms, per °C·(µrad/°C);
    column 1: the lagged squareness drift per µrad/°C (:class:`SquarenessDriftEffect` with τ,
    the effect's own forward model)."""

    def design(res: Residuals, tau: Any) -> FloatArray:
        t = res.signals["t"]
        lagged = SquarenessDriftEffect(comp, 1.0, "T_air", time_constant_s=float(tau))
        lagged.reference_C = reference_C
        direct = SquarenessDriftEffect(comp, 1.0, "T_air")
        direct.reference_C = reference_C
        decay = np.exp(-(t - float(np.min(t))) / float(tau))
        transient = replace(res, signals={**res.signals, "T_air": reference_C + decay})
        return np.stack(
            [effect_displacement_um(transient, direct), effect_displacement_um(res, lagged)],
            axis=2,
        )

    return design


def _periodic_columns(
    res: Residuals, axis: str, periods: Sequence[Any], harmonics: int
) -> FloatArray:
    """(N, T, 2·harmonics) cos/sin columns of harmonics 1…H for each of T periods, on the axis'
    positional error (that component only), each minus its value at the reference point
    (PeriodicEffect)."""
    k = AXIS_INDEX[axis]
    q = res.q_mm[:, k]
    ref = float(res.machine.volume.reference_mm[k])
    w = 2.0 * np.pi / np.asarray([float(p) for p in periods])
    x = np.empty((res.n, len(w), 2 * harmonics))
    for h in range(1, harmonics + 1):
        ph = np.outer(q, h * w)
        ph0 = h * w * ref
        x[:, :, 2 * h - 2] = np.cos(ph) - np.cos(ph0)
        x[:, :, 2 * h - 1] = np.sin(ph) - np.sin(ph0)
    return x


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

    return design


#: Cycles per travel scanned by the periodic candidate; a dense record (``DENSE_POINTS`` or more,
#: positions finer than Nyquist allows) also gets a short-period candidate up to
#: ``DENSE_CYCLES`` (a screw's pitch, an encoder's interpolation error, a stick-slip cycle).
PERIODIC_CYCLES = 80.0
DENSE_CYCLES = 400.0
DENSE_POINTS = 2000
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
        distinct = np.unique(np.round(np.asarray(positions_mm) / (1e-3 * length)))
        if len(distinct) > 1:
            gap = float(np.median(np.diff(distinct))) * 1e-3 * length
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


def _imaged(cand: Candidate, res: Residuals) -> Candidate:
    """``cand`` whose rich shape (its own, or itself) also carries its static image."""
    cand.rich = with_static_image(cand.rich or cand, res)
    return cand


def _frozen(res: Residuals, drivers: Sequence[str]) -> Residuals:
    """``res`` with the ``drivers`` signals held at their session mean."""
    return replace(
        res,
        signals={
            k: np.full_like(v, float(np.mean(v))) if k in drivers else v
            for k, v in res.signals.items()
        },
    )


def with_static_image(cand: Candidate, res: Residuals) -> Candidate:
    """``cand`` plus the static image it left in the tables (a calibration made in another
    thermal state): its columns with the driving signals frozen at their session mean, with
    coefficients of their own, first; built as a :class:`StaticImageEffect`. A copy: ``cand``
    itself is unchanged. See :mod:`cmm_comp.compensation.effects.static_image`."""
    p = cand.n_params
    drivers = cand.drivers
    frozen_at = {d: float(np.mean(res.signals[d])) for d in drivers if d in res.signals}

    def design(r: Residuals, theta: Any) -> FloatArray:
        return np.concatenate(
            [cand.design_uncached(_frozen(r, drivers), theta), cand.design_uncached(r, theta)],
            axis=2,
        )

    def build(a: list[float], theta: Any) -> Effect:
        return StaticImageEffect(cand.build(a[p:], theta), cand.build(a[:p], theta), frozen_at)

    # the frozen copy of a start-up transient is that transient again (same prior, same role)
    prior = tuple(cand.prior_sd or (None,) * p) * 2
    return replace(
        cand,
        n_params=2 * p,
        build=build,
        design_fn=design,
        design_many=None,
        design_component=None,
        rich=None,
        static_columns=p,
        prior_sd=prior,
        transient_columns=(*cand.transient_columns, *(p + j for j in cand.transient_columns)),
        _cache={},
        _statics={},
    )


def _scale_origin_candidate(res: Residuals, axis: str, reference_C: float) -> Candidate:
    """Scale expansion about a fixing point other than the reference (a scale fixed at one end):
    ``Δ·dT·u/1000 + c·dT`` on the axis' component, ``fixed_at = ref − 1000·c/Δ``."""
    k = AXIS_INDEX[axis]
    ref = float(res.machine.volume.reference_mm[k])
    role = f"T_{axis}"

    def design(r: Residuals, _theta: Any) -> FloatArray:
        dt = r.signals[role] - reference_C
        x = np.zeros((r.n, 3, 2))
        x[:, k, 0] = dt * r.u_mm[:, k] / 1000.0
        x[:, k, 1] = dt
        return x

    def build(a: list[float], _theta: Any) -> Effect:
        fixed = ref - 1000.0 * a[1] / a[0] if abs(a[0]) > 1e-9 else None
        eff = ScaleExpansionEffect(axis, a[0], fixed)
        eff.reference_C = reference_C
        return eff

    return Candidate("scale_expansion", {"axis": axis}, 2, build, design_fn=design, drivers=(role,))


def _workpiece_fixture_candidate(
    res: Residuals, fixture_mm: Sequence[float], reference_C: float
) -> Candidate:
    """Workpiece expansion about a fixture point other than the one described (the part clamped
    elsewhere): ``−Δα·dT·(q − f₀)/1000 − c·dT``, ``f = f₀ − 1000·c/Δα``."""
    f0 = np.asarray(fixture_mm, dtype=float)

    def design(r: Residuals, _theta: Any) -> FloatArray:
        dt = r.signals["T_wp"] - reference_C
        x = np.zeros((r.n, 3, 4))
        x[:, :, 0] = -dt[:, None] * (r.q_mm - f0) / 1000.0
        for j in range(3):
            x[:, j, 1 + j] = -dt
        return x

    def build(a: list[float], _theta: Any) -> Effect:
        delta = a[0]
        fixture = f0 - 1000.0 * np.asarray(a[1:4]) / delta if abs(delta) > 1e-9 else f0
        eff = WorkpieceExpansionEffect(delta, [float(v) for v in fixture])
        eff.reference_C = reference_C
        return eff

    return Candidate("workpiece_expansion", {}, 4, build, design_fn=design, drivers=("T_wp",))


def all_candidates(res: Residuals) -> list[Candidate]:
    """Every cause of docs/formats.md §4 that the measurements can show (signals present, axis moved)."""
    m = res.machine
    ref_c = m.thermal.reference_C
    moved = {a: float(np.ptp(res.q_mm[:, k])) > 1e-6 for k, a in enumerate(AXES)}
    out: list[Candidate] = []
    for comp in (*TABLE_COMPONENTS, *SQUARENESS):
        orders = candidate_orders(comp)
        if comp not in SQUARENESS and not moved[comp[-1]]:
            continue
        span = _span(res, comp[-1]) if comp not in SQUARENESS else (0.0, 1.0)
        cand = Candidate(
            "parametric", {"component": comp}, len(orders), _parametric_builder(comp, span, orders)
        )
        if comp not in SQUARENESS:
            r_orders = rich_orders(comp)
            cand.with_rich(n_params=len(r_orders), build=_parametric_builder(comp, span, r_orders))
        out.append(cand)
    # a carriage's tilt or its straightness that changes with another axis' position (a bridge
    # twist; a ram or beam whose bow depends on where the carriage stands)
    straightness = tuple(c for c in LINEAR if c[1] != c[-1])
    for comp in (*ANGULAR, *straightness):
        for other in AXES:
            if other == comp[-1] or not (moved[other] and moved[comp[-1]]):
                continue
            sa, sb = _span(res, comp[-1]), _span(res, other)
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

    def thermal(eff: Any) -> Effect:
        eff.reference_C = ref_c
        return eff

    def gradient_builder(a: str) -> EffectBuilder:
        # p: curvature, tilt, positional (2), deflection at the reference[, taper[, e3, e4]]:
        # rich, a curvature that varies along the beam up to a cubic (a gradient confined to
        # part of it)
        return lambda p, _t: thermal(
            ThermalGradientEffect(
                a,
                p[0],
                p[1],
                p[2],
                p[3],
                p[5] if len(p) > 5 else 0.0,
                offset_um_per_C=p[4],
                tilt_poly_urad_per_C=p[6:],
            )
        )

    def scale_builder(a: str) -> EffectBuilder:
        return lambda p, _t: thermal(ScaleExpansionEffect(a, p[0]))

    def squareness_drift_builder(comp: str) -> EffectBuilder:
        return lambda p, _t: thermal(SquarenessDriftEffect(comp, p[0], "T_air"))

    for a in AXES:
        if not moved[a]:
            continue
        if res.has("T_top", "T_bottom"):
            gradient = _imaged(
                Candidate(
                    "thermal_gradient",
                    {"axis": a},
                    5,
                    gradient_builder(a),
                    drivers=("T_top", "T_bottom"),
                ).with_rich(n_params=8),
                res,
            )
            out.append(gradient)
            # a beam calibrated on site, in another gradient than the session's mean: its
            # bend then is in the tables (several of them: a straightness, its carriage's
            # tilt, the Abbe term of the scale), and what the session sees is mostly that
            # image; the default shape with its image competes as a second shape of the same
            # cause (its image must not be all it explains: the static-part test applies)
            on_site = with_static_image(gradient, res)
            on_site.rich = gradient.rich
            out.append(on_site)
        if res.has(f"T_{a}"):
            # the scale expands about the reference (one parameter) or about a free fixing
            # point (a scale clamped at one end): both shapes compete; rich: plus the image
            scale = Candidate(
                "scale_expansion", {"axis": a}, 1, scale_builder(a), drivers=(f"T_{a}",)
            )
            out.append(_imaged(scale, res))
            out.append(_imaged(_scale_origin_candidate(res, a, ref_c), res))
        if res.has(f"dir_{a}"):
            span = _span(res, a)
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
                    ).with_rich(n_params=2 * hi_k + 1, build=_drift_builder(a, t_span, hi_k))
                )
        scans = [periodic_periods(_span(res, a), res.q_mm[:, AXIS_INDEX[a]])]
        if res.n >= DENSE_POINTS:
            scans.append(
                periodic_periods(
                    _span(res, a),
                    res.q_mm[:, AXIS_INDEX[a]],
                    (PERIODIC_CYCLES, DENSE_CYCLES),
                )
            )
        h_lo, h_hi = PERIODIC_HARMONICS
        for periods, n_eff in scans:
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
    if res.has("T_wp"):
        fixture = (
            m.thermal.workpiece_fixture_mm
            if m.thermal.workpiece_fixture_mm is not None
            else m.volume.reference_mm
        )
        fx = [float(v) for v in fixture]
        # the part expands about the fixture described (one parameter) or about where it is
        # really clamped (a free fixture point): both shapes compete; rich: plus the image
        workpiece = Candidate(
            "workpiece_expansion",
            {},
            1,
            lambda p, _t: thermal(WorkpieceExpansionEffect(p[0], fx)),
            drivers=("T_wp",),
        )
        out.append(_imaged(workpiece, res))
        out.append(_imaged(_workpiece_fixture_candidate(res, fx, ref_c), res))
    if res.has("T_air"):
        for comp in SQUARENESS:
            out.append(
                _imaged(
                    Candidate(
                        "squareness_drift",
                        {"component": comp},
                        1,
                        squareness_drift_builder(comp),
                        drivers=("T_air",),
                    ),
                    res,
                )
            )
        if res.has("t") and float(np.ptp(res.signals["t"])) > 0:
            # the structure follows the air through a lag (10 min … hours): the same cause
            for comp in SQUARENESS:
                out.append(
                    _imaged(
                        Candidate(
                            "squareness_drift",
                            {"component": comp},
                            2,
                            _lagged_squareness_builder(comp, ref_c),
                            thetas=LAG_TIME_CONSTANTS_S,
                            look_elsewhere=4.0,
                            design_fn=_lagged_squareness_design(comp, ref_c),
                            drivers=("T_air",),
                            static_columns=1,
                            prior_sd=(START_STATE_SD_C * SQUARENESS_DRIFT_SD_URAD_PER_C, None),
                            transient_columns=(0,),
                        ),
                        res,
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
                4,
                lambda p, tau: ThermalLagEffect(float(tau), p[3]),
                thetas=LAG_TIME_CONSTANTS_S,
                look_elsewhere=4.0,
                design_fn=_lag_design,
                # the lag must be seen beyond a decaying start-up transient of the scales
                static_columns=3,
                prior_sd=(START_STATE_SD_C, START_STATE_SD_C, START_STATE_SD_C, None),
                transient_columns=(0, 1, 2),
            )
        )
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


def contract_keys(effect: Effect) -> dict[str, Any]:
    """The docs/formats.md §4 identifying keys of an effect (cause plus component/axis/…)."""
    d = effect.describe()
    return {k: v for k, v in d.items() if k != "parameters"}


def is_finite_design(x: FloatArray) -> bool:
    return bool(np.all(np.isfinite(x))) and float(np.max(np.abs(x), initial=0.0)) > 0.0


__all__ = [
    "LAG_TIME_CONSTANTS_S",
    "LOBES",
    "Candidate",
    "all_candidates",
    "contract_keys",
    "effect_displacement_um",
    "is_finite_design",
    "periodic_periods",
    "rich_orders",
]
