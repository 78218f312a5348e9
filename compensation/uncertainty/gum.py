"""First-order propagation (the GUM uncertainty framework) of the same uncertainty model: the
analytic counterpart of the virtual CMM, and the check of JCGM 101 §8 (does the GUM interval
agree with the Monte Carlo one to the numerical tolerance?).

The residual of N probing points, (N, 3) µm, is to first order linear in the inputs: the tables'
calibration errors through the chain's partial derivatives (the paper's appendix A.1,
:func:`..kinematics.first_order_jacobian`), with the covariance of one table between two points
from its random function (:meth:`.model.TableUncertainty.covariance`); the tables' random parts
(independent at every probing: the paper's RSS, ``Machine.random_error``); squareness; the
thermal terms ``α·εT + ΔT·εα`` (their product ``εα·εT`` is second order and left out); probing.
:func:`residual_covariance` gives the (N, 3, N, 3) covariance; a measurand linear in the
residuals (a length, a sphere centre) gets ``u² = sᵀ·C·s``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..kinematics import first_order_jacobian
from ..parametric_errors import AXIS_INDEX, parse_component
from ..thermal.roles import WORKPIECE, scale_role
from .model import UncertaintyModel

if TYPE_CHECKING:
    from ..machine import Machine

__all__ = [
    "BUDGET_GROUPS",
    "gum_check",
    "residual_covariance",
    "residual_std",
    "uncertainty_budget",
]

#: Input groups of :func:`uncertainty_budget`.
BUDGET_GROUPS = (
    "calibration",
    "random_parts",
    "squareness",
    "scale_thermal",
    "workpiece_thermal",
    "probing",
)

FloatArray = NDArray[np.float64]
K95 = 1.959963984540054  # the Gaussian coverage factor for p = 0.95


def residual_covariance(
    machine: Machine,
    points_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    model: UncertaintyModel | None = None,
    random_parts: bool = True,
) -> FloatArray:
    """First-order covariance (N, 3, N, 3) µm² of the residuals at N probing points (each point
    its own probing: random parts and probing errors independent between points);
    ``random_parts=False`` leaves the tables' random parts out (for a budget)."""
    mdl = model if model is not None else machine.uncertainty_model()
    q = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    n = q.shape[0]
    p = np.broadcast_to(machine.stylus_or_probe(stylus_mm), (n, 3))
    ctx = machine.context(q, temps_C, inputs)
    jac, sq = first_order_jacobian(machine.chain, ctx.u_mm, p)
    cov = np.zeros((n, 3, n, 3))
    for comp, tu in mdl.tables.items():
        if tu.is_zero:
            continue
        c = parse_component(comp)
        k = AXIS_INDEX[c.axis]
        g = jac[:, :, k, c.slot]  # (N, 3)
        table = machine.tables.get(comp)
        v = table.evaluate(q[:, k]) if table is not None else np.zeros(n)
        ck = tu.covariance(q[:, k][:, None], q[:, k][None, :], v[:, None], v[None, :])
        cov += np.einsum("ai,ab,bj->aibj", g, ck, g)
    diag = np.zeros((n, 3, 3))
    for table in machine.tables.values():
        if not (table.has_random and random_parts):
            continue
        c = table.component
        k = AXIS_INDEX[c.axis]
        g = jac[:, :, k, c.slot]
        sigma = table.evaluate_random(q[:, k]) / 2.0
        diag += np.einsum("ai,aj,a->aij", g, g, sigma**2)
    diag += np.eye(3) * mdl.probe_um**2
    idx = np.arange(n)
    cov[idx, :, idx, :] += diag
    cov += np.einsum("aij,bkj,j->aibk", sq, sq, mdl.squareness_urad**2)
    ref_c = machine.thermal.reference_C
    for k, axis in enumerate("xyz"):
        alpha = float(machine.thermal.expansion[k])
        u_a, u_t = float(mdl.expansion[k]), float(mdl.scale_temperature_C[k])
        d_t = ctx.signals[scale_role(axis)] - ref_c
        lever = ctx.u_mm[:, k] / 1000.0
        cov[:, k, :, k] += (alpha**2 * u_t**2 + np.outer(d_t, d_t) * u_a**2) * np.outer(
            lever, lever
        )
    alpha_wp = float(machine.thermal.workpiece_expansion or 0.0)
    if alpha_wp:
        fixture = machine.thermal.workpiece_fixture_mm
        fixture = machine.volume.reference_mm if fixture is None else fixture
        lever = (q - np.asarray(fixture, float)) / 1000.0
        d_t = ctx.signals[WORKPIECE] - ref_c
        scal = (
            alpha_wp**2 * mdl.workpiece_temperature_C**2
            + np.outer(d_t, d_t) * mdl.workpiece_expansion**2
        )
        cov += np.einsum("ab,ai,bj->aibj", scal, lever, lever)
    return cov


