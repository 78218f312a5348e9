"""The correction grid: exact error poses at the nodes of the working volume, interpolated.

At every node the grid stores the machine's error pose (seed paper, Hermann §6): the error
rotation ``R_work_stylus`` as a unit quaternion (w, x, y, z), sign-continuous between
neighbours, and the translation (µm) at stylus offset 0. Between nodes

* rotations are interpolated by **Squad**, tensor-product: along x on the 4×4 neighbouring
  node lines (control points precomputed at the nodes), then along y on the 4 results, then
  along z (control points computed from the interpolated neighbours); at the edges of the
  volume the ``"quadratic"`` boundary rule of :mod:`compensation.squad` (a parabola through
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
Error convention true − indicated, so corrected = indicated + error (FORMATS.md).

Status of each corrected point (first applicable reason):
``"invalid_input"`` (NaN/inf coordinates or stylus; NaN coordinates out),
``"outside_volume"`` (policy ``outside="refuse"``: NaN coordinates out; never extrapolated),
``"clamped_outside_volume"`` (policy ``outside="clamp"``: the correction of the nearest point of
the volume is applied), ``"no_temperature"`` (a temperature the grid needs is missing or NaN:
the point is corrected geometrically, *without* that temperature's terms, and flagged),
``"missing_input"`` (same for a non-temperature signal such as ``dir_x``), ``"ok"``.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import re
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import make_interp_spline

from cmm_comp.compensation import grid_kernels as kern
from cmm_comp.compensation import quaternion as qt
from cmm_comp.compensation.grid_file import (
    FORMAT_NAME,
    FORMAT_VERSION,
    GridFileError,
    read_grid_file,
    write_grid_file,
)
from cmm_comp.compensation.squad import squad_control_points

__all__ = [
    "DEFAULT_STEPS",
    "MAX_NODES",
    "MAX_STEPS_PER_AXIS",
    "MIN_STEPS_PER_AXIS",
    "STATUS_DTYPE",
    "CorrectionGrid",
    "GridFileError",
    "GridSignal",
    "default_steps",
    "make_grid_continuous",
]

FloatArray = NDArray[np.float64]
ProgressFn = Callable[[float, str], None]

DEFAULT_STEPS = (20, 20, 10)
MIN_STEPS_PER_AXIS = 4  # the not-a-knot cubic spline needs 4 nodes per axis
MAX_STEPS_PER_AXIS = 1000


#: Node spacing relative to the finest error-table spacing of an axis (measured: 20×20×20 meets
#: the 1 % accuracy target on gec-mh2, whose tables are 100 mm apart, 20×20×10 does not).
TABLE_SPACING_FACTOR = 0.6
MAX_DEFAULT_STEPS = 100


def default_steps(machine: Any) -> tuple[int, int, int]:
    """Nodes per axis when none are given: ``volume.steps`` (or :data:`DEFAULT_STEPS`), raised
    so the node spacing is at most ``TABLE_SPACING_FACTOR`` × the finest spacing of the tabulated
    errors of that axis (at most :data:`MAX_DEFAULT_STEPS`)."""
    vol = machine.volume
    base = list(getattr(vol, "steps", None) or DEFAULT_STEPS)
    lo = np.asarray(vol.lower_mm, dtype=np.float64)
    hi = np.asarray(vol.upper_mm, dtype=np.float64)
    for table in getattr(machine, "tables", {}).values():
        pos = getattr(table, "position_mm", None)
        axis = getattr(getattr(table, "component", None), "axis", None)
        if pos is None or axis not in ("x", "y", "z") or len(pos) < 2:
            continue
        k = "xyz".index(axis)
        spacing = float(np.min(np.diff(pos)))
        if spacing > 0:
            need = int(np.ceil((hi[k] - lo[k]) / (TABLE_SPACING_FACTOR * spacing))) + 1
            base[k] = max(base[k], min(need, MAX_DEFAULT_STEPS))
    return (int(base[0]), int(base[1]), int(base[2]))


def _signal_filters(machine: Any) -> list[dict[str, Any]]:
    """Runtime signal filters required by the machine's effects (the thermal lag)."""
    out: list[dict[str, Any]] = []
    for effect in getattr(machine, "effects", []):
        if getattr(effect, "cause", "") == "thermal_lag":
            from .effects import LAGGED_SIGNALS

            table = effect.to_table()
            out.append(
                {
                    "kind": "first_order_lag",
                    "signals": list(LAGGED_SIGNALS),
                    "time_constant_s": float(table["time_constant_s"]),
                    "fraction": float(table.get("fraction", 1.0)),
                }
            )
    return out


