"""Hidden effects: physical forward models with random shape variants, each labelled with the
identity the diagnosis must report (docs/formats.md §4: cause + component/axis/varies_with).

Every effect is evaluated on the session's points through the generator's own chain
(:mod:`.chains`): angular errors act on their carriage's Abbe arms, linear ones directly. Its
size is then set by :func:`scale_to` so that its 3-D RMS over the session's points equals
``size × noise 3-D RMS``. No shape here is a Legendre polynomial referred to the reference
point (the diagnosis' candidate shape); constants of the integration are the physics' own
(support points, drive ends, random centres), so an effect need not vanish at the reference.

Units: positions mm, linear errors µm, angles µrad, temperatures °C, time s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from .chains import (
    ANGULAR_COMPONENTS,
    AXES,
    AXIS_INDEX,
    LINEAR_COMPONENTS,
    MODELS,
    SQUARENESS,
    chain_error_um,
)
from .machines import MachineSpec
from .sessions import Session, periodic_min_period_mm

FloatArray = NDArray[np.float64]

CAUSES = (
    "coupling",
    "thermal_gradient",
    "thermal_lag",
    "scale_expansion",
    "workpiece_expansion",
    "squareness_drift",
    "reversal",
    "periodic",
    "parametric",
    "probe_lobing",
    "drift",
    "unexplained",
)
IDENT_KEYS = ("cause", "component", "axis", "varies_with")
MIN_ARM_MM = 40.0  # an angular effect whose effective Abbe arm is shorter is not observable


class NotObservable(Exception):
    """The drawn variant has (almost) no effect on this session; draw another."""


@dataclass
class HiddenEffect:
    """One hidden effect on one session: identity, variant, parameters and its error (µm)."""

    cause: str
    component: str | None = None
    axis: str | None = None
    varies_with: str | None = None
    variant: str = ""
    params: dict[str, Any] = field(default_factory=dict)
    shape_um: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))  # unscaled (N, 3)
    scale: float = 1.0
    #: identities whose effect on *this session* is exactly the same (the chain puts both on
    #: the same Abbe arms): no session of this design can tell them apart
    equivalent: list[tuple[str | None, ...]] = field(default_factory=list)

    def identity(self) -> tuple[str | None, ...]:
        return (self.cause, self.component, self.axis, self.varies_with)

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            k: v for k, v in zip(IDENT_KEYS, self.identity(), strict=True) if v is not None
        }
        out["variant"] = self.variant
        out["params"] = self.params
        out["scale"] = self.scale
        if self.equivalent:
            out["equivalent"] = [list(e) for e in self.equivalent]
        return out

    def error_um(self) -> FloatArray:
        return self.shape_um * self.scale


def rms3d(e_um: FloatArray) -> float:
    """Square root of the mean over points of the squared length of the error vector."""
    return float(np.sqrt(np.mean(np.sum(np.asarray(e_um) ** 2, axis=1))))


def scale_to(effect: HiddenEffect, target_rms_um: float) -> HiddenEffect:
    """Scale ``effect`` so that its 3-D RMS over the session's points is ``target_rms_um``."""
    effect.scale = target_rms_um / max(rms3d(effect.shape_um), 1e-300)
    return effect


# ---------------------------------------------------------------------------- helpers
def _u(spec: MachineSpec, s: Session) -> FloatArray:
    return s.q_mm - spec.reference_mm


def _chain(spec: MachineSpec, s: Session, comps: dict[str, Any]) -> FloatArray:
    return chain_error_um(spec.model, _u(spec, s), s.stylus_mm, comps)


def _check_arm(shape_um: FloatArray, angle_urad: FloatArray) -> None:
    arm = (
        rms3d(shape_um) / max(float(np.sqrt(np.mean(np.asarray(angle_urad) ** 2))), 1e-300) * 1000.0
    )
    if arm < MIN_ARM_MM:
        raise NotObservable(f"effective arm {arm:.1f} mm")


