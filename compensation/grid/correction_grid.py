"""The correction grid: exact error poses at the nodes of the working volume, interpolated.

At every node the grid stores the machine's error pose (seed paper, Hermann §6): the error
rotation ``R_work_stylus`` as a unit quaternion (w, x, y, z), sign-continuous between
neighbours, and the translation (µm) at stylus offset 0. Between nodes

* rotations are interpolated by **Squad**, tensor-product: along x on the 4×4 neighbouring
  node lines (control points precomputed at the nodes), then along y on the 4 results, then
  along z (control points computed from the interpolated neighbours); at the edges of the
  volume the ``"quadratic"`` boundary rule of :mod:`.squad` (a parabola through
  the last three nodes sets the end control point: third-order accurate like the interior,
  where ``s_0 = q_0`` would be second-order only);
* translations by a **C² tricubic B-spline** (not-a-knot, the tensor product of
  ``scipy.interpolate.make_interp_spline`` along each axis) that interpolates the nodes.

Runtime signals (temperatures ``T_x`` …, ``dir_x`` … as listed by
``machine.runtime_signals()``) enter through per-signal **sensitivity grids**: at every node the
change of translation (µm) and of rotation vector (µrad) per unit of the signal, measured on
the machine by a central difference about the reference (±1 unit). The model's signal effects
are linear (thermal expansion is exactly linear in ΔT; bending to first order), so the
pose at signal values ``v`` is ``R = exp(Σ Δv_s ω_s) · R_0``, ``t = t_0 + Σ Δv_s t_s`` with
``Δv = v − reference``; the build records the measured departure from linearity.

Correction for stylus offset ``p`` (mm): ``corrected = indicated + t/1000 + (R − I)·p``, mm.
Error convention true − indicated, so corrected = indicated + error (docs/formats.md).

Status of each corrected point: the rule of :mod:`.status` (``"ok"``, ``"missing_input"``,
``"no_temperature"``, ``"clamped_outside_volume"``, ``"outside_volume"``, ``"invalid_input"``),
the same for the batch path (:meth:`CorrectionGrid.correct`) and the single-reading path
(:meth:`CorrectionGrid.correct_point`). Building is in :mod:`.build`, the file in :mod:`.file`,
the signals in :mod:`.inputs`, the compiled kernels in :mod:`.kernels`.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..thermal.lag import SignalFilter
from . import kernels as kern
from .build import MachineLike, build_from_machine, check_steps, grid_from_poses
from .file import GridContents, grid_header, load_grid, save_grid
from .inputs import GridSignal, derive_lobing_inputs, lobing_orders, signal_deviations
from .interpolation import interpolation_tables, make_grid_continuous
from .inverse import command_for_target
from .status import (
    INVALID,
    MISSING_INPUT,
    NO_TEMPERATURE,
    OUTSIDE,
    REFUSED_STATUSES,
    STATUS_BY_FLAGS,
    STATUS_DTYPE,
    VOLUME_TOL_MM,
    check_policy,
    statuses,
)
from .uncertainty import GridUncertainty, PointUncertainty, expanded_uncertainty_um

__all__ = ["CorrectionGrid"]

FloatArray = NDArray[np.float64]
ProgressFn = Callable[[float, str], None]
_WARM = {"done": False}
_NAN3 = (math.nan, math.nan, math.nan)
_MAX_UM = 1e9  # largest |translation| µm (1 km) and |sensitivity| per signal unit of a grid


class CorrectionGrid:
    """Error poses at the nodes of a regular grid over the working volume, and their
    interpolation (Squad for rotations, C² cubic spline for translations).

    Construct with :meth:`build` (from a machine model), :meth:`from_poses` (from measured
    node poses, e.g. :mod:`compensation.reports.sixdof`) or :meth:`load`. Quaternions (w, x, y, z).
    """

    def __init__(
        self,
        lower_mm: ArrayLike,
        upper_mm: ArrayLike,
        q_work_stylus: ArrayLike,
        translation_um: ArrayLike,
        signals: Sequence[GridSignal] = (),
        sensitivity_translation_um: ArrayLike | None = None,
        sensitivity_rotation_urad: ArrayLike | None = None,
        metadata: Mapping[str, Any] | None = None,
        outside: str = "refuse",
        uncertainty: GridUncertainty | None = None,
    ) -> None:
        lo = np.asarray(lower_mm, dtype=np.float64).reshape(3)
        hi = np.asarray(upper_mm, dtype=np.float64).reshape(3)
        q = np.asarray(q_work_stylus, dtype=np.float64)
        t = np.asarray(translation_um, dtype=np.float64)
        if q.ndim != 4 or q.shape[-1] != 4:
            raise ValueError(f"q_work_stylus must be (nx, ny, nz, 4), got {q.shape}")
        steps = check_steps(q.shape[:3])
        if t.shape != (*steps, 3):
            raise ValueError(f"translation_um must be {(*steps, 3)}, got {t.shape}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise ValueError(f"volume axes must increase: lower {lo.tolist()}, upper {hi.tolist()}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
            raise ValueError("node quaternions and translations must be finite")
        if np.abs(t).max() > _MAX_UM:  # 1e300 µm gave corrected coordinates of 1e297 mm
            raise ValueError(
                f"node translations reach {np.abs(t).max():g} µm, beyond ±{_MAX_UM:g} µm: no "
                "machine error (check the model's tables and effects)"
            )
        norm_dev = np.abs(np.linalg.norm(q, axis=-1) - 1.0).max()
        if norm_dev > 1e-9:
            raise ValueError(f"node quaternions must be unit (largest |‖q‖ − 1| = {norm_dev:.3g})")
        sigs = list(signals)
        n_sig = len(sigs)
        st = np.zeros((n_sig, *steps, 3))
        sr = np.zeros((n_sig, *steps, 3))
        if n_sig:
            if sensitivity_translation_um is None or sensitivity_rotation_urad is None:
                raise ValueError("signals given without sensitivity grids")
            st = np.asarray(sensitivity_translation_um, dtype=np.float64)
            sr = np.asarray(sensitivity_rotation_urad, dtype=np.float64)
            for name, arr in (("translation", st), ("rotation", sr)):
                if arr.shape != (n_sig, *steps, 3):
                    raise ValueError(
                        f"sensitivity_{name} must be {(n_sig, *steps, 3)}, got {arr.shape}"
                    )
                if not np.all(np.isfinite(arr)):
                    raise ValueError(f"sensitivity_{name} grid must be finite")
                if np.abs(arr).max(initial=0.0) > _MAX_UM:
                    raise ValueError(
                        f"sensitivity_{name} reaches {np.abs(arr).max():g} per unit of a signal, "
                        f"beyond ±{_MAX_UM:g}: no machine error"
                    )
        self.outside = check_policy(outside)
        self.lower_mm = lo
        self.upper_mm = hi
        self.steps = steps
        self.axes = tuple(np.linspace(lo[k], hi[k], steps[k]) for k in range(3))
        self.q_work_stylus = make_grid_continuous(q / np.linalg.norm(q, axis=-1, keepdims=True))
        self.translation_um = t
        self.signals = tuple(sigs)
        self.sensitivity_translation_um = st
        self.sensitivity_rotation_urad = sr
        self.metadata: dict[str, Any] = dict(metadata or {})
        # the header form (list of dicts) stays in the metadata; the typed form is read once
        self._signal_filters = tuple(
            SignalFilter.from_header(f) for f in self.metadata.get("signal_filters", [])
        )
        self.sha256: str | None = None
        self.uncertainty: GridUncertainty | None = None
        self._u_point: PointUncertainty | None = None  # prepared on first use (not pickled)
        if uncertainty is not None:
            self._set_uncertainty(uncertainty)
        self._prepare()

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(
        cls,
        machine: MachineLike,
        steps: Sequence[int] | None = None,
        progress: ProgressFn | None = None,
        outside: str = "refuse",
    ) -> CorrectionGrid:
        """Evaluate ``machine`` exactly at every node of its working volume (see
        :func:`.build.build_from_machine`: default steps, sensitivity grids per signal)."""
        return build_from_machine(cls, machine, steps, progress, outside)

    @classmethod
    def from_poses(
        cls,
        axes_mm: Sequence[ArrayLike],
        q_work_stylus: ArrayLike,
        translation_um: ArrayLike,
        *,
        machine_name: str = "measured",
        machine_model: str = "unknown",
        source_sha256: str = "",
        signals: Sequence[GridSignal] = (),
        sensitivity_translation_um: ArrayLike | None = None,
        sensitivity_rotation_urad: ArrayLike | None = None,
        outside: str = "refuse",
    ) -> CorrectionGrid:
        """Grid from measured node poses (see :func:`.build.grid_from_poses`): ``axes_mm`` three
        equally spaced node arrays (mm), quaternions (nx, ny, nz, 4) (w, x, y, z), translations
        (nx, ny, nz, 3) µm at stylus offset 0."""
        return grid_from_poses(
            cls,
            axes_mm,
            q_work_stylus,
            translation_um,
            machine_name=machine_name,
            machine_model=machine_model,
            source_sha256=source_sha256,
            signals=signals,
            sensitivity_translation_um=sensitivity_translation_um,
            sensitivity_rotation_urad=sensitivity_rotation_urad,
            outside=outside,
        )

    def _prepare(self) -> None:
        """Precompute Squad control data along x and the tensor spline coefficients."""
        t = interpolation_tables(
            self.q_work_stylus,
            self.translation_um,
            self.sensitivity_translation_um,
            self.sensitivity_rotation_urad,
            self.axes,
        )
        self._tables = t
        self._args = t.args()
        self._small = t.small
        self._needed = np.array([s.needed for s in self.signals], dtype=bool)
        self._derived_lobes = lobing_orders(self.signals)
        self._lo_list = self.lower_mm.tolist()
        self._hi_list = self.upper_mm.tolist()
        self._p1 = np.zeros((1, 3))
        self._s1 = np.zeros((1, 3))
        self._o1 = np.zeros((1, 3))
        self._d1 = np.zeros((1, len(self.signals)))
        # correct_point's view of the signals it reads: (column, name, reference, is_temperature)
        self._needed_signals = tuple(
            (k, sig.name, float(sig.reference), sig.is_temperature)
            for k, sig in enumerate(self.signals)
            if sig.needed
        )
        self._ncomp_all = 3 + 6 * len(self.signals)
        self._lock = threading.Lock()
        self._dummy_q = np.zeros((1, 4))
        self._dummy_t = np.zeros((1, 3))
        self._outputs1 = (self._o1, self._dummy_q, self._dummy_t)
        if not _WARM["done"]:  # compile or load the cached kernels now, not on first use
            p = np.array([0.5 * (self.lower_mm + self.upper_mm)])
            self._run(p, np.zeros((1, 3)), np.zeros((1, len(self.signals))), 3, parallel=False)
            self._run(
                np.repeat(p, 4, 0),
                np.zeros((1, 3)),
                np.zeros((4, len(self.signals))),
                3,
                parallel=True,
            )
            _WARM["done"] = True

    # ------------------------------------------------------------------ evaluation
    def _run(
        self,
        points: FloatArray,
        stylus: FloatArray,
        dev: FloatArray,
        ncomp: int,
        parallel: bool,
        want_pose: bool = False,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        n = points.shape[0]
        out = np.empty((n, 3))
        out_q = np.empty((n, 4)) if want_pose else self._dummy_q
        out_t = np.empty((n, 3)) if want_pose else self._dummy_t
        outputs = (out, out_q, out_t)
        if parallel:
            threads = max(1, (os.cpu_count() or 1))
            chunk = max(512, math.ceil(n / (8 * threads)))
            kern.eval_parallel(self._args, points, stylus, dev, outputs, ncomp, want_pose, chunk)
        else:
            kern.eval_serial(self._args, points, stylus, dev, outputs, ncomp, want_pose)
        return out, out_q, out_t

    def _evaluate(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
        outside: str | None,
        want_pose: bool,
    ) -> tuple[FloatArray, NDArray[np.str_], FloatArray, FloatArray]:
        pts = np.asarray(points_mm, dtype=np.float64)
        if pts.ndim == 1 and pts.shape[0] == 3:
            pts = pts[None, :]
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points_mm must be an (N, 3) array of mm, got shape {pts.shape}")
        n = pts.shape[0]
        stylus = np.asarray(stylus_mm, dtype=np.float64)
        stylus = stylus.reshape(1, 3) if stylus.shape == (3,) else stylus
        if stylus.ndim != 2 or stylus.shape[1] != 3 or stylus.shape[0] not in (1, n):
            raise ValueError(f"stylus_mm must be (3,) or ({n}, 3) mm, got shape {stylus.shape}")
        refuse = check_policy(self.outside if outside is None else outside) == "refuse"
        bad = ~np.isfinite(pts).all(axis=1)
        sty_bad = ~np.isfinite(stylus).all(axis=1)
        bad = bad | np.broadcast_to(sty_bad, (n,))
        clamped = np.clip(pts, self.lower_mm, self.upper_mm)
        outside_mask = np.any(np.abs(clamped - pts) > VOLUME_TOL_MM, axis=1) & ~bad
        if bad.any():
            clamped[bad] = self.lower_mm
            stylus = np.where(np.isfinite(stylus), stylus, 0.0)
        dev, no_temp, no_input = signal_deviations(self.signals, n, temps_C, inputs)
        ncomp = 3 + 6 * len(self.signals) if (dev.size and np.any(dev != 0.0)) else 3
        out, q, t = self._run(
            clamped,
            np.ascontiguousarray(stylus),
            dev,
            ncomp,
            parallel=n >= 256,
            want_pose=want_pose,
        )
        if outside_mask.any():
            out[outside_mask] += pts[outside_mask] - clamped[outside_mask]
        flags = (
            np.where(bad, INVALID, 0)
            | np.where(outside_mask, OUTSIDE, 0)
            | np.where(no_temp, NO_TEMPERATURE, 0)
            | np.where(no_input, MISSING_INPUT, 0)
        )
        status, refused_mask = statuses(flags, refuse)
        out[refused_mask] = np.nan
        return out, status, q, t

    def derive_inputs(self, inputs: Mapping[str, Any] | None) -> Mapping[str, Any] | None:
        """Add derived signals the grid needs and the caller cannot know: the probe-lobing
        signals ``lobe<n>_{c,s}_<axis>`` from the probing direction ``nx, ny, nz``
        (:func:`cmm_comp.compensation.effects.lobing_signals`). Anything given explicitly wins;
        without a probing direction nothing is derived and the point is flagged ``missing_input``."""
        return derive_lobing_inputs(self._derived_lobes, inputs)

    @overload
    def correct(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = ...,
        temps_C: Mapping[str, Any] | None = ...,
        inputs: Mapping[str, Any] | None = ...,
        *,
        outside: str | None = ...,
        with_uncertainty: Literal[False] = ...,
    ) -> tuple[FloatArray, NDArray[np.str_]]: ...

    @overload
    def correct(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = ...,
        temps_C: Mapping[str, Any] | None = ...,
        inputs: Mapping[str, Any] | None = ...,
        *,
        outside: str | None = ...,
        with_uncertainty: Literal[True],
    ) -> tuple[FloatArray, NDArray[np.str_], FloatArray]: ...

    def correct(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
        with_uncertainty: bool = False,
    ) -> Any:
        """Corrected positions (N, 3) mm and status (N,) str of indicated ``points_mm`` (N, 3).

        ``stylus_mm`` (3,) or (N, 3) mm; ``temps_C`` / ``inputs`` map signal names to scalars or
        (N,) arrays (either mapping may hold any signal). ``outside`` overrides the grid's
        policy (``"refuse"`` or ``"clamp"``). See the module docstring for the status values.

        ``with_uncertainty=True`` returns ``(corrected, status, U_um)``: U (N, 3) µm, expanded
        (k = 2) per component, of every point whose status is ``ok``; NaN elsewhere and
        everywhere when the grid carries no uncertainty (:attr:`has_uncertainty`).
        """
        if with_uncertainty:
            return self._correct_with_uncertainty(points_mm, stylus_mm, temps_C, inputs, outside)
        inputs = self.derive_inputs(inputs)
        pts = np.asarray(points_mm, dtype=np.float64)
        if pts.shape in ((3,), (1, 3)):
            fast = self._single(pts.reshape(3), stylus_mm, temps_C, inputs, outside)
            if fast is not None:
                return fast
        out, status, _, _ = self._evaluate(pts, stylus_mm, temps_C, inputs, outside, False)
        return out, status

    def _single(
        self,
        point: FloatArray,
        stylus_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
        outside: str | None,
    ) -> tuple[FloatArray, NDArray[np.str_]] | None:
        """``correct`` for one point through :meth:`correct_point` (None: use the general path)."""
        sty = np.asarray(stylus_mm, dtype=np.float64)
        if sty.size != 3:
            return None
        maps: list[dict[str, Any] | None] = []
        for m in (temps_C, inputs):
            if m is None:
                maps.append(None)
                continue
            conv: dict[str, Any] = {}
            for k, v in m.items():
                arr = np.asarray(v, dtype=np.float64) if v is not None else None
                if arr is not None and arr.size != 1:
                    return None
                conv[k] = None if arr is None else float(arr.reshape(()))
            maps.append(conv)
        if outside is not None:
            check_policy(outside)
        out, status = self.correct_point(point, sty.reshape(3), maps[0], maps[1], outside=outside)
        return np.array([out]), np.array([status], dtype=STATUS_DTYPE)

    def correct_point(
        self,
        point_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[tuple[float, float, float], str]:
        """Fast path for one reading: ``((cx, cy, cz) mm, status)``; same rules as :meth:`correct`.

        Scalars only (temperatures as floats); uses preallocated buffers under a lock, so
        it is safe but serialised across threads. ~10 µs per call after the grid's warm-up.
        """
        if self._derived_lobes:
            inputs = self.derive_inputs(inputs)
        by_flags = STATUS_BY_FLAGS[(outside or self.outside) == "refuse"]
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
            return _NAN3, by_flags[INVALID]  # nothing to evaluate at
        lo, hi = self._lo_list, self._hi_list
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
            return _NAN3, by_flags[flags]
        with self._lock:
            dev = self._d1
            row = dev[0]  # columns of signals not needed stay 0.0 forever
            active = False
            for k, name, reference, is_temperature in self._needed_signals:
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
            p1, s1, o1 = self._p1, self._s1, self._o1
            p1[0, 0], p1[0, 1], p1[0, 2] = cx, cy, cz
            s1[0, 0], s1[0, 1], s1[0, 2] = px, py, pz
            ncomp = self._ncomp_all if active else 3
            kern.eval_serial(self._args, p1, s1, dev, self._outputs1, ncomp, False)
            out = (
                float(o1[0, 0]) + (x - cx),
                float(o1[0, 1]) + (y - cy),
                float(o1[0, 2]) + (z - cz),
            )
        if flags:
            status = by_flags[flags]
            if status in REFUSED_STATUSES:
                return _NAN3, status
            return out, status
        return out, by_flags[0]

    # ------------------------------------------------------------------ uncertainty
    @property
    def has_uncertainty(self) -> bool:
        """Whether the grid carries U (built with ``grid build --uncertainty``)."""
        return self.uncertainty is not None

    def _set_uncertainty(self, gu: GridUncertainty) -> None:
        if gu.covariance.shape[:3] != tuple(self.steps):
            raise ValueError(
                f"uncertainty covariance has {gu.covariance.shape[:3]} nodes, the grid {self.steps}"
            )
        self.uncertainty = gu
        self._u_point = None
        gu.coefficients(self.axes)

    def with_uncertainty(self, uncertainty: GridUncertainty | None) -> CorrectionGrid:
        """A copy of this grid carrying ``uncertainty`` (None: without); not yet saved."""
        import copy

        out = copy.copy(self)
        out.uncertainty = None
        out._u_point = None
        out.sha256 = None
        if uncertainty is not None:
            out._set_uncertainty(uncertainty)
        return out

    def _u_tables(self) -> tuple[Any, ...]:
        return self._args[0]

    def _correct_with_uncertainty(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
        outside: str | None,
    ) -> tuple[FloatArray, NDArray[np.str_], FloatArray]:
        inputs = self.derive_inputs(inputs)
        pts = np.asarray(points_mm, dtype=np.float64)
        if pts.ndim == 1 and pts.shape[0] == 3:
            pts = pts[None, :]
        out, status, _, _ = self._evaluate(pts, stylus_mm, temps_C, inputs, outside, False)
        return out, status, self._expanded(pts, stylus_mm, temps_C, inputs, status)

    def _expanded(
        self,
        pts: FloatArray,
        stylus_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
        status: NDArray[np.str_],
    ) -> FloatArray:
        if self.uncertainty is None:
            return np.full((pts.shape[0], 3), np.nan)
        stylus = np.asarray(stylus_mm, dtype=np.float64).reshape(-1, 3)
        ok = status == "ok"
        temps = {k: v for k, v in (inputs or {}).items() if k.startswith("T_")}
        temps.update(temps_C or {})
        return expanded_uncertainty_um(
            self.uncertainty,
            self.uncertainty.coefficients(self.axes),
            self._u_tables(),
            np.clip(pts, self.lower_mm, self.upper_mm),  # rows not ok (NaN too) are not read
            stylus,
            temps,
            ok,
        )

    def uncertainty_um(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[FloatArray, NDArray[np.str_]]:
        """U (N, 3) µm (k = 2 per component) and status of indicated ``points_mm``: the
        uncertainty of what :meth:`correct` returns (NaN where the status is not ``ok`` or the
        grid carries no uncertainty)."""
        _, status, u = self._correct_with_uncertainty(
            points_mm, stylus_mm, temps_C, inputs, outside
        )
        return u, status

    def correct_point_with_uncertainty(
        self,
        point_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[tuple[float, float, float], str, tuple[float, float, float]]:
        """One reading: ``((cx, cy, cz) mm, status, (Ux, Uy, Uz) µm)`` — :meth:`correct_point`
        and U (k = 2 per component) in one call, scalars throughout (the daemon's path). U is
        NaN when the status is not ``ok`` or the grid carries no uncertainty."""
        out, status = self.correct_point(point_mm, stylus_mm, temps_C, inputs, outside=outside)
        gu = self.uncertainty
        if status != "ok" or gu is None:
            return out, status, _NAN3
        x, y, z = map(float, point_mm)  # type: ignore[arg-type, call-overload, unused-ignore]
        px, py, pz = map(float, stylus_mm)  # type: ignore[arg-type, call-overload, unused-ignore]
        lo, hi = self._lo_list, self._hi_list  # "ok" is within VOLUME_TOL_MM: clamp as correct()
        x, y, z = min(max(x, lo[0]), hi[0]), min(max(y, lo[1]), hi[1]), min(max(z, lo[2]), hi[2])
        with self._lock:
            point_u = self._u_point
            if point_u is None:
                point_u = self._u_point = PointUncertainty(
                    gu, gu.coefficients(self.axes), self._u_tables()
                )
            return out, status, point_u((x, y, z), (px, py, pz), temps_C, inputs)

    def uncertainty_point(
        self,
        point_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[tuple[float, float, float], str]:
        """One reading's ``((Ux, Uy, Uz) µm, status)`` (see
        :meth:`correct_point_with_uncertainty`)."""
        _, status, u = self.correct_point_with_uncertainty(
            point_mm, stylus_mm, temps_C, inputs, outside=outside
        )
        return u, status

    def error_um(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> tuple[FloatArray, NDArray[np.str_]]:
        """Interpolated volumetric error (N, 3) µm (= (corrected − indicated)·1000) and status."""
        pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
        out, status, _, _ = self._evaluate(pts, stylus_mm, temps_C, inputs, None, False)
        return (out - pts) * 1000.0, status

    def pose(
        self,
        points_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> tuple[FloatArray, FloatArray, NDArray[np.str_]]:
        """Interpolated error pose: quaternions (N, 4) (w, x, y, z), translation (N, 3) µm, status."""
        _, status, q, t = self._evaluate(points_mm, (0.0, 0.0, 0.0), temps_C, inputs, None, True)
        return q, t, status

    def command_for_target(
        self,
        targets_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        tol_mm: float = 1e-6,
        max_iter: int = 20,
    ) -> tuple[FloatArray, NDArray[np.str_]]:
        """Indicated (command) positions (N, 3) mm whose corrected position is ``targets_mm``
        (the inverse for machine-tool users; see :func:`.inverse.command_for_target`)."""
        return command_for_target(
            self, targets_mm, stylus_mm, temps_C, inputs, tol_mm=tol_mm, max_iter=max_iter
        )

    @property
    def signal_filters(self) -> list[SignalFilter]:
        """Filters a runtime user must apply to raw signals before :meth:`correct`.

        Each is a :class:`cmm_comp.compensation.thermal.SignalFilter`; kind ``first_order_lag``:
        feed ``T + w·(lag_τ(T) − T)`` for each listed signal, the lag being a first-order filter
        over time (:class:`cmm_comp.compensation.thermal.FirstOrderLag`). The grid's
        sensitivities are with respect to those effective signals (thermal-lag effect). In the
        file header they are dicts (:meth:`SignalFilter.to_header`)."""
        return list(self._signal_filters)

    # ------------------------------------------------------------------ file
    def header(self) -> dict[str, Any]:
        """The self-describing file header (JSON-serialisable; see :mod:`.file`)."""
        return grid_header(self)

    def save(self, path: str | Path) -> str:
        """Write the grid file atomically (see :mod:`.file`); return its SHA-256."""
        return save_grid(self, path)

    @classmethod
    def load(
        cls,
        path: str | Path,
        expect_machine: Any = None,
        outside: str | None = None,
        verify: Callable[[GridContents], None] | None = None,
    ) -> CorrectionGrid:
        """Read a grid file; :class:`GridFileError` (a ``ValueError``) names file and problem.

        ``expect_machine``: a machine (anything with ``identity_sha256()``) or a sha256 hex
        string; the file must have been built from that machine description. ``verify``: a
        check of the file contents before the grid is built (``signing.signature_check``).
        """
        return load_grid(cls, path, expect_machine, outside, verify)

    def __getstate__(self) -> dict[str, Any]:
        """Picklable (a daemon builds a grid in a worker process): the lock is not sent."""
        state = dict(self.__dict__)
        state.pop("_lock", None)
        state.pop("_u_point", None)  # views of its own buffers: rebuilt where it is used
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()
        self._u_point = None

    def __repr__(self) -> str:
        m = self.metadata.get("machine", {})
        return (
            f"CorrectionGrid(machine={m.get('name')!r}, steps={self.steps}, "
            f"signals={[s.name for s in self.signals]}, outside={self.outside!r})"
        )
