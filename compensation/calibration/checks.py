"""Checks that the written machine is the fitted one (docs/calibration.md §checks):

* **re-simulation**: every reading predicted again through the public machine API
  (:meth:`Machine.volumetric_error`, :meth:`Machine.pose_error`, :mod:`.simulate`) of the
  machine as written, with the fitted plate poses and stations, against the solver's own exact
  prediction: they must agree to rounding (the file reproduces its own data);
* **exact vs first order**: the solver's exact chain against the paper's first-order form
  (the Jacobian) at every reading and, through the machine API, on the volume grid: how much
  the exact model matters for this machine.

Units: µm, µrad.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .obs_artefacts import MultilaterationBlock, PlateBlock, StationState
from .obs_laser import LaserBlock
from .observation import project
from .simulate import run_values, trac_inputs
from .solver import Problem

if TYPE_CHECKING:
    from ..machine import Machine

__all__ = ["exact_vs_first_order", "resimulation", "virtual_cmm_check"]

FloatArray = NDArray[np.float64]


def resimulation(
    problem: Problem, theta: FloatArray, states: list[Any], machine: Machine
) -> dict[str, Any]:
    """Largest |written machine − fit| over each block's readings (µm or µrad)."""
    out: list[dict[str, Any]] = []
    for block, state in zip(problem.blocks, states, strict=True):
        if isinstance(block, LaserBlock):
            mine = block.predict(problem.model, theta)
            theirs = np.concatenate(
                [run_values(machine, r) for r in block.row_runs]
                + [run_values(machine, r) for r in block.square_runs]
            )
            diff = project(mine - theirs, block.projections)
        elif isinstance(block, PlateBlock):  # the residual differs by the error alone
            d = block.data
            err = machine.volumetric_error(d.q_mm, d.spec.stylus_mm, dict(d.temps_C) or None)
            mine, _ = problem.model.exact(theta, block.pts)
            diff = (mine - err).reshape(-1)
        elif isinstance(block, MultilaterationBlock):
            ss: StationState = state
            d2 = block.data
            err = machine.volumetric_error(
                d2.q_mm, d2.spec.stylus_mm, dict(d2.temps_C) or None, inputs=trac_inputs(d2)
            )
            p_theirs = d2.q_mm + err / 1000.0
            mine, _ = problem.model.exact(theta, block.pts)
            p_mine = d2.q_mm + mine / 1000.0
            s = ss.position_mm[d2.station]
            diff = 1000.0 * (
                np.linalg.norm(p_mine - s, axis=1) - np.linalg.norm(p_theirs - s, axis=1)
            )
        else:  # pragma: no cover - every block kind is handled above
            continue
        out.append(
            {"source": block.source, "kind": block.kind, "max_abs": float(np.max(np.abs(diff)))}
        )
    worst = max((float(o["max_abs"]) for o in out), default=0.0)
    return {
        "max_abs": worst,
        "per_dataset": out,
        "definition": "largest |reading predicted by the written machine.toml (public machine "
        "API) − reading predicted by the fit| (µm, µrad); rounding only when the file is the fit",
    }


def exact_vs_first_order(
    problem: Problem,
    theta: FloatArray,
    machine: Machine,
    grid_mm: FloatArray,
    stylus_mm: FloatArray,
) -> dict[str, Any]:
    """Largest |exact − first order| of the volumetric error at every reading and on the grid."""
    worst_data, scale = 0.0, 0.0
    for block in problem.blocks:
        pts = getattr(block, "pts", None)
        if pts is None and isinstance(block, LaserBlock) and block._rows is not None:
            pts = block._rows[0]
        if pts is None:
            continue
        exact, _ = problem.model.exact(theta, pts)
        first = np.einsum("nip,p->ni", problem.model.error_jacobian(pts), theta) + pts.thermal_um
        worst_data = max(worst_data, float(np.max(np.abs(exact - first))))
        scale = max(scale, float(np.max(np.abs(exact))))
    e = machine.volumetric_error(grid_mm, stylus_mm)
    f = machine.volumetric_error(grid_mm, stylus_mm, method="first_order")
    return {
        "readings_max_abs_um": worst_data,
        "readings_max_error_um": scale,
        "grid_max_abs_um": float(np.max(np.abs(e - f))),
        "grid_max_error_um": float(np.max(np.abs(e))),
        "definition": "largest |exact chain − paper's first-order form| of the volumetric error "
        "(µm): the second-order part the exact model carries",
    }


def virtual_cmm_check(
    machine: Machine, points_mm: FloatArray, stylus_mm: FloatArray, fit_u_um: FloatArray
) -> dict[str, Any]:
    """How well the written ``[uncertainty]`` (per table, no correlation between tables)
    reproduces the fit's own U: the virtual CMM's first-order U (calibration part only: tables
    and squareness, no probing, no random parts) of the rigid-body-free volumetric error on the
    same grid, as a ratio to the fit's U (k = 2)."""
    from dataclasses import replace

    from ..uncertainty.gum import residual_covariance
    from .rigid import rigid_basis

    model = replace(machine.uncertainty_model(), probe_um=0.0)
    n = points_mm.shape[0]
    cov = residual_covariance(
        machine, points_mm, stylus_mm, model=model, random_parts=False
    ).reshape(3 * n, 3 * n)
    b = rigid_basis(points_mm)
    proj = np.eye(3 * n) - b @ np.linalg.pinv(b)
    u_vcmm = 2.0 * np.sqrt(np.clip(np.diag(proj @ cov @ proj.T), 0.0, None)).reshape(n, 3)
    ok = fit_u_um > 0
    ratio = u_vcmm[ok] / fit_u_um[ok]
    return {
        "ratio_median": float(np.median(ratio)) if ratio.size else None,
        "ratio_p05": float(np.percentile(ratio, 5)) if ratio.size else None,
        "ratio_p95": float(np.percentile(ratio, 95)) if ratio.size else None,
        "definition": "U (k = 2) of the rigid-body-free volumetric error at the calibration "
        "stylus from the written [uncertainty] (virtual CMM, first order, tables and squareness) "
        "over the fit's own U, on the volumetric_u.csv grid",
    }
