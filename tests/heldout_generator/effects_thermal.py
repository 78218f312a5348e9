"""Thermal hidden effects: thermal_gradient, thermal_lag, scale_expansion, workpiece_expansion,
squareness_drift. Temperatures °C, expansion µm/(m·°C), times s."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from .beams import GRID, deflection, gradient_profile
from .chain import AXES, MODEL_AXES
from .design import Session
from .effect_base import Contribution, HiddenEffect, axis_index
from .environment import lag
from .identity import Identity
from .machine import SQUARENESS, RandomMachine

FloatArray = NDArray[np.float64]

ARM = {"MH1": "x", "MH2": "y"}


def _true(session: Session, name: str) -> FloatArray:
    return session.env.at(name, session.t_s)


# ---------------------------------------------------------------------------- thermal gradient
def draw_thermal_gradient(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """A horizontal guideway (bridge beam, granite base under a table or rails, a horizontal arm)
    bows with ``T_top − T_bottom``; its carriage follows the bow (vertical straightness) and tilts
    with the local slope (pitch or roll, with its Abbe arms through the chain). The tables of the
    description hold at the gradient they were measured in: none (``/isothermal``) or the site's
    on another day (``/on_site``).

    Supports: simply supported at the beam's ends (with overhangs beyond the travel), at the Bessel
    points of a plate, a cantilever from either end, a propped cantilever, or clamped at both ends
    (which only bends where the gradient is not uniform). Gradient along the beam: uniform, local,
    or a ramp. The horizontal arm of MH1/MH2 may instead be a cantilever whose free length grows as
    it runs out of its bearing.
    """
    axis = str(rng.choice(["x", "y"]))
    k = axis_index(axis)
    n = session.n
    on_table = axis in MODEL_AXES[machine.model][1]
    span = float(machine.span_mm[k])
    s = machine.normalised(session.q_mm)[:, k]
    dT = _true(session, "T_top") - _true(session, "T_bottom")
    params: dict[str, float | str] = {}
    if ARM.get(machine.model) == axis and rng.uniform() < 0.5:
        variant = "arm_cantilever"
        free0 = rng.uniform(100.0, 300.0)
        free = free0 + s * span
        free_max = free0 + span
        w_hat = (free / free_max) ** 2  # tip deflection, 1 at full extension
        slope_per_mm = 2 * free / free_max**2
        params.update(free_length_at_start_mm=free0)
    else:
        support = str(
            rng.choice(["simply_supported", "bessel", "cantilever", "propped", "clamped"])
        )
        profile = "local" if support == "clamped" else str(rng.choice(["uniform", "local", "ramp"]))
        curvature, p = gradient_profile(profile, rng)
        flip = support in ("cantilever", "propped") and rng.uniform() < 0.5
        if flip:  # clamped at the far end instead
            curvature = curvature[::-1]
        w, ws = deflection(support, curvature)
        if flip:
            w, ws = w[::-1], -ws[::-1]
        e0, e1 = rng.uniform(0.0, 0.08, 2)
        length = 1.0 + e0 + e1  # beam length in units of the travel
        guide = 1.0 - s if on_table else s  # a table rides over its guide backwards
        xi = (e0 + guide) / length
        w_at = np.interp(xi, GRID, w)
        ws_at = np.interp(xi, GRID, ws)
        inside = (e0 / length <= GRID) & ((e0 + 1) / length >= GRID)
        scale = max(np.abs(w[inside]).max(), 1e-12)
        w_hat = w_at / scale
        slope_per_mm = ws_at / scale / (length * span)
        variant = f"{support}/{profile}"
        params.update({f"profile_{key}": v for key, v in p.items()})
        params.update(overhang_start=e0, overhang_end=e1, clamped_far_end=float(flip))
    if rng.uniform() < 0.5:  # the tables were measured in an isothermal state …
        dT_cal = 0.0
        variant += "/isothermal"
    else:  # … or on site, on another day, with its own gradient
        dT_cal = float(dT.mean() + rng.uniform(-0.5, 0.5) * max(np.ptp(dT), 0.05))
        variant += "/on_site"
    dT = dT - dT_cal
    params["calibrated_dT_C"] = dT_cal
    sign_lin = -1.0 if on_table else 1.0  # a table's linear error is the relative motion's
    tilt_slot = 4 if axis == "x" else 3  # pitch about y for X, roll about x for Y
    tilt_sign = -1.0 if axis == "x" else 1.0
    params["on_table"] = float(on_table)

    def forward(um_per_C: float) -> Contribution:
        c = Contribution.zeros(n)
        c.errors[:, k, 2] += sign_lin * um_per_C * w_hat * dT
        c.errors[:, k, tilt_slot] += tilt_sign * um_per_C * slope_per_mm * 1e3 * dT
        return c

    return HiddenEffect(
        identity=Identity("thermal_gradient", axis=axis),
        variant=variant,
        params=params,
        forward=forward,
        knob_name="peak_deflection_um_per_C",
        knob_range=(0.05, 40.0),
    )


# ---------------------------------------------------------------------------- thermal lag
def draw_thermal_lag(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """The scales' bodies follow their (surface) sensors through a lag, with their whole history
    before the session: ``common`` (one structure, one τ), ``per_axis`` (each axis its own τ, ratios
    0.5–2), ``two_stage`` (two lags in series, a thick carrier). Knob: τ, s."""
    variant = str(rng.choice(["common", "per_axis", "two_stage"]))
    ratios = rng.uniform(0.5, 2.0, 3) if variant == "per_axis" else np.ones(3)
    second = rng.uniform(0.3, 1.0) if variant == "two_stage" else 0.0
    u = session.q_mm - machine.reference_mm
    env = session.env
    n = session.n
    true_now = {a: _true(session, f"T_{a}") for a in AXES}

    def forward(tau_s: float) -> Contribution:
        c = Contribution.zeros(n)
        for k, a in enumerate(AXES):
            body = lag(env.time_s, env.true_C[f"T_{a}"], tau_s * ratios[k])
            if second:
                body = lag(env.time_s, body, tau_s * second)
            eff = np.interp(session.t_s, env.time_s, body)
            c.direct_um[:, k] += machine.expansion[a] * (eff - true_now[a]) * u[:, k] / 1e3
        return c

    return HiddenEffect(
        identity=Identity("thermal_lag"),
        variant=variant,
        params={"ratios": ratios, "second_stage_ratio": second},
        forward=forward,
        knob_name="time_constant_s",
        knob_range=(120.0, 8 * 3600.0),
        linear=False,
    )


# ---------------------------------------------------------------------------- scale expansion
def draw_scale_expansion(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """An axis' effective expansion differs from the description: ``wrong_coefficient`` (about
    the reference point, as the description's term), ``other_origin`` (the scale is fixed at one end
    of its travel, so the change grows from there), ``missing`` (the description has 0 for it)."""
    axis = str(rng.choice(AXES))
    k = axis_index(axis)
    variant = str(rng.choice(["wrong_coefficient", "other_origin", "missing"], p=[0.45, 0.35, 0.2]))
    dT = _true(session, f"T_{axis}") - 20.0
    q = session.q_mm[:, k]
    origin = float(machine.reference_mm[k])
    if variant == "other_origin":
        origin = float(machine.lower_mm[k] if rng.uniform() < 0.5 else machine.upper_mm[k])
    n = session.n

    def forward(coeff: float) -> Contribution:
        c = Contribution.zeros(n)
        c.direct_um[:, k] += coeff * dT * (q - origin) / 1e3
        return c

    change = None
    knob_range = (0.1, 5.0)
    if variant == "missing":
        knob_range = (4.0, 25.0)

        def change(desc: RandomMachine) -> RandomMachine:
            return replace(desc, expansion={**desc.expansion, axis: 0.0})

    return HiddenEffect(
        identity=Identity("scale_expansion", axis=axis),
        variant=variant,
        params={"origin_mm": origin},
        forward=forward,
        knob_name="expansion_change_um_per_m_C"
        if variant != "missing"
        else "true_expansion_um_per_m_C",
        knob_range=knob_range,
        description_change=change,
    )


# ---------------------------------------------------------------------------- workpiece expansion
def draw_workpiece_expansion(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """The artefact's expansion is wrong (``wrong_coefficient``: aluminium described as steel …),
    ``missing`` from the description, or it grows from another clamping point than described
    (``fixture_elsewhere``). Driven by the workpiece's own temperature, which soaks from another
    room's during the session."""
    variant = str(rng.choice(["wrong_coefficient", "missing", "fixture_elsewhere"]))
    dT = _true(session, "T_wp") - 20.0
    n = session.n
    fixture = machine.workpiece_fixture_mm
    q = session.q_mm
    params: dict[str, object] = {}
    change = None
    if variant == "fixture_elsewhere":
        v = rng.normal(size=3)
        v[2] *= 0.3
        v /= np.linalg.norm(v)
        alpha_wp = machine.workpiece_expansion or 11.5
        params.update(direction=v)

        def forward(distance_mm: float) -> Contribution:
            c = Contribution.zeros(n)
            c.direct_um += alpha_wp * dT[:, None] * distance_mm * v / 1e3
            return c

        return HiddenEffect(
            identity=Identity("workpiece_expansion"),
            variant=variant,
            params=params,
            forward=forward,
            knob_name="fixture_shift_mm",
            knob_range=(10.0, float(np.linalg.norm(machine.span_mm)) / 2),
        )

    def forward_coeff(coeff: float) -> Contribution:
        c = Contribution.zeros(n)
        c.direct_um -= coeff * dT[:, None] * (q - fixture) / 1e3
        return c

    if variant == "missing":

        def change(desc: RandomMachine) -> RandomMachine:
            return replace(desc, workpiece_expansion=None)

    return HiddenEffect(
        identity=Identity("workpiece_expansion"),
        variant=variant,
        params=params,
        forward=forward_coeff,
        knob_name="expansion_um_per_m_C",
        knob_range=(0.3, 15.0) if variant == "wrong_coefficient" else (5.0, 25.0),
        description_change=change,
    )


