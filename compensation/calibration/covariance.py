"""From the fit's covariance to uncertainties people use (docs/calibration.md §uncertainty):

* each identified error function with its standard uncertainty along the axis (the ``errors``
  of ``calibration.json``), each squareness;
* the volumetric error on a grid of the volume at the calibration stylus and its expanded
  uncertainty (k = 2, per component) of the **rigid-body-free** part: the covariance projected
  onto the space orthogonal to the six rigid motions of the grid (least squares) — what
  ``volumetric_u.csv`` holds;
* the ``[uncertainty]`` section of ``machine.toml``: per table the parameters (u, u_per_m,
  correlation_mm) of the virtual CMM's random function fitted to that table's covariance, per
  squareness its u. That form has no correlation *between* tables (the fit has): it is a
  summary for the virtual CMM; :func:`virtual_cmm_check` says how well it reproduces the fit's U.

Covariances are in the fit's gauge: rigid rotations pinned at zero, every linear error zero at
the reference point. Units: µm, µrad, mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

from ..parametric_errors import SQUARENESS
from .basis import FunctionBasis, Layout
from .model import MachineModel
from .rigid import grid_points, rigid_basis

__all__ = [
    "FunctionBand",
    "VolumetricU",
    "function_bands",
    "table_uncertainty",
    "volumetric_u",
]

FloatArray = NDArray[np.float64]
BAND_POINTS = 41  # positions of a polynomial's band (a spline's are its nodes)


@dataclass(frozen=True)
class FunctionBand:
    """One identified function: values and standard uncertainty (k = 1) at ``position_mm``."""

    name: str
    position_mm: FloatArray
    value: FloatArray
    u: FloatArray
    covariance: FloatArray  # at position_mm
    curve: tuple[FloatArray, FloatArray, FloatArray]  # dense (q mm, value, u) for plots


@dataclass(frozen=True)
class VolumetricU:
    """The grid (N, 3) mm, the identified volumetric error (N, 3) µm at the stylus and the
    expanded uncertainty U (k = 2) of its rigid-body-free part (N, 3) µm."""

    points_mm: FloatArray
    stylus_mm: FloatArray
    error_um: FloatArray
    U_um: FloatArray

    def summary(self) -> dict[str, Any]:
        return {
            "coverage_factor": 2,
            "stylus_mm": self.stylus_mm.tolist(),
            "nodes": int(self.points_mm.shape[0]),
            "max_um": self.U_um.max(axis=0).tolist(),
            "rms_um": np.sqrt(np.mean(self.U_um**2, axis=0)).tolist(),
            "definition": "expanded uncertainty (k = 2) per component of the identified "
            "volumetric error after removing the least-squares rigid motion of the grid",
        }


def band_positions(fn: FunctionBasis) -> FloatArray:
    if fn.nodes_mm is not None:
        return fn.nodes_mm.copy()
    return np.linspace(fn.lo_mm, fn.hi_mm, BAND_POINTS)


def function_bands(layout: Layout, theta: FloatArray, cov: FloatArray) -> list[FunctionBand]:
    """Every identified function's values and u at its nodes (or along its span)."""
    out = []
    for fn in layout.functions:
        q = band_positions(fn)
        m = fn.matrix(q)
        c = m @ cov[fn.cols, fn.cols] @ m.T
        dense = np.linspace(fn.lo_mm, fn.hi_mm, 201)
        md = fn.matrix(dense)
        ud = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", md, cov[fn.cols, fn.cols], md), 0.0, None))
        out.append(
            FunctionBand(
                name=fn.name,
                position_mm=q,
                value=m @ theta[fn.cols],
                u=np.sqrt(np.clip(np.diag(c), 0.0, None)),
                covariance=c,
                curve=(dense, md @ theta[fn.cols], ud),
            )
        )
    return out


def squareness_bands(layout: Layout, theta: FloatArray, cov: FloatArray) -> dict[str, Any]:
    out = {}
    for name in SQUARENESS:
        if name in layout.squareness:
            j = layout.squareness[name]
            out[name] = {"value_urad": float(theta[j]), "u_urad": float(np.sqrt(max(cov[j, j], 0)))}
    return out


def volumetric_u(
    model: MachineModel,
    theta: FloatArray,
    cov: FloatArray,
    stylus_mm: FloatArray,
    steps: tuple[int, int, int],
) -> VolumetricU:
    """The identified error and U of its rigid-body-free part on the plan's grid."""
    lay = model.layout
    q = grid_points(lay.lower_mm, lay.upper_mm, steps)
    pts = model.points(q, stylus_mm)
    err, _ = model.exact(theta, pts)
    g = model.error_jacobian(pts).reshape(-1, lay.n)
    b = rigid_basis(q)
    coef = np.linalg.lstsq(b, g, rcond=None)[0]
    a = g - b @ coef  # (I − B B⁺) G
    var = np.einsum("ij,jk,ik->i", a, cov, a)
    u = 2.0 * np.sqrt(np.clip(var, 0.0, None)).reshape(-1, 3)
    return VolumetricU(points_mm=q, stylus_mm=np.asarray(stylus_mm, float), error_um=err, U_um=u)


def table_uncertainty(band: FunctionBand, reference_mm: float) -> dict[str, float]:
    """``u``, ``u_per_m``, ``u_relative`` (0) and ``correlation_mm`` of the virtual CMM's random
    function (docs/formats.md §1.11) fitted to the band's covariance: the variance profile by
    non-negative least squares in (1, d²) (d the distance from the reference, m), the
    correlation length by least squares over the whole covariance."""
    q = band.position_mm
    c = band.covariance
    var = np.clip(np.diag(c), 0.0, None)
    d = (q - reference_mm) / 1000.0
    coef, _ = nnls(np.column_stack([np.ones_like(d), d**2]), var)
    u, u_pm = float(np.sqrt(coef[0])), float(np.sqrt(coef[1]))
    span = float(q[-1] - q[0]) if q.size > 1 else 1.0
    best, best_err = span / 4.0, np.inf
    dq = q[:, None] - q[None, :]
    for ell in span * np.geomspace(0.02, 4.0, 40):
        model = u**2 * np.exp(-0.5 * (dq / ell) ** 2) + u_pm**2 * np.outer(d, d)
        err = float(np.sum((model - c) ** 2))
        if err < best_err:
            best, best_err = float(ell), err
    return {"u": u, "u_per_m": u_pm, "u_relative": 0.0, "correlation_mm": max(best, 1e-3)}
