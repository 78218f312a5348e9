"""The uncertainty a correction grid carries: U of every corrected point, interpolated from the
nodes like the translations (docs/formats.md §7, docs/uncertainty.md).

At every node the grid stores the covariance of the residual error pose (what the correction
leaves, from the virtual CMM, :mod:`cmm_comp.compensation.uncertainty.grid_field`): translation
δt (µm, at stylus offset 0) and rotation vector δω (µrad), as the 15 entries
:data:`COVARIANCE_COMPONENTS` that the per-component variance at any stylus needs. The residual
at stylus offset p (mm) is ``r = δt + 10⁻³·δω × p`` µm, so

    var(r_x) = C(tx,tx) + 2·10⁻³(p_z·C(tx,wy) − p_y·C(tx,wz)) + 10⁻⁶(p_z²·C(wy,wy)
               + p_y²·C(wz,wz) − 2·p_y·p_z·C(wy,wz))                         (y, z alike)

Between nodes the entries are interpolated by the same C² tricubic not-a-knot spline as the
translations (a variance interpolated below zero is taken as zero). The terms that depend on
the run-time signals are added analytically, from the header: per axis with an expansion
coefficient α the scale term ``(α²·u_T² + ΔT²·u_α² + u_α²·u_T²)·(u_k/1000)²`` (u_k mm from the
reference; exact for independent α and T errors), the workpiece term likewise about its fixture
point, and the probing ``σ²``. Then U = k·√var per component (k = 2).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import prange
from numpy.typing import NDArray
from scipy.interpolate import make_interp_spline

from ..jit import njit_cached
from .kernels import _basis3, _locate

__all__ = [
    "COVARIANCE_COMPONENTS",
    "UNCERTAINTY_MEMBER",
    "GridUncertainty",
    "PointUncertainty",
    "ThermalUncertainty",
    "variance_from_covariance",
]

FloatArray = NDArray[np.float64]
UNCERTAINTY_MEMBER = "uncertainty_covariance"
#: Entries of the residual pose covariance stored per node: t = translation µm, w = rotation
#: vector µrad (units µm², µm·µrad, µrad²).
COVARIANCE_COMPONENTS: tuple[str, ...] = (
    "tx_tx", "ty_ty", "tz_tz",
    "tx_wy", "tx_wz", "ty_wx", "ty_wz", "tz_wx", "tz_wy",
    "wx_wx", "wy_wy", "wz_wz", "wx_wy", "wx_wz", "wy_wz",
)  # fmt: skip
_NCOV = len(COVARIANCE_COMPONENTS)
PARALLEL_MIN = 256
"""Points from which the batch U pass runs on the thread pool (as the grid's correction)."""


@dataclass(frozen=True)
class ThermalUncertainty:
    """What the run-time thermal part of U needs (standard uncertainties, k = 1): per axis the
    expansion coefficient α (µm/(m·°C)) and the u of α and of the scale temperature (°C); the
    workpiece's likewise and its fixture point (mm); reference point (mm) and °C."""

    reference_C: float = 20.0
    reference_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    expansion: tuple[float, float, float] = (0.0, 0.0, 0.0)
    u_expansion: tuple[float, float, float] = (0.0, 0.0, 0.0)
    u_temperature_C: tuple[float, float, float] = (0.0, 0.0, 0.0)
    workpiece_expansion: float = 0.0
    u_workpiece_expansion: float = 0.0
    u_workpiece_temperature_C: float = 0.0
    workpiece_fixture_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_header(self) -> dict[str, Any]:
        return {
            "reference_C": self.reference_C,
            "reference_mm": list(self.reference_mm),
            "expansion": list(self.expansion),
            "u_expansion": list(self.u_expansion),
            "u_temperature_C": list(self.u_temperature_C),
            "workpiece_expansion": self.workpiece_expansion,
            "u_workpiece_expansion": self.u_workpiece_expansion,
            "u_workpiece_temperature_C": self.u_workpiece_temperature_C,
            "workpiece_fixture_mm": list(self.workpiece_fixture_mm),
        }

    @classmethod
    def from_header(cls, h: Mapping[str, Any]) -> ThermalUncertainty:
        def vec(key: str) -> tuple[float, float, float]:
            v = [float(x) for x in h[key]]
            if len(v) != 3 or not all(math.isfinite(x) for x in v):
                raise ValueError(f"uncertainty.thermal.{key} must be 3 finite numbers")
            return (v[0], v[1], v[2])

        def num(key: str) -> float:
            v = float(h[key])
            if not math.isfinite(v):
                raise ValueError(f"uncertainty.thermal.{key} must be finite")
            return v

        out = cls(
            reference_C=num("reference_C"),
            reference_mm=vec("reference_mm"),
            expansion=vec("expansion"),
            u_expansion=vec("u_expansion"),
            u_temperature_C=vec("u_temperature_C"),
            workpiece_expansion=num("workpiece_expansion"),
            u_workpiece_expansion=num("u_workpiece_expansion"),
            u_workpiece_temperature_C=num("u_workpiece_temperature_C"),
            workpiece_fixture_mm=vec("workpiece_fixture_mm"),
        )
        if (
            min(*out.u_expansion, *out.u_temperature_C) < 0
            or min(out.u_workpiece_expansion, out.u_workpiece_temperature_C) < 0
        ):
            raise ValueError("uncertainty.thermal: standard uncertainties must be ≥ 0")
        return out

    def variance_um2(self, points_mm: FloatArray, temps_C: Mapping[str, FloatArray]) -> FloatArray:
        """(N, 3) µm² of the thermal terms at ``points_mm`` for temperatures by role (°C, (N,)
        arrays; a missing role counts as the reference)."""
        n = points_mm.shape[0]
        var = np.zeros((n, 3))
        for k, axis in enumerate("xyz"):
            a, ua, ut = self.expansion[k], self.u_expansion[k], self.u_temperature_C[k]
            if ua == 0.0 and (a == 0.0 or ut == 0.0):
                continue
            d_t = temps_C.get(f"T_{axis}")
            dt = np.zeros(n) if d_t is None else np.asarray(d_t, float) - self.reference_C
            lever = (points_mm[:, k] - self.reference_mm[k]) / 1000.0
            var[:, k] += (a * a * ut * ut + dt * dt * ua * ua + ua * ua * ut * ut) * lever**2
        a, ua, ut = (
            self.workpiece_expansion,
            self.u_workpiece_expansion,
            self.u_workpiece_temperature_C,
        )
        if a != 0.0 and (ua > 0.0 or ut > 0.0):
            d_t = temps_C.get("T_wp")
            dt = np.zeros(n) if d_t is None else np.asarray(d_t, float) - self.reference_C
            lever = (points_mm - np.asarray(self.workpiece_fixture_mm)) / 1000.0
            var += ((a * a * ut * ut + dt * dt * ua * ua + ua * ua * ut * ut)[:, None]) * lever**2
        return var


@dataclass
class GridUncertainty:
    """The uncertainty data of a grid: node covariances (nx, ny, nz, 15) of the residual pose,
    the probing σ (µm, k = 1), the thermal data, the coverage factor and provenance (``info``:
    trials, seed, method, the uncertainty model with its defaulted values)."""

    covariance: FloatArray
    probe_um: float
    thermal: ThermalUncertainty
    coverage_factor: float = 2.0
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        cov = np.asarray(self.covariance, dtype=np.float64)
        if cov.ndim != 4 or cov.shape[-1] != _NCOV:
            raise ValueError(
                f"uncertainty covariance must be (nx, ny, nz, {_NCOV}), got {cov.shape}"
            )
        if not np.all(np.isfinite(cov)):
            raise ValueError("uncertainty covariance must be finite")
        if np.any(cov[..., [0, 1, 2, 9, 10, 11]] < 0):
            raise ValueError("uncertainty covariance: variances must be ≥ 0")
        if not (math.isfinite(self.probe_um) and self.probe_um >= 0):
            raise ValueError(f"uncertainty probe_um must be finite and ≥ 0, got {self.probe_um}")
        if not (math.isfinite(self.coverage_factor) and self.coverage_factor > 0):
            raise ValueError(f"coverage factor must be finite and > 0, got {self.coverage_factor}")
        self.covariance = np.ascontiguousarray(cov)
        self._coef: FloatArray | None = None
        t = self.thermal
        if t.workpiece_expansion == 0.0:  # no workpiece term in the model: none in U
            wp = [0.0, 0.0, 0.0]
        else:
            wp = [t.workpiece_expansion, t.u_workpiece_expansion, t.u_workpiece_temperature_C]
        scale = [  # an axis contributes only as variance_um2 says
            (a, ua, ut) if not (ua == 0.0 and (a == 0.0 or ut == 0.0)) else (0.0, 0.0, 0.0)
            for a, ua, ut in zip(t.expansion, t.u_expansion, t.u_temperature_C, strict=True)
        ]
        #: (column, role) of the temperatures U depends on (columns of ΔT: T_x, T_y, T_z,
        #: T_wp); any other temperature cannot change U and is not read (a NaN there cannot
        #: poison it).
        self.active_roles: tuple[tuple[int, str], ...] = tuple(
            (k, role)
            for k, (role, used) in enumerate(
                zip(
                    ("T_x", "T_y", "T_z", "T_wp"),
                    (*(v != (0.0, 0.0, 0.0) for v in scale), wp != [0.0, 0.0, 0.0]),
                    strict=True,
                )
            )
            if used
        )
        #: [reference_C, reference (3), α (3), uα (3), uT (3), α_wp, uα_wp, uT_wp, fixture (3),
        #: probe σ², coverage factor] for the compiled single-point path.
        self.thermal_vector = np.array(
            [
                t.reference_C, *t.reference_mm,
                *(v[0] for v in scale), *(v[1] for v in scale), *(v[2] for v in scale),
                *wp, *t.workpiece_fixture_mm, self.probe_um**2, self.coverage_factor,
            ],
            dtype=np.float64,
        )  # fmt: skip

    def to_header(self) -> dict[str, Any]:
        """The grid header's ``uncertainty`` object (JSON)."""
        return {
            "coverage_factor": self.coverage_factor,
            "covariance_components": list(COVARIANCE_COMPONENTS),
            "covariance_units": "um^2 (t t), um*urad (t w), urad^2 (w w); t = translation at "
            "stylus 0, w = rotation vector of R_true R_model^T",
            "probe_um": self.probe_um,
            "thermal": self.thermal.to_header(),
            "rule": "var_i = a_i^T C a_i, r = t + 1e-3 w x p (p stylus mm); + thermal + probe^2; "
            "U_i = coverage_factor * sqrt(var_i)",
            **self.info,
        }

    @classmethod
    def from_header(cls, header: Mapping[str, Any], covariance: FloatArray) -> GridUncertainty:
        """From the header object and the covariance member; ValueError naming the problem."""
        if not isinstance(header, Mapping):
            raise ValueError("header 'uncertainty' must be an object")
        comps = header.get("covariance_components")
        if list(comps or []) != list(COVARIANCE_COMPONENTS):
            raise ValueError(
                f"uncertainty covariance_components {comps!r} are not this version's "
                f"{list(COVARIANCE_COMPONENTS)}"
            )
        info = {
            k: v
            for k, v in header.items()
            if k
            not in (
                "coverage_factor",
                "covariance_components",
                "covariance_units",
                "probe_um",
                "thermal",
                "rule",
            )
        }
        return cls(
            covariance=covariance,
            probe_um=float(header["probe_um"]),
            thermal=ThermalUncertainty.from_header(header["thermal"]),
            coverage_factor=float(header["coverage_factor"]),
            info=info,
        )

    # ------------------------------------------------------------------ interpolation
    def coefficients(self, axes: Sequence[FloatArray]) -> FloatArray:
        """Tensor-product not-a-knot cubic spline coefficients (nx, ny, nz, 15) on ``axes``."""
        if self._coef is None:
            coef = self.covariance
            for axis in range(3):
                spline = make_interp_spline(axes[axis], coef, k=3, axis=axis)
                coef = np.moveaxis(spline.c, 0, axis)
            self._coef = np.ascontiguousarray(coef)
        return self._coef

    def __getstate__(self) -> dict[str, Any]:
        return dict(self.__dict__)


def variance_from_covariance(cov: FloatArray, stylus_mm: FloatArray) -> FloatArray:
    """(N, 3) µm²: the residual's per-component variance at stylus ``stylus_mm`` ((1 or N), 3)
    from interpolated covariance entries ``cov`` (N, 15) (:data:`COVARIANCE_COMPONENTS`)."""
    p = np.broadcast_to(stylus_mm, (cov.shape[0], 3))
    px, py, pz = p[:, 0], p[:, 1], p[:, 2]
    c = {name: cov[:, i] for i, name in enumerate(COVARIANCE_COMPONENTS)}
    var = np.empty((cov.shape[0], 3))
    var[:, 0] = (
        c["tx_tx"]
        + 2e-3 * (pz * c["tx_wy"] - py * c["tx_wz"])
        + 1e-6 * (pz * pz * c["wy_wy"] + py * py * c["wz_wz"] - 2 * py * pz * c["wy_wz"])
    )
    var[:, 1] = (
        c["ty_ty"]
        + 2e-3 * (px * c["ty_wz"] - pz * c["ty_wx"])
        + 1e-6 * (px * px * c["wz_wz"] + pz * pz * c["wx_wx"] - 2 * px * pz * c["wx_wz"])
    )
    var[:, 2] = (
        c["tz_tz"]
        + 2e-3 * (py * c["tz_wx"] - px * c["tz_wy"])
        + 1e-6 * (py * py * c["wx_wx"] + px * px * c["wy_wy"] - 2 * px * py * c["wx_wy"])
    )
    return np.maximum(var, 0.0)


@njit_cached(parallel=True)
def eval_spline(points, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, out):  # type: ignore[no-untyped-def]
    """Tricubic B-spline values (N, C) of ``coef`` (nx, ny, nz, C) at clamped ``points`` (N, 3)
    mm (same knots and cell spans as the grid's translation spline)."""
    for n in prange(points.shape[0]):
        _spline_row(n, points, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, out)


@njit_cached()
def eval_spline_serial(points, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, out):  # type: ignore[no-untyped-def]
    """:func:`eval_spline` without threads (one reading: no thread-pool wake-up)."""
    for n in range(points.shape[0]):
        _spline_row(n, points, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, out)


@njit_cached()
def _spline_row(n, points, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, out):  # type: ignore[no-untyped-def]
    nx, ny, nz = shape[0], shape[1], shape[2]
    ncomp = coef.shape[3]
    bx = np.empty(4)
    by = np.empty(4)
    bz = np.empty(4)
    left = np.empty(4)
    right = np.empty(4)
    px, py, pz = points[n, 0], points[n, 1], points[n, 2]
    i, _ = _locate(px, lo[0], inv_d[0], nx)
    j, _ = _locate(py, lo[1], inv_d[1], ny)
    k, _ = _locate(pz, lo[2], inv_d[2], nz)
    sxn, syn, szn = spanx[i], spany[j], spanz[k]
    _basis3(tx, sxn, px, bx, left, right)
    _basis3(ty, syn, py, by, left, right)
    _basis3(tz, szn, pz, bz, left, right)
    for c in range(ncomp):
        out[n, c] = 0.0
    for a in range(4):
        ia = sxn - 3 + a
        for b in range(4):
            jb = syn - 3 + b
            wab = bx[a] * by[b]
            for cc in range(4):
                kc = szn - 3 + cc
                wgt = wab * bz[cc]
                for c in range(ncomp):
                    out[n, c] += wgt * coef[ia, jb, kc, c]


def expanded_uncertainty_um(
    gu: GridUncertainty,
    coef: FloatArray,
    tables: tuple[Any, ...],
    points_mm: FloatArray,
    stylus_mm: FloatArray,
    temps_C: Mapping[str, Any] | None,
    ok: NDArray[np.bool_],
) -> FloatArray:
    """U (N, 3) µm, k = ``gu.coverage_factor``, of points whose status is ok (NaN elsewhere).

    ``coef`` the spline coefficients (:meth:`GridUncertainty.coefficients`), ``tables`` the
    grid's ``(lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz)``; ``stylus_mm`` (1 or N, 3);
    ``temps_C`` temperatures by role (scalars or (N,) arrays; only the roles U depends on,
    :attr:`GridUncertainty.active_roles`, are read). One compiled pass, parallel from
    :data:`PARALLEL_MIN` points (a small batch, e.g. a daemon's wake-up, is not worth waking
    a thread pool: :func:`_u_rows_serial`); :func:`variance_from_covariance` and
    :meth:`ThermalUncertainty.variance_um2` are the same mathematics in numpy."""
    n = points_mm.shape[0]
    out = np.full((n, 3), np.nan)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return out
    lo, inv_d, shape, tx, ty, tz, sx, sy, sz = tables
    pts = np.ascontiguousarray(points_mm[idx])
    sty = np.ascontiguousarray(stylus_mm if stylus_mm.shape[0] == 1 else stylus_mm[idx])
    ref_c = float(gu.thermal_vector[0])
    scalars = [0.0, 0.0, 0.0, 0.0]  # ΔT of T_x, T_y, T_z, T_wp; 0 = reference or not used
    columns: dict[int, FloatArray] = {}
    for k, name in gu.active_roles:
        value = (temps_C or {}).get(name)
        if value is None:
            continue
        arr = np.asarray(value, dtype=np.float64)
        if arr.ndim == 0:
            scalars[k] = float(arr) - ref_c
        else:
            columns[k] = arr[idx] - ref_c
    d_t = np.empty((idx.size if columns else 1, 4))  # one row: the same for every point
    d_t[:] = scalars
    for k, col in columns.items():
        d_t[:, k] = col
    u = np.empty((idx.size, 3))
    rows_fn = _u_rows if idx.size >= PARALLEL_MIN else _u_rows_serial
    rows_fn(pts, sty, d_t, lo, inv_d, shape, tx, ty, tz, sx, sy, sz, coef, gu.thermal_vector, u)
    out[idx] = u
    return out


class PointUncertainty:
    """U of one reading whose status is ok, the single-reading path (the daemon's): the
    buffers and the compiled kernel's arguments are prepared once, so a reading costs one
    compiled call plus the few temperatures U depends on. Not thread-safe: the grid calls it
    under its lock. Same mathematics as :func:`expanded_uncertainty_um` (equal bit for bit)."""

    def __init__(self, gu: GridUncertainty, coef: FloatArray, tables: tuple[Any, ...]) -> None:
        self._flat = np.zeros(10)  # point (3), stylus (3), ΔT of T_x, T_y, T_z, T_wp
        self._out = np.zeros((1, 3))
        self._roles = tuple((k, name, float(gu.thermal_vector[0])) for k, name in gu.active_roles)
        lo, inv_d, shape, tx, ty, tz, sx, sy, sz = tables
        f = self._flat
        self._args = (
            f[0:3].reshape(1, 3),
            f[3:6].reshape(1, 3),
            f[6:10].reshape(1, 4),
            lo,
            inv_d,
            shape,
            tx,
            ty,
            tz,
            sx,
            sy,
            sz,
            coef,
            gu.thermal_vector,
            np.zeros((1, coef.shape[3])),
            self._out,
        )  # fmt: skip (views of one buffer: one assignment fills them)

    def __call__(
        self,
        point: tuple[float, float, float],
        stylus: tuple[float, float, float],
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
    ) -> tuple[float, float, float]:
        """(Ux, Uy, Uz) µm at ``point`` (mm, inside the volume) and ``stylus`` (mm); a
        temperature is read from ``temps_C``, else from ``inputs``, as the correction reads it
        (a role absent from both counts as the reference)."""
        d_t = [0.0, 0.0, 0.0, 0.0]
        for k, name, ref_c in self._roles:
            value = None if temps_C is None else temps_C.get(name)
            if value is None and inputs is not None:
                value = inputs.get(name)
            if value is not None:
                d_t[k] = float(value) - ref_c
        self._flat[:] = (*point, *stylus, *d_t)
        _point_kernel(*self._args)
        o = self._out
        return float(o[0, 0]), float(o[0, 1]), float(o[0, 2])


@njit_cached()
def _u_row(
    n, points, stylus, d_t, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, th, cov, out
):  # type: ignore[no-untyped-def]
    """U of point n: spline of the covariance entries into ``cov[n]``, the stylus rule, the
    thermal terms (``th`` = :attr:`GridUncertainty.thermal_vector`; ``d_t`` rows of
    ΔT_x, ΔT_y, ΔT_z, ΔT_wp, one row or one per point), probing σ², coverage factor."""
    _spline_row(n, points, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, cov)
    c = cov[n]
    row = np.int64(n)  # a prange index is unsigned: int64 | uint64 would unify to float64
    zero = np.int64(0)
    si = row if stylus.shape[0] > 1 else zero
    px, py, pz = stylus[si, 0], stylus[si, 1], stylus[si, 2]
    v0 = (
        c[0]
        + 2e-3 * (pz * c[3] - py * c[4])
        + 1e-6 * (pz * pz * c[10] + py * py * c[11] - 2 * py * pz * c[14])
    )
    v1 = (
        c[1]
        + 2e-3 * (px * c[6] - pz * c[5])
        + 1e-6 * (px * px * c[11] + pz * pz * c[9] - 2 * px * pz * c[13])
    )
    v2 = (
        c[2]
        + 2e-3 * (py * c[7] - px * c[8])
        + 1e-6 * (py * py * c[9] + px * px * c[10] - 2 * px * py * c[12])
    )
    var = (max(v0, 0.0), max(v1, 0.0), max(v2, 0.0))
    r = row if d_t.shape[0] > 1 else zero
    a, ua, ut = th[13], th[14], th[15]
    dtw = d_t[r, 3]
    f = a * a * ut * ut + dtw * dtw * ua * ua + ua * ua * ut * ut
    for k in range(3):
        a, ua, ut = th[4 + k], th[7 + k], th[10 + k]
        dt = d_t[r, k]
        lever = (points[n, k] - th[1 + k]) / 1000.0
        lever_wp = (points[n, k] - th[16 + k]) / 1000.0
        vk = var[k] + (a * a * ut * ut + dt * dt * ua * ua + ua * ua * ut * ut) * lever * lever
        out[n, k] = th[20] * math.sqrt(vk + f * lever_wp * lever_wp + th[19])


@njit_cached(parallel=True)
def _u_rows(points, stylus, d_t, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, th, out):  # type: ignore[no-untyped-def]
    cov = np.empty((points.shape[0], coef.shape[3]))
    for n in prange(points.shape[0]):
        _u_row(
            n,
            points,
            stylus,
            d_t,
            lo,
            inv_d,
            shape,
            tx,
            ty,
            tz,
            spanx,
            spany,
            spanz,
            coef,
            th,
            cov,
            out,
        )


@njit_cached()
def _u_rows_serial(
    points, stylus, d_t, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, th, out
):  # type: ignore[no-untyped-def]
    """:func:`_u_rows` without threads (a small batch: no thread-pool wake-up)."""
    cov = np.empty((points.shape[0], coef.shape[3]))
    for n in range(points.shape[0]):
        _u_row(
            n, points, stylus, d_t, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, th,
            cov, out,
        )  # fmt: skip


@njit_cached()
def _point_kernel(
    point, stylus, d_t, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, th, cov, out
):  # type: ignore[no-untyped-def]
    _u_row(
        0, point, stylus, d_t, lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz, coef, th, cov, out
    )
