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
the same for the batch path (:meth:`CorrectionGrid.correct`, :mod:`.batch`) and the
single-reading path (:meth:`CorrectionGrid.correct_point`, :mod:`.point`). The node data is
made in :mod:`.build` and checked in :mod:`.nodes`, the file is :mod:`.file`, the signals
:mod:`.inputs`, the compiled kernels :mod:`.kernels`; none of them knows this class.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GridFileError
from ..thermal.lag import SignalFilter
from .batch import BatchCorrector
from .build import MachineLike, nodes_from_machine, nodes_from_poses
from .file import GridContents, grid_header, read_grid, save_grid
from .inputs import GridSignal, derive_lobing_inputs, lobing_orders
from .interpolation import interpolation_tables
from .inverse import command_for_target
from .kernels import KernelTables
from .nodes import check_nodes
from .point import PointCorrector
from .status import STATUS_DTYPE, check_policy
from .uncertainty import GridUncertainty, expanded_uncertainty_um

__all__ = ["CorrectionGrid"]

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.str_]
ProgressFn = Callable[[float, str], None]
Vec3 = tuple[float, float, float]


class CorrectionGrid:
    """Error poses at the nodes of a regular grid over the working volume, and their
    interpolation (Squad for rotations, C² cubic spline for translations).

    Construct with :meth:`build` (from a machine model), :meth:`from_poses` (from measured
    node poses, e.g. :mod:`compensation.reports.sixdof`) or :meth:`load`. Correct with
    :meth:`correct` / :meth:`correct_with_uncertainty` (N points) or :meth:`correct_point` /
    :meth:`correct_point_with_uncertainty` (one reading, scalars). Quaternions (w, x, y, z).

    The node data is public and read-only by convention (``lower_mm``, ``upper_mm``, ``steps``,
    ``axes``, ``q_work_stylus``, ``translation_um``, ``signals``, the sensitivity grids,
    ``metadata``, ``outside``, ``uncertainty``, ``sha256``); the interpolation tables the
    compiled kernels read (``kernel_tables``, :class:`.kernels.KernelTables`) are computed from
    it once, when the grid is constructed.
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
        nodes = check_nodes(
            lower_mm,
            upper_mm,
            q_work_stylus,
            translation_um,
            signals,
            sensitivity_translation_um,
            sensitivity_rotation_urad,
        )
        self.outside = check_policy(outside)
        self.lower_mm, self.upper_mm = nodes.lower_mm, nodes.upper_mm
        self.steps, self.axes = nodes.steps, nodes.axes
        self.q_work_stylus = nodes.q_work_stylus
        self.translation_um = nodes.translation_um
        self.signals = nodes.signals
        self.sensitivity_translation_um = nodes.sensitivity_translation_um
        self.sensitivity_rotation_urad = nodes.sensitivity_rotation_urad
        self.metadata: dict[str, Any] = dict(metadata or {})
        self.sha256: str | None = None
        self.uncertainty: GridUncertainty | None = None
        # the header form (list of dicts) stays in the metadata; the typed form is read once
        self._signal_filters = tuple(
            SignalFilter.from_header(f) for f in self.metadata.get("signal_filters", [])
        )
        self._derived_lobes = lobing_orders(self.signals)
        self.kernel_tables: KernelTables = interpolation_tables(
            self.q_work_stylus,
            self.translation_um,
            self.sensitivity_translation_um,
            self.sensitivity_rotation_urad,
            self.axes,
        )
        self._batch = BatchCorrector(self.kernel_tables, self.lower_mm, self.upper_mm, self.signals)
        self._point = PointCorrector(self.kernel_tables, self.lower_mm, self.upper_mm, self.signals)
        if uncertainty is not None:
            self._set_uncertainty(uncertainty)

    # ------------------------------------------------------------------ construction, file
    @classmethod
    def build(
        cls,
        machine: MachineLike,
        steps: Sequence[int] | None = None,
        progress: ProgressFn | None = None,
        outside: str = "refuse",
    ) -> CorrectionGrid:
        """Evaluate ``machine`` exactly at every node of its working volume (see
        :func:`.build.nodes_from_machine`: default steps, sensitivity grids per signal)."""
        return cls(*nodes_from_machine(machine, steps, progress), outside=outside)

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
        """Grid from measured node poses (see :func:`.build.nodes_from_poses`): ``axes_mm`` three
        equally spaced node arrays (mm), quaternions (nx, ny, nz, 4) (w, x, y, z), translations
        (nx, ny, nz, 3) µm at stylus offset 0."""
        nodes = nodes_from_poses(
            axes_mm,
            q_work_stylus,
            translation_um,
            machine_name=machine_name,
            machine_model=machine_model,
            source_sha256=source_sha256,
            signals=signals,
            sensitivity_translation_um=sensitivity_translation_um,
            sensitivity_rotation_urad=sensitivity_rotation_urad,
        )
        return cls(*nodes, outside=outside)

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
        ``outside``: the policy (default: the one the grid was saved with).
        """
        stored = read_grid(path, expect_machine, verify)
        try:
            grid = cls(
                *stored.nodes, outside=outside or stored.outside, uncertainty=stored.uncertainty
            )
        except ValueError as exc:
            raise GridFileError(f"{path}: invalid grid content ({exc})") from None
        grid.sha256 = stored.sha256
        return grid

    def header(self) -> dict[str, Any]:
        """The self-describing file header (JSON-serialisable; see :mod:`.file`)."""
        return grid_header(self)

    def save(self, path: str | Path) -> str:
        """Write the grid file atomically (see :mod:`.file`); return its SHA-256."""
        self.sha256 = save_grid(self, path)
        return self.sha256

    def with_uncertainty(self, uncertainty: GridUncertainty | None) -> CorrectionGrid:
        """A copy of this grid carrying ``uncertainty`` (None: without); not yet saved."""
        out = copy.copy(self)
        out.uncertainty = None
        out.sha256 = None
        out._point = self._point.with_uncertainty(None, None)
        if uncertainty is not None:
            out._set_uncertainty(uncertainty)
        return out

    def _set_uncertainty(self, gu: GridUncertainty) -> None:
        if gu.covariance.shape[:3] != tuple(self.steps):
            raise ValueError(
                f"uncertainty covariance has {gu.covariance.shape[:3]} nodes, the grid {self.steps}"
            )
        self.uncertainty = gu
        self._point = self._point.with_uncertainty(gu, gu.coefficients(self.axes))

    # ------------------------------------------------------------------ what the grid needs
    @property
    def has_uncertainty(self) -> bool:
        """Whether the grid carries U (built with ``grid build --uncertainty``)."""
        return self.uncertainty is not None

    @property
    def signal_filters(self) -> list[SignalFilter]:
        """Filters a runtime user must apply to raw signals before :meth:`correct`.

        Each is a :class:`cmm_comp.compensation.thermal.SignalFilter`; kind ``first_order_lag``:
        feed ``T + w·(lag_τ(T) − T)`` for each listed signal, the lag being a first-order filter
        over time (:class:`cmm_comp.compensation.thermal.FirstOrderLag`). The grid's
        sensitivities are with respect to those effective signals (thermal-lag effect). In the
        file header they are dicts (:meth:`SignalFilter.to_header`)."""
        return list(self._signal_filters)

    def derive_inputs(self, inputs: Mapping[str, Any] | None) -> Mapping[str, Any] | None:
        """Add derived signals the grid needs and the caller cannot know: the probe-lobing
        signals ``lobe<n>_{c,s}_<axis>`` from the probing direction ``nx, ny, nz``
        (:func:`cmm_comp.compensation.effects.lobing_signals`). Anything given explicitly wins;
        without a probing direction nothing is derived and the point is flagged ``missing_input``."""
        return derive_lobing_inputs(self._derived_lobes, inputs)

    def _refuse(self, outside: str | None) -> bool:
        """Whether the policy (``outside``, else the grid's) refuses points outside the volume."""
        return (self.outside if outside is None else check_policy(outside)) == "refuse"

    # ------------------------------------------------------------------ N points
    def correct(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[FloatArray, StatusArray]:
        """Corrected positions (N, 3) mm and status (N,) str of indicated ``points_mm`` (N, 3).

        ``stylus_mm`` (3,) or (N, 3) mm; ``temps_C`` / ``inputs`` map signal names to scalars or
        (N,) arrays (either mapping may hold any signal). ``outside`` overrides the grid's
        policy (``"refuse"`` or ``"clamp"``). See the module docstring for the status values;
        a coordinate whose status is not ``ok`` must not be used as corrected.
        """
        inputs = self.derive_inputs(inputs)
        pts = np.asarray(points_mm, dtype=np.float64)
        refuse = self._refuse(outside)
        if pts.shape in ((3,), (1, 3)):  # one reading of scalars: the single-reading path
            one = _scalars(stylus_mm, temps_C, inputs)
            if one is not None:
                c, status = self._point.correct(pts.reshape(3), one[0], one[1], one[2], refuse)
                return np.array([c]), np.array([status], dtype=STATUS_DTYPE)
        result = self._batch(pts, stylus_mm, temps_C, inputs, refuse)
        return result.corrected_mm, result.status

    def correct_with_uncertainty(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[FloatArray, StatusArray, FloatArray]:
        """:meth:`correct` and U_um (N, 3) µm: the expanded uncertainty (k = 2) per component of
        every point whose status is ``ok``; NaN elsewhere and everywhere when the grid carries
        no uncertainty (:attr:`has_uncertainty`)."""
        inputs = self.derive_inputs(inputs)
        result = self._batch(points_mm, stylus_mm, temps_C, inputs, self._refuse(outside))
        u_um = self._expanded_um(result.points_mm, stylus_mm, temps_C, inputs, result.status)
        return result.corrected_mm, result.status, u_um

    def uncertainty_um(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[FloatArray, StatusArray]:
        """U (N, 3) µm (k = 2 per component) and status of indicated ``points_mm``: the
        uncertainty of what :meth:`correct` returns (:meth:`correct_with_uncertainty`)."""
        _, status, u_um = self.correct_with_uncertainty(
            points_mm, stylus_mm, temps_C, inputs, outside=outside
        )
        return u_um, status

    def _expanded_um(
        self,
        pts: FloatArray,
        stylus_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
        status: StatusArray,
    ) -> FloatArray:
        """U (N, 3) µm of the points whose ``status`` is ok; temperatures from ``temps_C``, else
        from ``inputs``, as the correction reads them."""
        if self.uncertainty is None:
            return np.full((pts.shape[0], 3), np.nan)
        temps = {k: v for k, v in (inputs or {}).items() if k.startswith("T_")}
        temps.update(temps_C or {})
        return expanded_uncertainty_um(
            self.uncertainty,
            self.uncertainty.coefficients(self.axes),
            tuple(self.kernel_tables.spline),
            np.clip(pts, self.lower_mm, self.upper_mm),  # rows not ok (NaN too) are not read
            np.asarray(stylus_mm, dtype=np.float64).reshape(-1, 3),
            temps,
            status == "ok",
        )

    def error_um(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> tuple[FloatArray, StatusArray]:
        """Interpolated volumetric error (N, 3) µm (= (corrected − indicated)·1000) and status."""
        pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
        result = self._batch(pts, stylus_mm, temps_C, inputs, self._refuse(None))
        return (result.corrected_mm - pts) * 1000.0, result.status

    def pose(
        self,
        points_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> tuple[FloatArray, FloatArray, StatusArray]:
        """Interpolated error pose: quaternions (N, 4) (w, x, y, z), translation (N, 3) µm, status."""
        r = self._batch(points_mm, (0.0, 0.0, 0.0), temps_C, inputs, self._refuse(None), True)
        return r.q, r.translation_um, r.status

    def command_for_target(
        self,
        targets_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        tol_mm: float = 1e-6,
        max_iter: int = 20,
    ) -> tuple[FloatArray, StatusArray]:
        """Indicated (command) positions (N, 3) mm whose corrected position is ``targets_mm``
        (the inverse for machine-tool users; see :func:`.inverse.command_for_target`)."""
        return command_for_target(
            self.correct, targets_mm, stylus_mm, temps_C, inputs, tol_mm=tol_mm, max_iter=max_iter
        )

    # ------------------------------------------------------------------ one reading
    def correct_point(
        self,
        point_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[Vec3, str]:
        """Fast path for one reading: ``((cx, cy, cz) mm, status)``; same rules as :meth:`correct`.

        Scalars only (temperatures as floats); uses preallocated buffers under a lock, so
        it is safe but serialised across threads. ~10 µs per call after the grid's warm-up.
        """
        if self._derived_lobes:
            inputs = self.derive_inputs(inputs)
        return self._point.correct(point_mm, stylus_mm, temps_C, inputs, self._refuse(outside))

    def correct_point_with_uncertainty(
        self,
        point_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[Vec3, str, Vec3]:
        """One reading: ``((cx, cy, cz) mm, status, (Ux, Uy, Uz) µm)`` — :meth:`correct_point`
        and U (k = 2 per component) in one call, scalars throughout (the daemon's path). U is
        NaN when the status is not ``ok`` or the grid carries no uncertainty."""
        if self._derived_lobes:
            inputs = self.derive_inputs(inputs)
        refuse = self._refuse(outside)
        return self._point.correct_with_uncertainty(point_mm, stylus_mm, temps_C, inputs, refuse)

    def uncertainty_point(
        self,
        point_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
        *,
        outside: str | None = None,
    ) -> tuple[Vec3, str]:
        """One reading's ``((Ux, Uy, Uz) µm, status)`` (see
        :meth:`correct_point_with_uncertainty`)."""
        _, status, u = self.correct_point_with_uncertainty(
            point_mm, stylus_mm, temps_C, inputs, outside=outside
        )
        return u, status

    def __repr__(self) -> str:
        m = self.metadata.get("machine", {})
        return (
            f"CorrectionGrid(machine={m.get('name')!r}, steps={self.steps}, "
            f"signals={[s.name for s in self.signals]}, outside={self.outside!r})"
        )


def _scalars(
    stylus_mm: ArrayLike, temps_C: Mapping[str, Any] | None, inputs: Mapping[str, Any] | None
) -> tuple[FloatArray, dict[str, float | None] | None, dict[str, float | None] | None] | None:
    """A stylus (3,) and the signal mappings as scalars (None values kept), or None when any
    is an array of more than one value (then the batch path corrects)."""
    sty = np.asarray(stylus_mm, dtype=np.float64)
    if sty.size != 3:
        return None
    maps: list[dict[str, float | None] | None] = []
    for m in (temps_C, inputs):
        if m is None:
            maps.append(None)
            continue
        conv: dict[str, float | None] = {}
        for k, v in m.items():
            arr = np.asarray(v, dtype=np.float64) if v is not None else None
            if arr is not None and arr.size != 1:
                return None
            conv[k] = None if arr is None else float(arr.reshape(()))
        maps.append(conv)
    return sty.reshape(3), maps[0], maps[1]