_LOBE_SIGNAL = re.compile(r"lobe(\d+)_[cs]_[xyz]")
MAX_NODES = 2_000_000  # ~0.5 GB with 4 signals; beyond this is not a sensible grid
STATUS_DTYPE = "<U22"
VOLUME_TOL_MM = 1e-9  # points this far outside the volume still count as inside
_WARM = {"done": False}


class MachineLike(Protocol):
    """What :meth:`CorrectionGrid.build` needs from a machine (see ``compensation.machine``)."""

    name: str
    model: str
    volume: Any

    def pose_error(
        self,
        points_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> Any: ...

    def runtime_signals(self) -> dict[str, float]: ...

    def identity_sha256(self) -> str: ...


@dataclass(frozen=True)
class GridSignal:
    """A runtime signal: its name, reference value, and whether the grid depends on it."""

    name: str
    reference: float
    needed: bool

    @property
    def is_temperature(self) -> bool:
        return self.name.startswith("T_")


def make_grid_continuous(q_grid: ArrayLike) -> FloatArray:
    """Sign-continuous node quaternions (nx, ny, nz, 4), order (w, x, y, z).

    Fixes node (0, 0, 0) to w ≥ 0, then propagates along x on the first line, along y on
    the first plane and along z everywhere, so that every neighbour pair along every axis
    has a non-negative dot product; raises ``ValueError`` if the rotation changes so fast
    between neighbours that this is impossible (dot < 0.5, i.e. > 120° apart).
    """
    q = np.array(q_grid, dtype=np.float64, copy=True)
    if q[0, 0, 0, 0] < 0:
        q[0, 0, 0] *= -1
    q[:, 0, 0] = qt.make_continuous(q[:, 0, 0], axis=0)
    q[:, :, 0] = qt.make_continuous(q[:, :, 0], axis=1)
    q = qt.make_continuous(q, axis=2)
    for axis in range(3):
        a = np.moveaxis(q, axis, 0)
        if a.shape[0] > 1 and np.min(np.sum(a[1:] * a[:-1], axis=-1)) < 0.5:
            raise ValueError(
                "node rotations differ by more than 120° between neighbours along axis "
                f"{'xyz'[axis]}: the grid is far too coarse for this rotation field"
            )
    return q


def _library_version() -> str:
    try:
        from importlib.metadata import version

        return version("cmm-comp")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


def _check_steps(steps: Sequence[int]) -> tuple[int, int, int]:
    vals = tuple(int(s) for s in steps)
    if len(vals) != 3 or any(s != t for s, t in zip(vals, steps, strict=False)):
        raise ValueError(f"steps must be three integers (nodes per axis), got {tuple(steps)!r}")
    for axis, s in zip("xyz", vals, strict=True):
        if not MIN_STEPS_PER_AXIS <= s <= MAX_STEPS_PER_AXIS:
            raise ValueError(
                f"steps along {axis} = {s}: allowed {MIN_STEPS_PER_AXIS}…{MAX_STEPS_PER_AXIS} "
                "nodes per axis (the cubic spline needs at least 4)"
            )
    total = vals[0] * vals[1] * vals[2]
    if total > MAX_NODES:
        raise ValueError(
            f"steps {vals} give {total} nodes; at most {MAX_NODES} are allowed "
            "(a grid this size would not fit in memory; use fewer steps)"
        )
    return vals  # type: ignore[return-value]


def _knots_and_spans(nodes: FloatArray) -> tuple[FloatArray, NDArray[np.int64]]:
    """Not-a-knot cubic knot vector of ``nodes`` and the knot span of every cell."""
    spl = make_interp_spline(nodes, np.zeros_like(nodes), k=3)
    knots = np.ascontiguousarray(spl.t, dtype=np.float64)
    mids = 0.5 * (nodes[:-1] + nodes[1:])
    spans = np.searchsorted(knots, mids, side="right").astype(np.int64) - 1
    return knots, spans


def _lookup(name: str, *maps: Mapping[str, Any] | None) -> Any:
    for m in maps:
        if m is not None and name in m and m[name] is not None:
            return m[name]
    return None


class CorrectionGrid:
    """Error poses at the nodes of a regular grid over the working volume, and their
    interpolation (Squad for rotations, C² cubic spline for translations).

    Construct with :meth:`build` (from a machine model), :meth:`from_poses` (from measured
    node poses, e.g. :mod:`compensation.sixdof`) or :meth:`load`. Quaternions (w, x, y, z).
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
    ) -> None:
        lo = np.asarray(lower_mm, dtype=np.float64).reshape(3)
        hi = np.asarray(upper_mm, dtype=np.float64).reshape(3)
        q = np.asarray(q_work_stylus, dtype=np.float64)
        t = np.asarray(translation_um, dtype=np.float64)
        if q.ndim != 4 or q.shape[-1] != 4:
            raise ValueError(f"q_work_stylus must be (nx, ny, nz, 4), got {q.shape}")
        steps = _check_steps(q.shape[:3])
        if t.shape != (*steps, 3):
            raise ValueError(f"translation_um must be {(*steps, 3)}, got {t.shape}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise ValueError(f"volume axes must increase: lower {lo.tolist()}, upper {hi.tolist()}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
            raise ValueError("node quaternions and translations must be finite")
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
        if outside not in ("refuse", "clamp"):
            raise ValueError(f"outside must be 'refuse' or 'clamp', got {outside!r}")
        self.outside = outside
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
        self.sha256: str | None = None
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
        """Evaluate ``machine`` exactly at every node of its working volume.

        ``steps`` = nodes per axis (default: :func:`default_steps`: the machine's ``volume.steps``
        or :data:`DEFAULT_STEPS`, refined so nodes are no further apart than 0.6× the finest
        tabulated error spacing along each axis — a coarser grid cannot follow the tables).
        For every runtime signal the sensitivity per unit is the central difference of the
        pose at reference ± 1 unit; ``metadata["nonlinearity"]`` records, per signal, the
        largest second difference (µm, µrad) over the nodes, i.e. how far from linear it is.
        ``progress(fraction, message)`` is called as the work proceeds.
        """
        vol = machine.volume
        if steps is None:
            steps = default_steps(machine)
        steps_ok = _check_steps(steps)
        lo = np.asarray(vol.lower_mm, dtype=np.float64)
        hi = np.asarray(vol.upper_mm, dtype=np.float64)
        axes = [np.linspace(lo[k], hi[k], steps_ok[k]) for k in range(3)]
        nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        refs = {str(k): float(v) for k, v in machine.runtime_signals().items()}
        n_eval = 1 + 2 * len(refs)
        done = 0

        def evaluate(values: dict[str, float]) -> tuple[FloatArray, FloatArray]:
            nonlocal done
            temps = {k: v for k, v in values.items() if k.startswith("T_")}
            other = {k: v for k, v in values.items() if not k.startswith("T_")}
            pose = machine.pose_error(nodes, temps_C=temps or None, inputs=other or None)
            done += 1
            if progress is not None:
                progress(
                    done / n_eval, f"evaluated machine at {len(nodes)} nodes ({done}/{n_eval})"
                )
            return np.asarray(pose.rotation, float), np.asarray(pose.translation_um, float)

        r0, t0 = evaluate(refs)
        q0 = qt.quaternion_from_matrix(r0)
        sens_t, sens_r, signals, nonlin = [], [], [], {}
        for name, ref in refs.items():
            rp, tp = evaluate({**refs, name: ref + 1.0})
            rm, tm = evaluate({**refs, name: ref - 1.0})
            # rotation vectors of R(ref ± 1)·R0ᵀ (left, in the workpiece frame), µrad
            wp = qt.rotvec_from_quaternion(qt.quaternion_from_matrix(rp @ np.swapaxes(r0, 1, 2)))
            wm = qt.rotvec_from_quaternion(qt.quaternion_from_matrix(rm @ np.swapaxes(r0, 1, 2)))
            dt = 0.5 * (tp - tm)
            dw = 0.5e6 * (wp - wm)
            nonlin[name] = {
                "translation_um": float(np.abs(tp - 2 * t0 + tm).max()),
                "rotation_urad": float(1e6 * np.abs(wp + wm).max()),
            }
            needed = bool(np.abs(dt).max() > 1e-12 or np.abs(dw).max() > 1e-12)
            signals.append(GridSignal(name, ref, needed))
            sens_t.append(dt.reshape(*steps_ok, 3))
            sens_r.append(dw.reshape(*steps_ok, 3))
        meta = {
            "machine": {
                "name": str(machine.name),
                "model": str(machine.model),
                "sha256": machine.identity_sha256(),
            },
            "source": "model",
            "probe_offset_mm": np.asarray(
                getattr(getattr(machine, "probe", None), "offset_mm", np.zeros(3)), float
            ).tolist(),
            "reference_mm": np.asarray(getattr(vol, "reference_mm", lo), float).tolist(),
            "nonlinearity": nonlin,
            "signal_filters": _signal_filters(machine),
        }
        return cls(
            lo,
            hi,
            q0.reshape(*steps_ok, 4),
            t0.reshape(*steps_ok, 3),
            signals,
            np.array(sens_t).reshape(len(signals), *steps_ok, 3),
            np.array(sens_r).reshape(len(signals), *steps_ok, 3),
            meta,
            outside,
        )

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
        """Grid from node poses, e.g. captured with the 6-DOF scheme (:mod:`compensation.sixdof`).

        ``axes_mm``: three increasing, equally spaced node coordinate arrays (mm);
        ``q_work_stylus`` (nx, ny, nz, 4) unit quaternions (w, x, y, z) of the error rotation;
        ``translation_um`` (nx, ny, nz, 3) the error translation at stylus offset 0 (µm), i.e.
        the error of the point about which the rotation acts.
        """
        ax = [np.asarray(a, dtype=np.float64) for a in axes_mm]
        if len(ax) != 3:
            raise ValueError(f"axes_mm must hold three node arrays, got {len(ax)}")
        for name, a in zip("xyz", ax, strict=True):
            if a.ndim != 1 or a.size < 2 or not np.all(np.diff(a) > 0):
                raise ValueError(f"axis {name} nodes must be a strictly increasing 1-D array")
            uniform = np.linspace(a[0], a[-1], a.size)
            if np.abs(a - uniform).max() > 1e-9 * max(1.0, abs(a[-1] - a[0])):
                raise ValueError(f"axis {name} nodes must be equally spaced (Squad parameter)")
        meta = {
            "machine": {"name": machine_name, "model": machine_model, "sha256": source_sha256},
            "source": "poses",
        }
        return cls(
            [a[0] for a in ax],
            [a[-1] for a in ax],
            q_work_stylus,
            translation_um,
            signals,
            sensitivity_translation_um,
            sensitivity_rotation_urad,
            meta,
            outside,
        )

    def _prepare(self) -> None:
        """Precompute Squad control data along x and the tensor spline coefficients."""
        q = self.q_work_stylus
        sx = squad_control_points(q, axis=0, boundary="quadratic")
        wq = np.zeros((*self.steps, 3))
        ws = np.zeros((*self.steps, 3))
        wq[:-1] = qt.log(qt.multiply(qt.conjugate(q[:-1]), q[1:]))
        ws[:-1] = qt.log(qt.multiply(qt.conjugate(sx[:-1]), sx[1:]))
        comps = [self.translation_um]
        for s in range(len(self.signals)):
            comps += [self.sensitivity_translation_um[s], self.sensitivity_rotation_urad[s]]
        coef = np.concatenate(comps, axis=-1)
        for axis in range(3):
            spline = make_interp_spline(self.axes[axis], coef, k=3, axis=axis)
            coef = np.moveaxis(spline.c, 0, axis)  # BSpline puts the spline axis first
        knots, spans = zip(*(_knots_and_spans(a) for a in self.axes), strict=True)
        # half-angle bound of every x-stage relative rotation (see grid_kernels, "small")
        d_qs = np.linalg.norm(qt.log(qt.multiply(qt.conjugate(q), sx)), axis=-1).max()
        bound = np.linalg.norm(wq, axis=-1).max() + d_qs + np.linalg.norm(ws, axis=-1).max()
        self._small = bool(bound * bound < kern.SERIES_LIMIT2)
        self._node = np.ascontiguousarray(np.concatenate([q, sx, wq, ws], axis=-1))
        self._q = np.ascontiguousarray(q)
        self._sx = np.ascontiguousarray(sx)
        self._wq = wq
        self._ws = ws
        self._coef = np.ascontiguousarray(coef)
        self._knots = knots
        self._spans = spans
        self._lo = self.lower_mm.copy()
        self._inv_d = np.array(
            [(self.steps[k] - 1) / (self.upper_mm[k] - self.lower_mm[k]) for k in range(3)]
        )
        self._shape = np.array(self.steps, dtype=np.int64)
        self._needed = np.array([s.needed for s in self.signals], dtype=bool)
        self._derived_lobes = sorted(
            {
                int(m.group(1))
                for sig in self.signals
                if sig.needed and (m := _LOBE_SIGNAL.fullmatch(sig.name))
            }
        )
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
        args = (
            points, stylus, dev, self._lo, self._inv_d, self._shape,
            self._q, self._sx, self._wq, self._ws, self._node, self._small, *self._knots, *self._spans,
            self._coef, ncomp, out, out_q, out_t, want_pose,
        )  # fmt: skip
        if parallel:
            threads = max(1, (os.cpu_count() or 1))
            chunk = max(512, math.ceil(n / (8 * threads)))
            kern.eval_parallel(*args, chunk)  # type: ignore[call-arg]
        else:
            kern.eval_serial(*args)  # type: ignore[call-arg]
        return out, out_q, out_t

    def _deviations(
        self, n: int, temps_C: Mapping[str, Any] | None, inputs: Mapping[str, Any] | None
    ) -> tuple[FloatArray, NDArray[np.bool_], NDArray[np.bool_]]:
        """Signal deviations (n, S) and masks of points missing a needed temperature / input."""
        dev = np.zeros((n, len(self.signals)))
        no_temp = np.zeros(n, dtype=bool)
        no_input = np.zeros(n, dtype=bool)
        for s, sig in enumerate(self.signals):
            if not sig.needed:
                continue
            first, second = (temps_C, inputs) if sig.is_temperature else (inputs, temps_C)
            value = _lookup(sig.name, first, second)
            missing = no_temp if sig.is_temperature else no_input
            if value is None:
                missing[:] = True
                continue
            arr = np.asarray(value, dtype=np.float64)
            if arr.ndim == 0:
                arr = np.full(n, float(arr))
            if arr.shape != (n,):
                raise ValueError(
                    f"signal {sig.name!r} must be a scalar or have shape ({n},), got {arr.shape}"
                )
            bad = ~np.isfinite(arr)
            missing |= bad
            dev[:, s] = np.where(bad, 0.0, arr - sig.reference)
        return dev, no_temp, no_input

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
        policy = self.outside if outside is None else outside
        if policy not in ("refuse", "clamp"):
            raise ValueError(f"outside must be 'refuse' or 'clamp', got {policy!r}")
        status = np.full(n, "ok", dtype=STATUS_DTYPE)
        bad = ~np.isfinite(pts).all(axis=1)
        sty_bad = ~np.isfinite(stylus).all(axis=1)
        bad = bad | np.broadcast_to(sty_bad, (n,))
        clamped = np.clip(pts, self.lower_mm, self.upper_mm)
        outside_mask = np.any(np.abs(clamped - pts) > VOLUME_TOL_MM, axis=1) & ~bad
        if bad.any():
            clamped[bad] = self.lower_mm
            stylus = np.where(np.isfinite(stylus), stylus, 0.0)
        dev, no_temp, no_input = self._deviations(n, temps_C, inputs)
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
        status[no_input] = "missing_input"
        status[no_temp] = "no_temperature"
        if outside_mask.any():
            if policy == "refuse":
                out[outside_mask] = np.nan
                status[outside_mask] = "outside_volume"
            else:
                status[outside_mask] = "clamped_outside_volume"
        if bad.any():
            out[bad] = np.nan
            status[bad] = "invalid_input"
        return out, status, q, t

    def derive_inputs(self, inputs: Mapping[str, Any] | None) -> Mapping[str, Any] | None:
        """Add derived signals the grid needs and the caller cannot know: the probe-lobing
        signals ``lobe<n>_{c,s}_<axis>`` from the probing direction ``nx, ny, nz``
        (:func:`compensation.effects.lobing_signals`). Anything given explicitly wins; without a
        probing direction nothing is derived and the point is flagged ``missing_input``."""
        if not self._derived_lobes or inputs is None:
            return inputs
        if not all(k in inputs and inputs[k] is not None for k in ("nx", "ny", "nz")):
            return inputs
        from .effects import lobing_signals

        out = dict(inputs)
        for lobes in self._derived_lobes:
            for name, value in lobing_signals(
                inputs["nx"], inputs["ny"], inputs["nz"], lobes
            ).items():
                out.setdefault(name, value)
        return out

    def correct(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[FloatArray, NDArray[np.str_]]:
        """Corrected positions (N, 3) mm and status (N,) str of indicated ``points_mm`` (N, 3).

        ``stylus_mm`` (3,) or (N, 3) mm; ``temps_C`` / ``inputs`` map signal names to scalars or
        (N,) arrays (either mapping may hold any signal). ``outside`` overrides the grid's
        policy (``"refuse"`` or ``"clamp"``). See the module docstring for the status values.
        """
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
        if outside is not None and outside not in ("refuse", "clamp"):
            raise ValueError(f"outside must be 'refuse' or 'clamp', got {outside!r}")
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
        outside_override = outside
        x, y, z = map(float, point_mm)  # type: ignore[arg-type, call-overload, unused-ignore]
        px, py, pz = map(float, stylus_mm)  # type: ignore[arg-type, call-overload, unused-ignore]
        nan = math.nan
        isfinite = math.isfinite
        if not (
            isfinite(x)
            and isfinite(y)
            and isfinite(z)
            and isfinite(px)
            and isfinite(py)
            and isfinite(pz)
        ):
            return (nan, nan, nan), "invalid_input"
        lo, hi = self._lo_list, self._hi_list
        cx = min(max(x, lo[0]), hi[0])
        cy = min(max(y, lo[1]), hi[1])
        cz = min(max(z, lo[2]), hi[2])
        is_outside = (
            abs(cx - x) > VOLUME_TOL_MM
            or abs(cy - y) > VOLUME_TOL_MM
            or abs(cz - z) > VOLUME_TOL_MM
        )
        if is_outside and (outside_override or self.outside) == "refuse":
            return (nan, nan, nan), "outside_volume"
        status = "ok"
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
                v = nan if value is None else float(value)
                if not isfinite(v):
                    row[k] = 0.0
                    if status == "ok" or is_temperature:
                        status = "no_temperature" if is_temperature else "missing_input"
                    continue
                row[k] = v - reference
                active = active or v != reference
            p1, s1, o1 = self._p1, self._s1, self._o1
            p1[0, 0], p1[0, 1], p1[0, 2] = cx, cy, cz
            s1[0, 0], s1[0, 1], s1[0, 2] = px, py, pz
            ncomp = self._ncomp_all if active else 3
            kern.eval_serial(  # type: ignore[call-arg]
                p1, s1, dev, self._lo, self._inv_d, self._shape,
                self._q, self._sx, self._wq, self._ws, self._node, self._small, *self._knots,
                *self._spans, self._coef, ncomp, o1, self._dummy_q, self._dummy_t, False,
            )  # fmt: skip
            out = (
                float(o1[0, 0]) + (x - cx),
                float(o1[0, 1]) + (y - cy),
                float(o1[0, 2]) + (z - cz),
            )
        if is_outside:
            status = "clamped_outside_volume"
        return out, status

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
        """Indicated (command) positions whose corrected position is ``targets_mm`` (N, 3).

        The inverse for machine-tool users: solves ``c + e(c) = target`` by the fixed-point
        iteration ``c ← target − e(c)`` (contracts because ‖∂e/∂c‖ ≈ 10⁻⁵). Stops when every
        step is below ``tol_mm``; points that have not converged after ``max_iter`` iterations
        get NaN and status ``"not_converged"``. Other statuses as in :meth:`correct` (a target
        outside the volume is refused whatever the policy).
        """
        tgt = np.asarray(targets_mm, dtype=np.float64).reshape(-1, 3)
        cmd = tgt.copy()
        _, status = self.correct(tgt, stylus_mm, temps_C, inputs, outside="refuse")
        active = status != "invalid_input"
        active &= status != "outside_volume"
        converged = ~active
        for _ in range(max_iter):
            idx = np.flatnonzero(~converged)
            if idx.size == 0:
                break
            sty = np.asarray(stylus_mm, dtype=np.float64)
            sty_i = sty[idx] if sty.ndim == 2 and sty.shape[0] == tgt.shape[0] else sty
            sub_t = _subset(temps_C, idx, tgt.shape[0])
            sub_i = _subset(inputs, idx, tgt.shape[0])
            corr, _ = self.correct(cmd[idx], sty_i, sub_t, sub_i, outside="clamp")
            new = tgt[idx] - (corr - cmd[idx])
            step = np.abs(new - cmd[idx]).max(axis=1)
            cmd[idx] = new
            converged[idx[step < tol_mm]] = True
        fail = ~converged
        cmd[fail] = np.nan
        status[fail] = "not_converged"
        cmd[~active] = np.nan
        return cmd, status

    @property
    def signal_filters(self) -> list[dict[str, Any]]:
        """Filters a runtime user must apply to raw signals before :meth:`correct`.

        Each is ``{"kind": "first_order_lag", "signals": [...], "time_constant_s": τ,
        "fraction": w}``: feed ``T + w·(lag_τ(T) − T)`` for each listed signal, the lag being a
        first-order filter over time (:class:`compensation.effects.FirstOrderLag`). The grid's
        sensitivities are with respect to those effective signals (thermal-lag effect)."""
        return list(self.metadata.get("signal_filters", []))

    # ------------------------------------------------------------------ file
    def header(self) -> dict[str, Any]:
        """The self-describing file header (JSON-serialisable)."""
        meta = dict(self.metadata)
        machine = meta.pop("machine", {"name": "", "model": "", "sha256": ""})
        ref_c = next((s.reference for s in self.signals if s.is_temperature), 20.0)
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "machine": machine,
            "volume": {"lower_mm": self.lower_mm.tolist(), "upper_mm": self.upper_mm.tolist()},
            "steps": list(self.steps),
            "units": {
                "position": "mm",
                "translation": "um",
                "rotation": "unit quaternion (w, x, y, z)",
                "sensitivity_translation": "um per signal unit",
                "sensitivity_rotation": "urad (rotation vector) per signal unit",
            },
            "reference_C": ref_c,
            "stylus_convention": (
                "error_um = translation_um + 1000 (R - I) p, p = stylus offset (mm) from the "
                "point the translation refers to; corrected = indicated + error; "
                "error = true - indicated"
            ),
            "interpolation": {
                "rotation": "tensor-product Squad x, y, z; quadratic end control points",
                "translation": "tricubic not-a-knot B-spline (C2)",
            },
            "signals": [
                {"name": s.name, "reference": s.reference, "needed": s.needed} for s in self.signals
            ],
            "outside_policy": self.outside,
            "built_utc": meta.pop("built_utc", _dt.datetime.now(_dt.UTC).isoformat()),
            "library_version": meta.pop("library_version", _library_version()),
            **meta,
        }

    def save(self, path: str | Path) -> str:
        """Write the grid file atomically (see :mod:`compensation.grid_file`); return its SHA-256."""
        header = self.header()
        self.metadata.setdefault("built_utc", header["built_utc"])
        self.metadata.setdefault("library_version", header["library_version"])
        arrays = {
            "q_work_stylus": self.q_work_stylus,
            "translation_um": self.translation_um,
            "sensitivity_translation_um": self.sensitivity_translation_um,
            "sensitivity_rotation_urad": self.sensitivity_rotation_urad,
        }
        self.sha256 = write_grid_file(path, header, arrays)
        return self.sha256

    @classmethod
    def load(
        cls, path: str | Path, expect_machine: Any = None, outside: str | None = None
    ) -> CorrectionGrid:
        """Read a grid file; :class:`GridFileError` (a ``ValueError``) names file and problem.

        ``expect_machine``: a machine (anything with ``identity_sha256()``) or a sha256 hex
        string; the file must have been built from that machine description.
        """
        header, arrays, sha = read_grid_file(path)
        try:
            machine = header["machine"]
            sigs = [
                GridSignal(str(s["name"]), float(s["reference"]), bool(s["needed"]))
                for s in header["signals"]
            ]
            grid = cls(
                header["volume"]["lower_mm"],
                header["volume"]["upper_mm"],
                arrays["q_work_stylus"],
                arrays["translation_um"],
                sigs,
                arrays["sensitivity_translation_um"],
                arrays["sensitivity_rotation_urad"],
                {
                    k: v
                    for k, v in header.items()
                    if k
                    in (
                        "machine",
                        "source",
                        "reference_mm",
                        "probe_offset_mm",
                        "signal_filters",
                        "nonlinearity",
                        "built_utc",
                        "library_version",
                    )
                },
                outside or header.get("outside_policy", "refuse"),
            )
            if list(grid.steps) != list(header["steps"]):
                raise ValueError(
                    f"header steps {header['steps']} do not match the arrays {grid.steps}"
                )
        except (KeyError, TypeError, ValueError) as exc:
            raise GridFileError(f"{path}: invalid grid content ({exc})") from None
        if expect_machine is not None:
            want = (
                expect_machine
                if isinstance(expect_machine, str)
                else expect_machine.identity_sha256()
            )
            if machine.get("sha256") != want:
                raise GridFileError(
                    f"{path}: grid was built for machine {machine.get('name')!r} "
                    f"(description sha256 {str(machine.get('sha256'))[:12]}…), "
                    f"not for the expected one (sha256 {want[:12]}…); rebuild the grid"
                )
        grid.sha256 = sha
        return grid

    def __repr__(self) -> str:
        m = self.metadata.get("machine", {})
        return (
            f"CorrectionGrid(machine={m.get('name')!r}, steps={self.steps}, "
            f"signals={[s.name for s in self.signals]}, outside={self.outside!r})"
        )


def _subset(
    mapping: Mapping[str, Any] | None, idx: NDArray[np.intp], n: int
) -> dict[str, Any] | None:
    if mapping is None:
        return None
    out: dict[str, Any] = {}
    for k, v in mapping.items():
        if v is None:
            out[k] = None
            continue
        arr = np.asarray(v, dtype=np.float64)
        out[k] = arr[idx] if arr.ndim == 1 and arr.shape[0] == n else arr
    return out
