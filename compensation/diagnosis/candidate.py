"""One candidate cause as a fit-ready term (:class:`Candidate`), and what every family shares.

A :class:`Candidate` gives, for a value ``theta`` of its nonlinear parameter (period, time
constant, number of lobes, a ripple's period law; None when it has none), the design ``X``
(N, 3, p): the displacement (µm) of each point per unit of each amplitude parameter, and builds
the :class:`Effect` for fitted amplitudes. Designs come from the effects' own hooks evaluated on a
zero model and mapped through the chain's first-order Jacobian at each point's stylus offset
(:func:`effect_displacement_um`), so the fitted term is exactly the term the extended machine
evaluates (up to second-order small terms); families written out explicitly (periodic scans,
thermal lags, the reference instrument's terms) give ``design_fn``.

Every candidate also says which instrument carries it (``source``: the machine or the reference)
and which coordinate it is a function of (``locked_to``: the axis' position, the reference's
reading, time, velocity): the diagnosis JSON reports both (docs/formats.md §4).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..effects import Effect, EvalContext, StaticImageEffect
from ..effects.parametric import SHAPES
from ..parametric_errors import AXIS_INDEX
from .residuals import FloatArray, Residuals

#: Designs kept per candidate whose parameter is refined continuously (``theta_step``).
_REFINED_CACHE = 8

#: ``(amplitudes, theta) → Effect``: builds a candidate's effect for fitted amplitudes.
EffectBuilder = Callable[[list[float], Any], Effect]


def effect_displacement_um(
    res: Residuals, effect: Effect, shapes: dict[Any, FloatArray] | None = None
) -> FloatArray:
    """(N, 3) µm that ``effect`` alone adds at the points of ``res`` (first order in the chain).
    ``shapes``: a memo of the Legendre shapes at these points, shared by calls on the same
    ``res`` (``EvalContext.extras[SHAPES]``, :func:`~..effects.parametric.shape_at`)."""
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
        extras={} if shapes is None else {SHAPES: shapes},
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
    #: Which instrument carries the cause: ``"machine"`` (what compensation corrects) or
    #: ``"reference"`` (the sensor that measured it, its mounting, timestamps, environment).
    source: str = "machine"
    #: The coordinate the cause is a function of: ``"position"`` (the axis' indicated position),
    #: ``"reference"`` (the reference's reading), ``"time"``, ``"velocity"``.
    locked_to: str = "position"
    #: For a tuple-valued nonlinear parameter (a ripple's period law): the step of each of its
    #: numeric entries for the continuous refinement after the grid (None: grid only).
    theta_step: tuple[float, ...] | None = None
    #: For a cyclic error: the order of its envelope (an amplitude that changes along the
    #: travel as Legendre polynomials up to this order; 0: constant).
    envelope: int = 0
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
            if self.theta_step is not None and len(self._cache) >= _REFINED_CACHE:
                # a continuously refined parameter tries hundreds of values: keep the last few
                self._cache.pop(next(iter(self._cache)))
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
                rest = self.design_uncached(frozen(res, self.drivers), at)
                rest = rest[:, :, self.static_columns :]
                x = np.concatenate([x, rest], axis=2)
        elif self.drivers:
            x = self.design_uncached(frozen(res, self.drivers), self.thetas[0])
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
        """(N, 3, p) displacement per unit amplitude, computed afresh: one effect per unit
        amplitude, their Legendre shapes evaluated once for all of them (a shared memo)."""
        if self.design_fn is not None:
            return self.design_fn(res, theta)
        shapes: dict[Any, FloatArray] = {}
        cols = []
        for j in range(self.n_params):
            amps = [0.0] * self.n_params
            amps[j] = 1.0
            cols.append(effect_displacement_um(res, self.build(amps, theta), shapes))
        return np.stack(cols, axis=2)


def span_of(res: Residuals, axis: str) -> tuple[float, float]:
    k = AXIS_INDEX[axis]
    lo, hi = float(res.machine.volume.lower_mm[k]), float(res.machine.volume.upper_mm[k])
    return (lo, hi) if hi > lo else (lo - 0.5, lo + 0.5)


def imaged(cand: Candidate, res: Residuals) -> Candidate:
    """``cand`` whose rich shape (its own, or itself) also carries its static image."""
    cand.rich = with_static_image(cand.rich or cand, res)
    return cand


def frozen(res: Residuals, drivers: Sequence[str]) -> Residuals:
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
            [cand.design_uncached(frozen(r, drivers), theta), cand.design_uncached(r, theta)],
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


def contract_keys(effect: Effect) -> dict[str, Any]:
    """The docs/formats.md §4 identifying keys of an effect (cause plus component/axis/…)."""
    d = effect.describe()
    return {k: v for k, v in d.items() if k != "parameters"}


def is_finite_design(x: FloatArray) -> bool:
    return bool(np.all(np.isfinite(x))) and float(np.max(np.abs(x), initial=0.0)) > 0.0


#: Values (float64) of scan columns one candidate keeps between calls (:func:`kept_scan`).
SCAN_STORE_VALUES = 2_000_000


def kept_scan(
    design_many: Callable[[Residuals, Sequence[Any]], FloatArray],
) -> Callable[[Residuals, Sequence[Any]], FloatArray]:
    """``design_many`` whose (N, T, p) columns for a block of grid values are kept (read-only)
    and returned again for the same block on the same data set (identity of ``res``) while the
    kept blocks hold at most :data:`SCAN_STORE_VALUES` values: a scan is profiled against a new
    base in every selection round, on the same positions — the same numbers, computed once."""
    store: dict[tuple[Any, ...], FloatArray] = {}
    held: list[Residuals] = []  # the data set the store belongs to

    def design(res: Residuals, thetas: Sequence[Any]) -> FloatArray:
        if not held or held[0] is not res:
            store.clear()
            held[:] = [res]
        key = tuple(thetas)
        x = store.get(key)
        if x is None:
            x = design_many(res, thetas)
            if x.size + sum(v.size for v in store.values()) <= SCAN_STORE_VALUES:
                x.flags.writeable = False
                store[key] = x
        return x

    return design


__all__ = [
    "Candidate",
    "EffectBuilder",
    "contract_keys",
    "effect_displacement_um",
    "frozen",
    "imaged",
    "is_finite_design",
    "kept_scan",
    "span_of",
    "with_static_image",
]
