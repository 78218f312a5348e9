"""The machine: its description (FORMATS.md §1) and the exact volumetric error model.

``Machine.volumetric_error`` evaluates the parametric model with full homogeneous transforms
(:mod:`compensation.kinematics`), plus thermal terms, the optional arm-deflection terms of the
horizontal-arm models and any extra effects. Units: positions mm, errors µm, angles µrad, °C.
Error = true − indicated; corrected = indicated + error.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .components import AXES, AXIS_INDEX
from .effects_base import Effect, EvalContext
from .kinematics import (
    ARM_AXIS,
    Chain,
    exact_pose,
    first_order_error,
    first_order_jacobian,
)
from .tables import ErrorTable

FloatArray = NDArray[np.float64]

#: Temperature signal names (FORMATS.md §2, §5).
TEMPERATURE_SIGNALS: tuple[str, ...] = ("T_x", "T_y", "T_z", "T_wp", "T_top", "T_bottom", "T_air")


@dataclass(frozen=True)
class Volume:
    """Working volume (mm), the reference point all parametric errors refer to, default steps."""

    lower_mm: FloatArray
    upper_mm: FloatArray
    reference_mm: FloatArray
    steps: tuple[int, int, int] | None = None

    def contains(self, points_mm: FloatArray, tol_mm: float = 1e-9) -> NDArray[np.bool_]:
        p = np.asarray(points_mm, dtype=float)
        return np.all((p >= self.lower_mm - tol_mm) & (p <= self.upper_mm + tol_mm), axis=-1)

    def nodes(self, steps: tuple[int, int, int]) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Node coordinates along x, y, z for ``steps`` nodes per axis (paper: "13 steps")."""
        return tuple(  # type: ignore[return-value]
            np.linspace(self.lower_mm[k], self.upper_mm[k], int(steps[k])) for k in range(3)
        )


@dataclass(frozen=True)
class Probe:
    offset_mm: FloatArray  # stylus tip offset (Xp, Yp, Zp)
    random_um: float = 0.0  # random probing error (2σ)


@dataclass(frozen=True)
class Thermal:
    reference_C: float = 20.0
    expansion: FloatArray = field(default_factory=lambda: np.zeros(3))  # µm/(m·°C) per axis scale
    workpiece_expansion: float | None = None  # µm/(m·°C)
    workpiece_fixture_mm: FloatArray | None = None


@dataclass(frozen=True)
class ArmDeflection:
    """The φ terms of the horizontal-arm models (not rigid-body; see docs/seed-equations.md).

    ``phi1`` µrad per m of arm travel: a load-dependent tilt (MH1: ΔX += φ1·x·z; MH2: ΔY += φ1·y·z);
    ``phi2`` µrad per m: the arm's droop curvature (MH1: ΔZ −= φ2·x²/2; MH2: ΔZ += φ2·y²/2).
    """

    phi1: float = 0.0
    phi2: float = 0.0


@dataclass(frozen=True)
class PoseError:
    """Error pose of the stylus frame relative to the workpiece at N points.

    ``volumetric_error(p) = translation_um + 1000·(rotation − I)·p`` exactly (p in mm).
    """

    rotation: FloatArray  # (N, 3, 3), R_work_stylus error rotation
    translation_um: FloatArray  # (N, 3)

    def error_um(self, stylus_mm: ArrayLike) -> FloatArray:
        p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), self.translation_um.shape)
        return self.translation_um + 1000.0 * np.einsum("nij,nj->ni", self.rotation - np.eye(3), p)


