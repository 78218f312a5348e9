"""Residuals of a machine model against verification measurements, and their statistics.

residual = observed error − predicted error (µm), per point and axis, where the observed error is
``(ref − indicated)·1000`` and the prediction is :meth:`Machine.volumetric_error` at the point's
stylus offset, temperatures, directions and probing direction. :class:`Residuals` also holds the
first-order Jacobian of the chain at every point (the Abbe arms a parametric perturbation acts
through), which the candidate causes use so that fit and forward model agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..formats.measurements import Measurements
from ..kinematics import first_order_jacobian
from ..machine import Machine
from ..thermal.roles import TEMPERATURE_ROLES
from .reading import denoised_reading

FloatArray = NDArray[np.float64]
#: a larger |residual| is no machine error (a wrong value or unit): refused, not averaged
MAX_RESIDUAL_UM = 1e9


def rms3d(r_um: FloatArray) -> float:
    """3-D RMS (µm): square root of the mean over points of the squared residual length."""
    r = np.asarray(r_um, dtype=float)
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")


@dataclass
class Residuals:
    """Model residuals at N points with everything a candidate cause needs to fit them."""

    machine: Machine
    data: Measurements
    stylus_mm: FloatArray  # (N, 3)
    signals: dict[str, FloatArray]  # temperatures (filled with the reference) and inputs
    predicted_um: FloatArray  # (N, 3)
    residual_um: FloatArray  # (N, 3)
    jacobian: FloatArray  # (N, 3 out, 3 axes, 6)
    squareness_jacobian: FloatArray  # (N, 3 out, 3)
    #: (N, 3) the reading as the coordinate of reading-locked terms: the distance the sensor
    #: looked at (:mod:`.reading`); None: the raw reading
    reading_mm: FloatArray | None = None

    @property
    def n(self) -> int:
        return self.data.n

    @property
    def q_mm(self) -> FloatArray:
        return self.data.indicated_mm

    @property
    def u_mm(self) -> FloatArray:
        return self.data.indicated_mm - self.machine.volume.reference_mm

    def has(self, *names: str) -> bool:
        """Whether the measurements carry every signal in ``names`` (not just the default)."""
        given = set(self.data.temps_C) | set(self.data.inputs()) | set(self.data.velocities)
        return all(n in given for n in names)

    @property
    def ref_mm(self) -> FloatArray:
        """(N, 3) the reference instrument's reading in the machine frame (mm), as the
        coordinate of terms locked to it: ``reading_mm`` where it is set (a stream: the distance
        the sensor looked at, :mod:`.reading`); the observed error always uses the raw reading."""
        return self.data.reference_mm if self.reading_mm is None else self.reading_mm

    def subset(self, index: Any) -> Residuals:
        return Residuals(
            machine=self.machine,
            data=self.data.subset(index),
            stylus_mm=self.stylus_mm[index],
            signals={k: v[index] for k, v in self.signals.items()},
            predicted_um=self.predicted_um[index],
            residual_um=self.residual_um[index],
            jacobian=self.jacobian[index],
            squareness_jacobian=self.squareness_jacobian[index],
            reading_mm=None if self.reading_mm is None else self.reading_mm[index],
        )


def compute_residuals(machine: Machine, data: Measurements) -> Residuals:
    """Residuals of ``machine`` against ``data`` (see module docstring)."""
    stylus = data.stylus(machine.probe.offset_mm.tolist())
    predicted = machine.volumetric_error(
        data.indicated_mm, stylus, data.temps_C, inputs=data.inputs()
    )
    ref_c = machine.thermal.reference_C
    signals: dict[str, FloatArray] = {k: np.full(data.n, ref_c) for k in TEMPERATURE_ROLES}
    signals.update(data.temps_C)
    signals.update(data.inputs())
    signals.update(data.velocities)  # diagnosis only: a latency acts through them
    jac, sq = first_order_jacobian(
        machine.chain, data.indicated_mm - machine.volume.reference_mm, stylus
    )
    residual = data.observed_error_um() - predicted
    with np.errstate(invalid="ignore"):
        bad = ~np.all(np.abs(residual) <= MAX_RESIDUAL_UM, axis=1)
    if bad.any():  # its square overflows: every RMS was inf, diagnosis.json held NaN
        i = int(np.argmax(bad))
        raise ValueError(
            f"data row {i + 1}: observed − modelled error "
            f"{residual[i].tolist()} µm is not a finite error within ±{MAX_RESIDUAL_UM:g} µm "
            "(check its reference and indicated positions, mm, and temperatures)"
        )
    return Residuals(
        machine=machine,
        data=data,
        stylus_mm=stylus,
        signals=signals,
        predicted_um=predicted,
        residual_um=residual,
        jacobian=jac,
        squareness_jacobian=sq,
        reading_mm=denoised_reading(data),
    )


# ----------------------------------------------------------------------------- statistics
def axis_statistics(r_um: FloatArray) -> dict[str, dict[str, float]]:
    """Per axis: mean, standard deviation, RMS and max |r| (µm); plus the 3-D RMS."""
    r = np.asarray(r_um, dtype=float)
    out: dict[str, dict[str, float]] = {}
    for k, a in enumerate("xyz"):
        c = r[:, k]
        out[a] = {
            "mean_um": float(np.mean(c)),
            "std_um": float(np.std(c, ddof=1)) if len(c) > 1 else 0.0,
            "rms_um": float(np.sqrt(np.mean(c**2))),
            "max_abs_um": float(np.max(np.abs(c))),
        }
    out["3d"] = {"rms_um": rms3d(r)}
    return out


def explanatory_variables(res: Residuals) -> dict[str, FloatArray]:
    """What residuals are shown against: positions, time, temperatures, directions, azimuth."""
    d = res.data
    out: dict[str, FloatArray] = {
        f"position {a} (mm)": d.indicated_mm[:, k] for k, a in enumerate("xyz")
    }
    if d.t_s is not None:
        out["time (s)"] = d.t_s
    for name, v in d.temps_C.items():
        out[f"{name} (°C)"] = v
    if "T_top" in d.temps_C and "T_bottom" in d.temps_C:
        out["T_top − T_bottom (°C)"] = d.temps_C["T_top"] - d.temps_C["T_bottom"]
    for name, v in d.directions.items():
        out[name] = v
    if d.normals is not None:
        out["probing azimuth (deg)"] = np.degrees(np.arctan2(d.normals[:, 1], d.normals[:, 0]))
    return out


def binned_statistics(x: FloatArray, r_um: FloatArray, bins: int = 8) -> dict[str, list[float]]:
    """Mean residual per axis in up to ``bins`` equal-count bins of ``x`` (±1 variables: 2
    bins). A bin left empty by tied values (a quantised temperature: its quantiles repeat) is
    not listed: it has no centre or mean (was NaN, written into diagnosis.json)."""
    x = np.asarray(x, dtype=float)
    levels = np.unique(x)
    if len(levels) <= 2:
        edges_idx = [x == v for v in levels]
    else:
        qs = np.quantile(x, np.linspace(0, 1, bins + 1))
        which = np.clip(np.searchsorted(qs, x, side="right") - 1, 0, bins - 1)
        edges_idx = [m for m in (which == b for b in range(bins)) if m.any()]
    out: dict[str, list[float]] = {
        "centre": [float(np.mean(x[m])) for m in edges_idx],
        "count": [int(m.sum()) for m in edges_idx],
    }
    for k, a in enumerate("xyz"):
        out[f"mean_{a}_um"] = [float(np.mean(r_um[m, k])) for m in edges_idx]
    return out


def length_error_e0_um(
    reference_mm: FloatArray,
    residual_um: FloatArray,
    group: NDArray[np.str_] | None,
    max_points: int = 600,
) -> float:
    """ISO 10360-2-style E0 estimate (µm): max |length error| over point pairs of one artefact.

    For points i, j of the same group (artefact position), the length error of the corrected
    coordinates is ``(r_j − r_i)·(p_j − p_i)/|p_j − p_i|`` with r the residual (true − corrected)
    and p the reference positions; pairs closer than 1 mm are skipped. Without groups, blocks of
    30 consecutive points stand in for artefact positions. A group of more than ``max_points``
    points (a dense record) is thinned to ``max_points`` evenly spaced ones (pairs grow as N²).
    """
    n = len(reference_mm)
    labels = group if group is not None else np.asarray([str(i // 30) for i in range(n)])
    worst = 0.0
    for g in np.unique(labels):
        idx = np.flatnonzero(labels == g)
        if len(idx) > max_points:
            idx = idx[np.linspace(0, len(idx) - 1, max_points).round().astype(int)]
        p = reference_mm[idx]
        r = residual_um[idx]
        dp = p[None, :, :] - p[:, None, :]
        length = np.linalg.norm(dp, axis=2)
        mask = length > 1.0
        if not mask.any():
            continue
        dr = r[None, :, :] - r[:, None, :]
        err = np.einsum("ijk,ijk->ij", dr, dp)[mask] / length[mask]
        worst = max(worst, float(np.max(np.abs(err))))
    return worst
