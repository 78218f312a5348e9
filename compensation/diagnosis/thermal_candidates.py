"""Thermal candidate causes (docs/formats.md §4): a guideway bending with a temperature
difference, scales and workpiece expanding about their fixing points, squareness following the
air (directly or through a lag), the scales' thermal lag; each with its static image (a
calibration made in another thermal state) as a rich shape.

The lag designs are written out explicitly (the effects' own forward models are checked against
them in the tests).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ..effects import Effect
from ..parametric_errors import AXES, AXIS_INDEX, SQUARENESS
from ..thermal import (
    ScaleExpansionEffect,
    SquarenessDriftEffect,
    ThermalGradientEffect,
    ThermalLagEffect,
    WorkpieceExpansionEffect,
    lag_filter,
)
from .candidate import Candidate, EffectBuilder, effect_displacement_um, imaged, with_static_image
from .residuals import FloatArray, Residuals

__all__ = ["LAG_TIME_CONSTANTS_S", "thermal_candidates"]

LAG_TIME_CONSTANTS_S: tuple[float, ...] = tuple(
    float(v) for v in np.geomspace(120.0, 12 * 3600.0, 34)
)
LOBES: tuple[int, ...] = (2, 3, 4, 5, 6)
#: Plausible size (1σ) of a structure's start-up offset from its sensor (°C): a machine that has
#: stood in its room for hours is within a degree or two of what its sensors read.
START_STATE_SD_C = 2.0
#: Plausible size (1σ) of a squareness' temperature coefficient (µrad/°C).
SQUARENESS_DRIFT_SD_URAD_PER_C = 5.0


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


def _thermal(eff: Any, reference_C: float) -> Effect:
    eff.reference_C = reference_C
    return eff


def _gradient_builder(a: str, ref_c: float) -> EffectBuilder:
    # p: curvature, tilt, positional (2), deflection at the reference[, taper[, e3, e4]]:
    # rich, a curvature that varies along the beam up to a cubic (a gradient confined to
    # part of it)
    return lambda p, _t: _thermal(
        ThermalGradientEffect(
            a,
            p[0],
            p[1],
            p[2],
            p[3],
            p[5] if len(p) > 5 else 0.0,
            offset_um_per_C=p[4],
            tilt_poly_urad_per_C=p[6:],
        ),
        ref_c,
    )


def _squareness_drift_builder(comp: str, ref_c: float) -> EffectBuilder:
    return lambda p, _t: _thermal(SquarenessDriftEffect(comp, p[0], "T_air"), ref_c)


def _axis_candidates(res: Residuals, a: str, ref_c: float) -> list[Candidate]:
    """The thermal causes of one moved axis: its guideway's bend with ``T_top − T_bottom`` and
    its scale's expansion, each as the temperatures logged allow."""
    out: list[Candidate] = []
    if res.has("T_top", "T_bottom"):
        gradient = imaged(
            Candidate(
                "thermal_gradient",
                {"axis": a},
                5,
                _gradient_builder(a, ref_c),
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
            "scale_expansion",
            {"axis": a},
            1,
            lambda p, _t: _thermal(ScaleExpansionEffect(a, p[0]), ref_c),
            drivers=(f"T_{a}",),
        )
        out.append(imaged(scale, res))
        out.append(imaged(_scale_origin_candidate(res, a, ref_c), res))
    return out


def _squareness_drift_candidates(res: Residuals, ref_c: float) -> list[Candidate]:
    """A squareness that follows the air temperature (µrad/°C), at once and, with a time column,
    through a lag (10 min … hours: the same cause)."""
    out: list[Candidate] = []
    for comp in SQUARENESS:
        out.append(
            imaged(
                Candidate(
                    "squareness_drift",
                    {"component": comp},
                    1,
                    _squareness_drift_builder(comp, ref_c),
                    drivers=("T_air",),
                ),
                res,
            )
        )
    if res.has("t") and float(np.ptp(res.signals["t"])) > 0:
        # the structure follows the air through a lag (10 min … hours): the same cause
        for comp in SQUARENESS:
            out.append(
                imaged(
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
    return out


def thermal_candidates(res: Residuals, moved: dict[str, bool]) -> list[Candidate]:
    """Every thermal cause the session's temperatures (and time) can show."""
    m = res.machine
    ref_c = m.thermal.reference_C
    out: list[Candidate] = []
    for a in AXES:
        if moved[a]:
            out += _axis_candidates(res, a, ref_c)
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
            lambda p, _t: _thermal(WorkpieceExpansionEffect(p[0], fx), ref_c),
            drivers=("T_wp",),
        )
        out.append(imaged(workpiece, res))
        out.append(imaged(_workpiece_fixture_candidate(res, fx, ref_c), res))
    if res.has("T_air"):
        out += _squareness_drift_candidates(res, ref_c)
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
    return out