@dataclass
class Machine:
    """A CMM described by its kinematic model, 21 parametric errors, thermal data and effects."""

    name: str
    model: str
    chain: Chain
    volume: Volume
    probe: Probe
    thermal: Thermal
    squareness_urad: FloatArray  # (α, β1, β2)
    tables: dict[str, ErrorTable]
    squareness_random_urad: FloatArray = field(default_factory=lambda: np.zeros(3))
    arm: ArmDeflection = field(default_factory=ArmDeflection)
    effects: list[Effect] = field(default_factory=list)
    description: dict[str, Any] = field(default_factory=dict)  # normalised TOML content
    source: str = "<memory>"
    warnings: list[str] = field(default_factory=list)  # accepted but questionable input

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_toml(cls, path: str | Path) -> Machine:
        """Load ``machine.toml`` (FORMATS.md §1); :class:`MachineFileError` on any problem."""
        from .machine_io import load_machine

        return load_machine(Path(path))

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], *, source: str = "<dict>", base_dir: Path | None = None
    ) -> Machine:
        """Build from the parsed TOML structure (same rules and errors as :meth:`from_toml`)."""
        from .machine_io import machine_from_dict

        return machine_from_dict(data, source=source, base_dir=base_dir or Path.cwd())

    def to_toml(self, path: str | Path) -> None:
        """Write a self-contained description (tables inline) that loads back to this machine."""
        from .machine_io import write_machine

        write_machine(self, Path(path))

    def with_effects(self, effects: list[Effect]) -> Machine:
        """A copy of this machine with ``effects`` added (the description is updated too)."""
        from .machine_io import machine_from_dict

        data = json.loads(json.dumps(self.description))
        data["effects"] = list(data.get("effects", [])) + [e.to_table() for e in effects]
        return machine_from_dict(data, source=self.source, base_dir=Path.cwd())

    # ------------------------------------------------------------------ identity
    def identity_sha256(self) -> str:
        """SHA-256 of the normalised description: changes whenever the model changes."""
        blob = json.dumps(self.description, sort_keys=True, separators=(",", ":"), default=float)
        return hashlib.sha256(blob.encode()).hexdigest()

    def runtime_signals(self) -> dict[str, float]:
        """Runtime inputs the model depends on, with their reference values."""
        ref = self.thermal.reference_C
        out: dict[str, float] = {}
        for k, axis in enumerate(AXES):
            if self.thermal.expansion[k] != 0.0:
                out[f"T_{axis}"] = ref
        if self.thermal.workpiece_expansion:
            out["T_wp"] = ref
        for table in self.tables.values():
            if table.reversal is not None:
                out[f"dir_{table.component.axis}"] = 0.0
        for effect in self.effects:
            for name, neutral in effect.signals().items():
                out.setdefault(name, neutral)  # the machine's own neutral values win
        return out

    # ------------------------------------------------------------------ evaluation
    def parametric_errors(self, q_mm: FloatArray) -> FloatArray:
        """(N, 3 axes, 6) parametric errors (µm, µrad) at indicated positions ``q_mm`` (N, 3)."""
        q = np.asarray(q_mm, dtype=float)
        out = np.zeros((q.shape[0], 3, 6))
        for table in self.tables.values():
            c = table.component
            out[:, AXIS_INDEX[c.axis], c.slot] += table.evaluate(q[:, AXIS_INDEX[c.axis]])
        return out

    def _errors_with_reversal(self, q: FloatArray, signals: dict[str, FloatArray]) -> FloatArray:
        errors = self.parametric_errors(q)
        for table in self.tables.values():
            if table.reversal is not None:
                k = AXIS_INDEX[table.component.axis]
                direction = signals.get(f"dir_{table.component.axis}")
                if direction is not None:
                    errors[:, k, k] += np.clip(direction, -1.0, 1.0) * table.evaluate_reversal(
                        q[:, k]
                    )
        return errors

    def _context(
        self,
        points_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
    ) -> EvalContext:
        q = _as_points(points_mm)
        n = q.shape[0]
        signals = _signals(n, self.thermal.reference_C, temps_C, inputs)
        ctx = EvalContext(
            q_mm=q,
            u_mm=q - self.volume.reference_mm,
            signals=signals,
            errors=self._errors_with_reversal(q, signals),
            squareness_urad=np.broadcast_to(self.squareness_urad, (n, 3)).copy(),
            direct_um=np.zeros((n, 3)),
            reference_C=self.thermal.reference_C,
            reference_mm=self.volume.reference_mm,
        )
        for effect in self.effects:
            effect.transform_signals(ctx)
        for effect in self.effects:
            effect.modify_errors(ctx)
        self._thermal_terms(ctx)
        self._arm_terms(ctx)
        for effect in self.effects:
            effect.add_direct(ctx)
        return ctx

    def pose_error(
        self,
        points_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> PoseError:
        """Exact error pose (rotation, translation µm) of the stylus frame at indicated points."""
        ctx = self._context(points_mm, temps_C, inputs)
        rot, t_um = exact_pose(self.chain, ctx.u_mm, ctx.errors, ctx.squareness_urad)
        return PoseError(rotation=rot, translation_um=t_um + ctx.direct_um)

    def volumetric_error(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        *,
        inputs: Mapping[str, Any] | None = None,
        method: str = "exact",
    ) -> FloatArray:
        """Volumetric error (N, 3) µm at indicated ``points_mm`` (N, 3) for a stylus offset (mm).

        ``temps_C`` maps temperature names (``T_x`` … ``T_air``) to scalars or (N,) arrays;
        ``inputs`` any other runtime signal (``dir_x`` …, ``nx`` …, ``t``). ``method`` is
        ``"exact"`` (full rigid-body transforms) or ``"first_order"`` (the paper's A.1 form).
        """
        ctx = self._context(points_mm, temps_C, inputs)
        p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), ctx.q_mm.shape)
        if method == "exact":
            rot, t_um = exact_pose(self.chain, ctx.u_mm, ctx.errors, ctx.squareness_urad)
            rigid = t_um + 1000.0 * np.einsum("nij,nj->ni", rot - np.eye(3), p)
        elif method == "first_order":
            rigid = first_order_error(self.chain, ctx.u_mm, ctx.errors, ctx.squareness_urad, p)
        else:
            raise ValueError(f"method must be 'exact' or 'first_order', got {method!r}")
        return rigid + ctx.direct_um

    def random_error(
        self, points_mm: ArrayLike, stylus_mm: ArrayLike = (0.0, 0.0, 0.0)
    ) -> FloatArray:
        """Random volumetric error (N, 3) µm (2σ), the paper's propagation formula (§5.1).

        ``RΔX_i = sqrt(Σ_j (∂ΔX_i/∂E_j · ΔRE_j)² + ΔXp²)`` with the first-order partial
        derivatives of the chain and the random parts ΔRE_j of the 21 errors (2σ bands).
        """
        q = _as_points(points_mm)
        p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), q.shape)
        jac, sq = first_order_jacobian(self.chain, q - self.volume.reference_mm, p)
        rnd = np.zeros((q.shape[0], 3, 6))
        for table in self.tables.values():
            c = table.component
            rnd[:, AXIS_INDEX[c.axis], c.slot] = np.hypot(
                rnd[:, AXIS_INDEX[c.axis], c.slot], table.evaluate_random(q[:, AXIS_INDEX[c.axis]])
            )
        var = np.einsum("nias,nas->ni", jac**2, rnd**2) + np.einsum(
            "nij,j->ni", sq**2, self.squareness_random_urad**2
        )
        return np.sqrt(var + self.probe.random_um**2)

    @property
    def has_random(self) -> bool:
        return (
            any(t.has_random for t in self.tables.values())
            or bool(np.any(self.squareness_random_urad))
            or self.probe.random_um > 0
        )

    # ------------------------------------------------------------------ built-in terms
    def _thermal_terms(self, ctx: EvalContext) -> None:
        """FORMATS.md §1: α_j·(T_j − T_ref)·(q_j − ref_j)/1000 per axis; workpiece about fixture."""
        ref_c = self.thermal.reference_C
        for k, axis in enumerate(AXES):
            alpha = self.thermal.expansion[k]
            if alpha:
                dt = ctx.signals[f"T_{axis}"] - ref_c
                ctx.direct_um[:, k] += alpha * dt * ctx.u_mm[:, k] / 1000.0
        if self.thermal.workpiece_expansion:
            fixture = (
                self.thermal.workpiece_fixture_mm
                if self.thermal.workpiece_fixture_mm is not None
                else self.volume.reference_mm
            )
            dt = ctx.signals["T_wp"] - ref_c
            ctx.direct_um -= (
                self.thermal.workpiece_expansion * dt[:, None] * (ctx.q_mm - fixture) / 1000.0
            )

    def _arm_terms(self, ctx: EvalContext) -> None:
        if self.model not in ARM_AXIS or (self.arm.phi1 == 0.0 and self.arm.phi2 == 0.0):
            return
        u = ctx.u_mm
        if self.model == "MH1":
            ctx.direct_um[:, 0] += self.arm.phi1 * u[:, 0] * u[:, 2] * 1e-6
            ctx.direct_um[:, 2] -= self.arm.phi2 * u[:, 0] ** 2 / 2 * 1e-6
        else:  # MH2
            ctx.direct_um[:, 1] += self.arm.phi1 * u[:, 1] * u[:, 2] * 1e-6
            ctx.direct_um[:, 2] += self.arm.phi2 * u[:, 1] ** 2 / 2 * 1e-6


def _as_points(points_mm: ArrayLike) -> FloatArray:
    q = np.asarray(points_mm, dtype=float)
    if q.ndim == 1 and q.shape[0] == 3:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != 3:
        raise ValueError(f"points must be an (N, 3) array of mm, got shape {q.shape}")
    return q


def _signals(
    n: int, reference_C: float, temps_C: Mapping[str, Any] | None, inputs: Mapping[str, Any] | None
) -> dict[str, FloatArray]:
    out: dict[str, FloatArray] = {name: np.full(n, reference_C) for name in TEMPERATURE_SIGNALS}
    for mapping in (temps_C, inputs):
        if not mapping:
            continue
        for key, value in mapping.items():
            if value is None:
                continue
            arr = np.asarray(value, dtype=float)
            if arr.ndim == 0:
                arr = np.full(n, float(arr))
            if arr.shape != (n,):
                raise ValueError(
                    f"signal {key!r} must be a scalar or have shape ({n},), got {arr.shape}"
                )
            out[key] = arr
    return out