def residual_std(
    machine: Machine,
    points_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    model: UncertaintyModel | None = None,
    random_parts: bool = True,
) -> FloatArray:
    """First-order standard uncertainty (N, 3) µm of each corrected point's components."""
    q = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    out = np.empty((q.shape[0], 3))
    step = 256  # block-diagonal only: the (N, 3, N, 3) matrix is never formed for many points
    p = np.broadcast_to(machine.stylus_or_probe(stylus_mm), q.shape)
    for i in range(0, q.shape[0], step):
        sl = slice(i, i + step)
        sub_t = signals_at(temps_C, sl, q.shape[0])
        sub_i = signals_at(inputs, sl, q.shape[0])
        c = residual_covariance(
            machine, q[sl], p[sl], sub_t, sub_i, model=model, random_parts=random_parts
        )
        m = c.shape[0]
        out[sl] = np.sqrt(np.maximum(c[np.arange(m), :, np.arange(m), :].diagonal(0, 1, 2), 0))
    return out


def signals_at(
    mapping: Mapping[str, Any] | None, sel: slice | NDArray[np.bool_], n: int
) -> dict[str, Any] | None:
    """The signals (temperatures °C, other inputs) of the points ``sel`` (a slice or a mask) of
    n: a per-point (n,) value indexed, a scalar (or None) as given; None without signals."""
    if not mapping:
        return None
    out: dict[str, Any] = {}
    for k, v in mapping.items():
        arr = None if v is None else np.asarray(v, dtype=float)
        out[k] = arr[sel] if arr is not None and arr.ndim == 1 and arr.shape[0] == n else arr
    return out


def gum_check(
    u_gum: FloatArray,
    low: FloatArray,
    high: FloatArray,
    tolerance: FloatArray,
    estimate: FloatArray | float = 0.0,
    probability: float = 0.95,
) -> dict[str, Any]:
    """JCGM 101 §8: the GUM interval ``y ± k_p·u`` (Gaussian k_p) against the Monte Carlo interval
    [low, high]: ``d_low = |y − U_p − low|``, ``d_high = |y + U_p − high|``; validated where both
    are ≤ the numerical tolerance δ."""
    from scipy.stats import norm

    k_p = float(norm.ppf(0.5 + probability / 2.0))
    u_gum = np.asarray(u_gum, dtype=float)
    y = np.asarray(estimate, dtype=float)
    d_low = np.abs(y - k_p * u_gum - low)
    d_high = np.abs(y + k_p * u_gum - high)
    valid = (d_low <= tolerance) & (d_high <= tolerance)
    return {
        "u": u_gum.tolist(),
        "U_k2": (2.0 * u_gum).tolist(),
        "k_p": k_p,
        "d_low": d_low.tolist(),
        "d_high": d_high.tolist(),
        "validated": bool(np.all(valid)),
        "rule": "JCGM 101 §8.2: |y ∓ U_p − y_low/high| ≤ δ",
    }


def uncertainty_budget(
    machine: Machine,
    points_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    model: UncertaintyModel | None = None,
) -> dict[str, FloatArray]:
    """First-order uncertainty budget: per input group (:data:`BUDGET_GROUPS`) the standard
    uncertainty (N, 3) µm it alone gives each corrected point; the groups are independent, so
    their squares add up to the total's."""
    mdl = model if model is not None else machine.uncertainty_model()
    zero3 = np.zeros(3)
    nothing = replace(
        mdl,
        tables={},
        squareness_urad=zero3,
        scale_temperature_C=zero3,
        expansion=zero3,
        workpiece_temperature_C=0.0,
        workpiece_expansion=0.0,
        probe_um=0.0,
    )
    only = {
        "calibration": replace(nothing, tables=mdl.tables),
        "random_parts": nothing,
        "squareness": replace(nothing, squareness_urad=mdl.squareness_urad),
        "scale_thermal": replace(
            nothing, scale_temperature_C=mdl.scale_temperature_C, expansion=mdl.expansion
        ),
        "workpiece_thermal": replace(
            nothing,
            workpiece_temperature_C=mdl.workpiece_temperature_C,
            workpiece_expansion=mdl.workpiece_expansion,
        ),
        "probing": replace(nothing, probe_um=mdl.probe_um),
    }
    return {
        group: residual_std(
            machine,
            points_mm,
            stylus_mm,
            temps_C,
            inputs,
            model=sub,
            random_parts=group == "random_parts",
        )
        for group, sub in only.items()
    }