def _same(a: FloatArray, b: FloatArray) -> bool:
    return float(np.max(np.abs(a - b))) <= 1e-9 * max(float(np.max(np.abs(a))), 1e-300)


def _angular_equivalents(
    spec: MachineSpec,
    s: Session,
    comp: str,
    value: FloatArray,
    shape: FloatArray,
    depends_on_own_axis: bool,
    varies_with: str | None,
) -> list[tuple[str | None, ...]]:
    """Identities that reproduce ``shape`` exactly on this session.

    * the same rotation put on another carriage whose arm differs only along the rotation
      axis (e.g. MB1: a roll of the bridge Y that varies with x is a roll of carriage X);
    * a rotation whose arm is the same at every point (the last tool carriage with one stylus)
      acting along a single direction: a linear table of that axis.
    """
    out: list[tuple[str | None, ...]] = []
    i, a = comp[1], comp[3]
    for other in AXES:
        if other == a:
            continue
        alt = f"e{i}_{other}"
        if not _same(shape, _chain(spec, s, {alt: value})):
            continue
        if varies_with is None:  # a table of a moved to another carriage: a coupling there
            out.append(("coupling", alt, None, a))
        elif other == varies_with and not depends_on_own_axis:
            out.append(("parametric", alt, None, None))
        elif other == varies_with:
            out.append(("coupling", alt, None, a))
        elif not depends_on_own_axis:  # a function of b alone on the third carriage
            out.append(("coupling", alt, None, varies_with))
    cols = [k for k in range(3) if np.max(np.abs(shape[:, k])) > 1e-9 * np.max(np.abs(shape))]
    if len(cols) == 1 and varies_with is None:
        j = AXES[cols[0]]
        lin = f"d{j}_{a}"
        if _same(shape, _chain(spec, s, {lin: shape[:, cols[0]]})) and _is_function_of(
            s.q_mm[:, AXIS_INDEX[a]], shape[:, cols[0]]
        ):
            out.append(("parametric", lin, None, None))
    return out


def _is_function_of(q: FloatArray, v: FloatArray) -> bool:
    """True when equal positions ``q`` carry equal values ``v`` and ``v`` is smooth in ``q``
    (checked by interpolating each point from its neighbours in q)."""
    order = np.argsort(q)
    qs, vs = q[order], v[order]
    if len(qs) < 5:
        return False
    dq = qs[2:] - qs[:-2]
    w = np.where(dq > 0, (qs[1:-1] - qs[:-2]) / np.where(dq > 0, dq, 1.0), 0.5)
    mid = vs[:-2] + w * (vs[2:] - vs[:-2])
    return float(np.max(np.abs(mid - vs[1:-1]))) <= 0.05 * float(np.max(np.abs(vs))) + 1e-12


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _direct(n: int, axis: str, value: FloatArray) -> FloatArray:
    out = np.zeros((n, 3))
    out[:, AXIS_INDEX[axis]] = value
    return out


def smooth_shape(
    rng: np.random.Generator, lo: float, hi: float
) -> tuple[str, Callable[[FloatArray], FloatArray]]:
    """A random smooth function on [lo, hi]: cubic spline through 3–6 knots, Gaussian bumps or
    low-frequency sines (unit-ish amplitude, not normalised)."""
    span = hi - lo
    kind = str(rng.choice(["spline", "bumps", "sines"]))
    if kind == "spline":
        k = int(rng.integers(3, 7))
        knots = np.linspace(lo, hi, k)
        knots[1:-1] += rng.uniform(-0.3, 0.3, k - 2) * span / (k - 1)
        spline = CubicSpline(knots, rng.normal(0.0, 1.0, k), bc_type="natural")
        return kind, lambda q: spline(np.clip(q, lo, hi))
    if kind == "bumps":
        m = int(rng.integers(1, 4))
        centres = rng.uniform(lo, hi, m)
        widths = rng.uniform(0.1, 0.4, m) * span
        heights = rng.normal(0.0, 1.0, m)

        def bumps(q: FloatArray) -> FloatArray:
            q = np.asarray(q, dtype=float)[..., None]
            return np.sum(heights * np.exp(-0.5 * ((q - centres) / widths) ** 2), axis=-1)

        return kind, bumps
    m = int(rng.integers(1, 3))
    periods = rng.uniform(span / 3.0, 2.0 * span, m)
    phases = rng.uniform(0.0, 2 * np.pi, m)
    amps = rng.normal(0.0, 1.0, m)

    def sines(q: FloatArray) -> FloatArray:
        q = np.asarray(q, dtype=float)[..., None]
        return np.sum(amps * np.sin(2 * np.pi * (q - lo) / periods + phases), axis=-1)

    return kind, sines