# ---------------------------------------------------------------------------- squareness drift
def draw_squareness_drift(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """A squareness changes with the air temperature (one side of a bridge or a column warms
    first), following the air ``direct``-ly or ``lagged`` (the structure follows it through
    τ 15–120 min, with its history). The squareness in the description holds at the temperature it
    was measured at: 20 °C in the maker's lab (``/factory``), or on site on another day
    (``/on_site``: within the session's range, ± a little)."""
    component = str(rng.choice(SQUARENESS))
    j = SQUARENESS.index(component)
    env = session.env
    params: dict[str, float] = {}
    if rng.uniform() < 0.5:
        variant = "lagged"
        tau = rng.uniform(900.0, 7200.0)
        t_eff = env.lagged("T_air", tau, session.t_s)
        params["tau_s"] = tau
    else:
        variant = "direct"
        t_eff = _true(session, "T_air")
    if rng.uniform() < 0.4:
        variant += "/factory"
        cal = 20.0
    else:
        variant += "/on_site"
        cal = float(t_eff.mean() + rng.uniform(-0.5, 0.5) * max(np.ptp(t_eff), 0.1))
    params["calibrated_C"] = cal
    n = session.n

    def forward(urad_per_C: float) -> Contribution:
        c = Contribution.zeros(n)
        c.squareness_urad[:, j] += urad_per_C * (t_eff - cal)
        return c

    return HiddenEffect(
        identity=Identity("squareness_drift", component=component),
        variant=variant,
        params=params,
        forward=forward,
        knob_name="urad_per_C",
        knob_range=(0.3, 40.0),
    )
