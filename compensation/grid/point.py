"""The single-reading path of a grid (the daemon's): one indicated point, scalars throughout,
the compiled kernel on preallocated buffers under a lock, and U of the same reading
(:class:`.uncertainty.PointUncertainty`). Same status rule as the batch path
(:data:`.status.STATUS_BY_FLAGS`); equal to it bit for bit.

Positions mm, U µm (k = 2 per component).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import kernels as kern
from .inputs import GridSignal
from .status import (
    INVALID,
    MISSING_INPUT,
    NO_TEMPERATURE,
    OUTSIDE,
    REFUSED_STATUSES,
    STATUS_BY_FLAGS,
    VOLUME_TOL_MM,
)
from .uncertainty import GridUncertainty, PointUncertainty

__all__ = ["NAN3", "PointCorrector"]

FloatArray = NDArray[np.float64]
Vec3 = tuple[float, float, float]
NAN3: Vec3 = (math.nan, math.nan, math.nan)


class PointCorrector:
    """One reading at a time with one grid's kernel tables (:class:`.kernels.KernelTables`),
    volume ``lower_mm`` … ``upper_mm`` and ``signals``, and the grid's U (None: none).

    The buffers are preallocated and shared, so a call holds a lock: safe from any thread, but
    serialised. ~10 µs per reading after the grid's warm-up (``benchmarks/bench_grid.py``)."""

    def __init__(
        self,
        tables: kern.KernelTables,
        lower_mm: FloatArray,
        upper_mm: FloatArray,
        signals: Sequence[GridSignal],
        uncertainty: tuple[GridUncertainty, FloatArray] | None = None,
    ) -> None:
        self._tables = tables
        self._args = tables.args()
        self._lo = lower_mm.tolist()
        self._hi = upper_mm.tolist()
        self._signals = tuple(signals)
        self._point = np.zeros((1, 3))
        self._stylus = np.zeros((1, 3))
        self._dev = np.zeros((1, len(self._signals)))  # columns not needed stay 0.0 forever
        self._outputs = (np.zeros((1, 3)), np.zeros((1, 4)), np.zeros((1, 3)))
        #: (column, name, reference, is_temperature) of the signals a correction reads
        self._needed = tuple(
            (k, sig.name, float(sig.reference), sig.is_temperature)
            for k, sig in enumerate(self._signals)
            if sig.needed
        )
        self._ncomp_all = 3 + 6 * len(self._signals)
        self._uncertainty = uncertainty
        self._lock = threading.Lock()
        self._u_point: PointUncertainty | None = None  # prepared on first use (not pickled)

    def with_uncertainty(
        self, uncertainty: GridUncertainty | None, coefficients: FloatArray | None
    ) -> PointCorrector:
        """The same path for a grid carrying ``uncertainty`` (its spline ``coefficients``)."""
        u = None if uncertainty is None or coefficients is None else (uncertainty, coefficients)
        lo, hi = np.array(self._lo), np.array(self._hi)
        return PointCorrector(self._tables, lo, hi, self._signals, u)

    def correct(
        self,
        point_mm: ArrayLike,
        stylus_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
        refuse: bool,
    ) -> tuple[Vec3, str]:
        """``((cx, cy, cz) mm, status)`` of one indicated point for one stylus offset (mm); a
        signal is read from ``temps_C`` first, else from ``inputs`` (scalars); ``refuse``:
        policy ``"refuse"`` rather than ``"clamp"``."""
        by_flags = STATUS_BY_FLAGS[refuse]
        x, y, z = map(float, point_mm)  # type: ignore[arg-type, call-overload, unused-ignore]
        px, py, pz = map(float, stylus_mm)  # type: ignore[arg-type, call-overload, unused-ignore]
        isfinite = math.isfinite
        if not (
            isfinite(x)
            and isfinite(y)
            and isfinite(z)
            and isfinite(px)
            and isfinite(py)
            and isfinite(pz)
        ):
            return NAN3, by_flags[INVALID]  # nothing to evaluate at
        lo, hi = self._lo, self._hi
        cx = min(max(x, lo[0]), hi[0])
        cy = min(max(y, lo[1]), hi[1])
        cz = min(max(z, lo[2]), hi[2])
        flags = (
            OUTSIDE
            if (
                abs(cx - x) > VOLUME_TOL_MM
                or abs(cy - y) > VOLUME_TOL_MM
                or abs(cz - z) > VOLUME_TOL_MM
            )
            else 0
        )
        # a refusal depends on the geometric flags only (.status): stop before the signals
        if flags and by_flags[flags] in REFUSED_STATUSES:
            return NAN3, by_flags[flags]
        with self._lock:
            row = self._dev[0]
            active = False
            for k, name, reference, is_temperature in self._needed:
                value = None
                if temps_C is not None:
                    value = temps_C.get(name)
                if value is None and inputs is not None:
                    value = inputs.get(name)
                v = math.nan if value is None else float(value)
                if not isfinite(v):
                    row[k] = 0.0
                    flags |= NO_TEMPERATURE if is_temperature else MISSING_INPUT
                    continue
                row[k] = v - reference
                active = active or v != reference
            p1, s1, o1 = self._point, self._stylus, self._outputs[0]
            p1[0, 0], p1[0, 1], p1[0, 2] = cx, cy, cz
            s1[0, 0], s1[0, 1], s1[0, 2] = px, py, pz
            ncomp = self._ncomp_all if active else 3
            kern.eval_serial(self._args, p1, s1, self._dev, self._outputs, ncomp, False)
            out = (
                float(o1[0, 0]) + (x - cx),
                float(o1[0, 1]) + (y - cy),
                float(o1[0, 2]) + (z - cz),
            )
        if flags:
            status = by_flags[flags]
            if status in REFUSED_STATUSES:
                return NAN3, status
            return out, status
        return out, by_flags[0]

    def correct_with_uncertainty(
        self,
        point_mm: ArrayLike,
        stylus_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
        refuse: bool,
    ) -> tuple[Vec3, str, Vec3]:
        """:meth:`correct` and U ``(Ux, Uy, Uz)`` µm of the reading: NaN when the status is
        not ``ok`` or the grid carries no U."""
        out, status = self.correct(point_mm, stylus_mm, temps_C, inputs, refuse)
        if status != "ok" or self._uncertainty is None:
            return out, status, NAN3
        x, y, z = map(float, point_mm)  # type: ignore[arg-type, call-overload, unused-ignore]
        px, py, pz = map(float, stylus_mm)  # type: ignore[arg-type, call-overload, unused-ignore]
        lo, hi = self._lo, self._hi  # "ok" is within VOLUME_TOL_MM: clamp as the correction
        x, y, z = min(max(x, lo[0]), hi[0]), min(max(y, lo[1]), hi[1]), min(max(z, lo[2]), hi[2])
        with self._lock:
            point_u = self._u_point
            if point_u is None:
                gu, coef = self._uncertainty
                point_u = self._u_point = PointUncertainty(gu, coef, self._args[0])
            return out, status, point_u((x, y, z), (px, py, pz), temps_C, inputs)

    def __getstate__(self) -> dict[str, Any]:
        """Picklable (a daemon builds a grid in a worker process): the lock and the U buffers
        are not sent (views of their own buffers: rebuilt where they are used)."""
        state = dict(self.__dict__)
        state.pop("_lock", None)
        state.pop("_u_point", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()
        self._u_point = None