# ---------------------------------------------------------------------------- the causes
def draw_coupling(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """An angular error of axis a's carriage that changes with axis b's position (bridge twist,
    load shift): uniform in a, growing along a, sag-like along a, or a mix."""
    a = str(rng.choice(AXES))
    b = str(rng.choice([x for x in AXES if x != a]))
    comp = f"e{rng.choice(AXES)}_{a}"
    ka, kb = AXIS_INDEX[a], AXIS_INDEX[b]
    lo, hi = spec.lower_mm, spec.upper_mm
    qa, qb = s.q_mm[:, ka], s.q_mm[:, kb]
    ca, cb = (
        float(rng.uniform(lo[k] + 0.1 * (hi[k] - lo[k]), hi[k] - 0.1 * (hi[k] - lo[k])))
        for k in (ka, kb)
    )
    span_a, span_b = hi[ka] - lo[ka], hi[kb] - lo[kb]
    tb = (qb - cb) / span_b
    variant = str(rng.choice(["uniform", "growing", "sag", "mixed"]))
    if variant == "uniform":
        eps = tb
    elif variant == "growing":
        eps = tb * (qa - ca) / span_a
    elif variant == "sag":
        eps = tb * 4.0 * (qa - lo[ka]) * (hi[ka] - qa) / span_a**2
    else:
        w = rng.normal(0.0, 1.0, 2)
        eps = tb * (w[0] + w[1] * (qa - ca) / span_a)
    shape = _chain(spec, s, {comp: eps})
    _check_arm(shape, eps)
    return HiddenEffect(
        cause="coupling",
        component=comp,
        varies_with=b,
        variant=variant,
        params={"c_a_mm": ca, "c_b_mm": cb},
        shape_um=shape,
        equivalent=_angular_equivalents(spec, s, comp, eps, shape, variant != "uniform", b),
    )


def bending_shape(
    variant: str, lo: float, hi: float, taper: float, fixed_end: int
) -> Callable[[FloatArray], tuple[FloatArray, FloatArray]]:
    """Deflection w(q) (µm, per unit curvature scale) and slope dw/dq (µm/mm) of a guideway.

    Curvature along the beam ``κ(x) = 1 + taper·x`` with ``x = (q − mid)/half`` (a gradient
    that is not uniform along the beam when taper ≠ 0). Boundary conditions: ``simply_supported``
    (w = 0 at both supports lo, hi), ``cantilever`` (w = w' = 0 at the fixed end lo or hi),
    ``mid_clamped`` (uniform curvature about mid-span: w = w' = 0 at mid).
    """
    mid, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    P = np.polynomial.Polynomial
    kappa = P([1.0, taper])
    w0 = kappa.integ(2)  # in x; add A + B x to meet the boundary conditions
    if variant == "simply_supported":
        # w0(-1) + A - B = 0, w0(1) + A + B = 0
        B = -(w0(1.0) - w0(-1.0)) / 2.0
        A = -(w0(1.0) + w0(-1.0)) / 2.0
    else:
        x0 = 0.0 if variant == "mid_clamped" else (-1.0 if fixed_end == 0 else 1.0)
        B = -w0.deriv()(x0)
        A = -w0(x0) - B * x0
    w = w0 + P([A, B])
    dw = w.deriv()

    def evaluate(q: FloatArray) -> tuple[FloatArray, FloatArray]:
        x = (np.asarray(q, dtype=float) - mid) / half
        return w(x) * half**2, dw(
            x
        ) * half  # d/dq = d/dx / half; scale w by half² (curvature units)

    return evaluate


def draw_thermal_gradient(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """A guideway bows with ΔT = T_top − T_bottom; its carriage tilts with the local slope.

    X and Y bend in their vertical plane, Z in the x-z plane: the rail's deflection ``w(s)``
    is along ``n`` (z for X and Y, x for Z). A carriage riding it moves by ``w·n`` and turns
    with the slope about the horizontal axis across the guideway: ``ey_x = −dw/dx``,
    ``ex_y = +dw/dy``, ``ey_z = +dw/dz`` (a rail rising along +x turns the carriage's x
    direction towards +z: a negative rotation about y, right-hand rule; along +y towards +z is
    positive about x; z leaning towards +x is positive about y).

    A tool carriage's linear error is its own motion (``dz_x = +w``); a table's is the motion
    of the tool relative to the part (``−w``), its angle the table's own turn (the chain then
    acts with the opposite sign); a table's pads travel over the base's rail in the opposite
    direction, so its rail coordinate is mirrored. Variant ``rail_h``: the carriage turns about its rail contact,
    ``H`` mm from the chain's rotation point along ``n`` (a bridge beam above the ram, rails on
    the base below a table), adding the Abbe term ``−ε × H·n`` (tool) / ``+ε × H·n`` (table).
    """
    axis = str(rng.choice(AXES))
    k = AXIS_INDEX[axis]
    lo, hi = float(spec.lower_mm[k]), float(spec.upper_mm[k])
    margin = float(rng.uniform(0.0, 0.1)) * (hi - lo)
    variant = str(rng.choice(["simply_supported", "cantilever", "mid_clamped"]))
    taper = 0.0 if rng.random() < 0.5 else float(rng.uniform(-0.6, 0.6))
    fixed_end = int(rng.integers(0, 2))
    rail_h = 0.0 if rng.random() < 0.5 else float(rng.uniform(-600.0, 600.0))
    bend = bending_shape(variant, lo - margin, hi + margin, taper, fixed_end)
    table = axis in MODELS[spec.model][1]
    side = -1.0 if table else 1.0
    # where the carriage's pads sit on the rail (base coordinate along +axis): a tool carriage
    # at q; a table's pads move the other way over the base's rail (the table travels by −u)
    on_rail = lo + hi - s.q_mm[:, k] if table else s.q_mm[:, k]
    w, slope = bend(on_rail)  # slope: dw/d(base coordinate), µm/mm per unit scale
    dT = s.temps_C["T_top"] - s.temps_C["T_bottom"]
    sign = float(rng.choice([-1.0, 1.0]))
    w_um = sign * dT * w * 1e-6  # any consistent scale; scaled later
    tilt_urad = sign * dT * slope * 1e-6 * 1000.0  # µm/mm → µrad
    n_axis, rot_axis, rot_sign = {
        "x": ("z", "y", -1.0),
        "y": ("z", "x", 1.0),
        "z": ("x", "y", 1.0),
    }[axis]
    comps = {f"d{n_axis}_{axis}": side * w_um, f"e{rot_axis}_{axis}": rot_sign * tilt_urad}
    shape = _chain(spec, s, comps)
    if rail_h:
        rot = np.zeros((s.n, 3))
        rot[:, AXIS_INDEX[rot_axis]] = rot_sign * tilt_urad
        c = np.zeros(3)
        c[AXIS_INDEX[n_axis]] = rail_h
        shape = shape - side * np.cross(rot, c) / 1000.0
    return HiddenEffect(
        cause="thermal_gradient",
        axis=axis,
        variant=variant + ("" if taper == 0.0 else "+taper") + ("+rail_h" if rail_h else ""),
        params={
            "support_margin_mm": margin,
            "taper": taper,
            "fixed_end": fixed_end,
            "sign": sign,
            "rail_h_mm": rail_h,
            "table": table,
        },
        shape_um=shape,
    )


def draw_thermal_lag(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """The scales' effective temperature follows the logged T_x, T_y, T_z through a lag τ
    (5 min … 2 h, log-uniform, filter started 12 h before the session): the error is
    ``α_j · fraction · (T_lag − T_logged) · (q_j − reference_j) / 1000`` µm on each axis."""
    tau = _logu(rng, 300.0, 7200.0)
    fraction = 1.0 if rng.random() < 0.7 else float(rng.uniform(0.5, 1.0))
    u = _u(spec, s)
    shape = np.zeros((s.n, 3))
    for k, a in enumerate(AXES):
        name = f"T_{a}"
        lagged = s.field.lagged(name, tau, s.t_s)
        true_now = s.field.at(name, s.t_s)
        # the structure lags the true temperature; the sensor's noise is not in the structure
        shape[:, k] = spec.expansion[a] * fraction * (lagged - true_now) * u[:, k] / 1000.0
    return HiddenEffect(
        cause="thermal_lag",
        variant="fraction" if fraction < 1.0 else "full",
        params={"time_constant_s": tau, "fraction": fraction},
        shape_um=shape,
    )


def draw_scale_expansion(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """An axis' expansion coefficient is off by Δα: ``Δα·(T_axis − 20)·u / 1000`` µm."""
    axis = str(rng.choice(AXES))
    k = AXIS_INDEX[axis]
    d_alpha = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 3.0))
    t_ax = s.temps_C[f"T_{axis}"]
    value = d_alpha * (t_ax - spec.reference_C) * _u(spec, s)[:, k] / 1000.0
    return HiddenEffect(
        cause="scale_expansion",
        axis=axis,
        params={"delta_expansion": d_alpha},
        shape_um=_direct(s.n, axis, value),
    )


def draw_workpiece_expansion(
    rng: np.random.Generator, spec: MachineSpec, s: Session
) -> HiddenEffect:
    """The workpiece's expansion is off by Δα_wp: ``−Δα·(T_wp − 20)·(q − fixture)/1000`` µm."""
    d_alpha = float(rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 8.0))
    dT = s.temps_C["T_wp"] - spec.reference_C
    shape = -d_alpha * dT[:, None] * (s.q_mm - spec.workpiece_fixture_mm) / 1000.0
    return HiddenEffect(
        cause="workpiece_expansion",
        params={"delta_expansion": d_alpha},
        shape_um=shape,
    )


def draw_squareness_drift(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """A squareness changes with the air temperature, directly or through a lag of 10–60 min:
    ``Δ = c·(T − 20)`` µrad, through the chain's first-order squareness terms."""
    comp = str(rng.choice(SQUARENESS))
    lag = rng.random() < 0.5
    tau = _logu(rng, 600.0, 3600.0) if lag else 0.0
    temp = s.field.lagged("T_air", tau, s.t_s) if lag else s.temps_C["T_air"]
    value = (temp - spec.reference_C) * float(rng.choice([-1.0, 1.0]))
    return HiddenEffect(
        cause="squareness_drift",
        component=comp,
        variant="lagged" if lag else "direct",
        params={"tau_s": tau},
        shape_um=_chain(spec, s, {comp: value}),
    )


def draw_reversal(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """Positional error that depends on the direction of travel: a constant backlash, or a
    hysteresis that grows with the distance from the drive end: ``dir·h(q)``."""
    axis = str(rng.choice(AXES))
    k = AXIS_INDEX[axis]
    lo, hi = float(spec.lower_mm[k]), float(spec.upper_mm[k])
    direction = s.directions[f"dir_{axis}"]
    variant = str(rng.choice(["constant", "growing"]))
    if variant == "constant":
        h = np.ones(s.n)
        params: dict[str, Any] = {}
    else:
        drive_end = lo if rng.random() < 0.5 else hi
        h0 = float(rng.uniform(0.0, 0.5))
        h = h0 + np.abs(s.q_mm[:, k] - drive_end) / (hi - lo)
        params = {"drive_end_mm": drive_end, "h0": h0}
    return HiddenEffect(
        cause="reversal",
        axis=axis,
        variant=variant,
        params=params,
        shape_um=_direct(s.n, axis, direction * h),
    )


def draw_periodic(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """Cyclic positional error: fundamental + a random 2nd harmonic (ratio 0–0.5), random
    phases; period from ~1/40 to 1/2 of the travel, never shorter than the session resolves."""
    axis = str(rng.choice(AXES))
    k = AXIS_INDEX[axis]
    span = float(spec.span_mm[k])
    p_min = periodic_min_period_mm(s, k, span)
    if p_min > span / 2.0:
        raise NotObservable(f"session cannot resolve periods on {axis} (min {p_min:.0f} mm)")
    period = _logu(rng, p_min, span / 2.0)
    ratio = float(rng.uniform(0.0, 0.5))
    ph1, ph2 = rng.uniform(0.0, 2 * np.pi, 2)
    q = s.q_mm[:, k]
    value = np.cos(2 * np.pi * q / period + ph1) + ratio * np.cos(4 * np.pi * q / period + ph2)
    return HiddenEffect(
        cause="periodic",
        axis=axis,
        variant="harmonic" if ratio > 0.05 else "pure",
        params={"period_mm": period, "harmonic_ratio": ratio},
        shape_um=_direct(s.n, axis, value),
    )


def draw_parametric(
    rng: np.random.Generator, spec: MachineSpec, s: Session, component: str | None = None
) -> HiddenEffect:
    """A smooth change of one table (spline, bumps or sines; zero mean or zero at a random
    point; straightness without its linear slope) or of a squareness (a constant)."""
    comp = component or str(rng.choice(LINEAR_COMPONENTS + ANGULAR_COMPONENTS + SQUARENESS))
    if comp in SQUARENESS:
        return HiddenEffect(
            cause="parametric",
            component=comp,
            variant="constant",
            shape_um=_chain(spec, s, {comp: 1.0}),
        )
    k = AXIS_INDEX[comp[3]]
    lo, hi = float(spec.lower_mm[k]), float(spec.upper_mm[k])
    kind, f = smooth_shape(rng, lo, hi)
    grid = np.linspace(lo, hi, 201)
    g = f(grid)
    slope, icpt = 0.0, 0.0
    if comp in LINEAR_COMPONENTS and comp[1] != comp[3]:
        slope, icpt = np.polyfit(grid, g, 1)
    zero = "mean" if rng.random() < 0.5 else "point"
    level = float(np.mean(g - (slope * grid + icpt)))
    if zero == "point":
        q0 = float(rng.uniform(lo, hi))
        level = float(f(np.array([q0]))[0] - (slope * q0 + icpt))
    q = s.q_mm[:, k]
    value = f(q) - (slope * q + icpt) - level
    shape = _chain(spec, s, {comp: value})
    equivalent: list[tuple[str | None, ...]] = []
    if comp in ANGULAR_COMPONENTS:
        _check_arm(shape, value)
        equivalent = _angular_equivalents(spec, s, comp, value, shape, True, None)
    if rms3d(shape) < 1e-9:
        raise NotObservable("flat shape")
    return HiddenEffect(
        cause="parametric",
        component=comp,
        variant=f"{kind}/zero-{zero}",
        shape_um=shape,
        equivalent=equivalent,
    )


def draw_probe_lobing(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """Error along the probing direction n: ``cos(k(φ − φ0))·ρ`` with φ the azimuth of n and
    ρ its horizontal fraction, k = 2…6 lobes."""
    k = int(rng.integers(2, 7))
    phi0 = float(rng.uniform(0.0, 2 * np.pi))
    n = s.normals
    rho = np.hypot(n[:, 0], n[:, 1])
    phi = np.arctan2(n[:, 1], n[:, 0])
    shape = n * (np.cos(k * (phi - phi0)) * rho)[:, None]
    if rms3d(shape) < 1e-6:
        raise NotObservable("no horizontal probing")
    return HiddenEffect(
        cause="probe_lobing", variant=f"k{k}", params={"lobes": k, "phi0": phi0}, shape_um=shape
    )


def draw_drift(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """Positional error of an axis drifting with time (a thermal state not logged):
    ``u·f(t)/1000 + g(t)`` µm with f, g splines through random knots (either or both)."""
    axis = str(rng.choice(AXES))
    k = AXIS_INDEX[axis]
    t_end = float(s.t_s[-1])
    variant = str(rng.choice(["scale", "offset", "both"]))

    def spline() -> CubicSpline:
        m = int(rng.integers(3, 7))
        knots = np.linspace(0.0, t_end, m)
        vals = np.cumsum(rng.normal(0.0, 1.0, m))  # a wandering, not a zig-zag
        return CubicSpline(knots, vals - vals[0], bc_type="natural")

    u_m = _u(spec, s)[:, k] / 1000.0
    value = np.zeros(s.n)
    if variant in ("scale", "both"):
        value += u_m / max(float(np.sqrt(np.mean(u_m**2))), 1e-9) * spline()(s.t_s)
    if variant in ("offset", "both"):
        value += spline()(s.t_s)
    return HiddenEffect(
        cause="drift", axis=axis, variant=variant, shape_um=_direct(s.n, axis, value)
    )


def draw_unexplained(rng: np.random.Generator, spec: MachineSpec, s: Session) -> HiddenEffect:
    """A localised 3-D bump: a Gaussian blob in one axis' error in one corner of the volume."""
    axis = str(rng.choice(AXES))
    corner = rng.integers(0, 2, 3)
    inset = rng.uniform(0.1, 0.25, 3)
    centre = spec.lower_mm + np.where(corner == 1, 1.0 - inset, inset) * spec.span_mm
    sigma = rng.uniform(0.12, 0.25, 3) * spec.span_mm
    r2 = np.sum(((s.q_mm - centre) / sigma) ** 2, axis=1)
    value = np.exp(-0.5 * r2)
    if np.count_nonzero(value > 0.3) < 8:
        raise NotObservable("blob holds too few points")
    return HiddenEffect(
        cause="unexplained",
        variant=f"blob-{axis}",
        params={"centre_mm": centre.tolist(), "sigma_mm": sigma.tolist(), "axis": axis},
        shape_um=_direct(s.n, axis, value),
    )


DRAW: dict[str, Callable[[np.random.Generator, MachineSpec, Session], HiddenEffect]] = {
    "coupling": draw_coupling,
    "thermal_gradient": draw_thermal_gradient,
    "thermal_lag": draw_thermal_lag,
    "scale_expansion": draw_scale_expansion,
    "workpiece_expansion": draw_workpiece_expansion,
    "squareness_drift": draw_squareness_drift,
    "reversal": draw_reversal,
    "periodic": draw_periodic,
    "parametric": draw_parametric,
    "probe_lobing": draw_probe_lobing,
    "drift": draw_drift,
    "unexplained": draw_unexplained,
}


def draw_effect(
    cause: str, rng: np.random.Generator, spec: MachineSpec, s: Session, tries: int = 30
) -> HiddenEffect:
    """A random observable variant of ``cause`` on session ``s`` (unscaled)."""
    last: Exception | None = None
    for _ in range(tries):
        try:
            return DRAW[cause](rng, spec, s)
        except NotObservable as exc:
            last = exc
    raise NotObservable(f"{cause}: no observable variant in {tries} draws ({last})")
