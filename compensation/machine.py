"""The machine: its description (docs/formats.md §1) and the exact volumetric error model.

``Machine.volumetric_error`` evaluates the parametric model with full homogeneous transforms
(:mod:`compensation.kinematics`), plus thermal terms, the optional arm-deflection terms of the
horizontal-arm models and any extra effects. Units: positions mm, errors µm, angles µrad, °C.
Error = true − indicated; corrected = indicated + error.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .effects.base import Effect, EvalContext
from .errors import MachineFileError
from .kinematics import (
    ARM_AXIS,
    Chain,
    exact_pose,
    first_order_error,
    first_order_jacobian,
)
from .machine_parts import ArmDeflection, Probe, Volume
from .offsets import refer_to_reference
from .parametric_errors import AXIS_INDEX, ParametricErrors, canonical_name, names_as_written
from .tables import ErrorTable
from .thermal import TEMPERATURE_ROLES, Thermal
from .uncertainty.model import UncertaintyModel

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PoseError:
    """Error pose of the stylus frame relative to the workpiece at N points.

    ``volumetric_error(p) = translation_um + 1000·(rotation − I)·p`` exactly (p in mm).
    """

    rotation: FloatArray  # (N, 3, 3), R_work_stylus error rotation
    translation_um: FloatArray  # (N, 3)

    def error_um(self, stylus_mm: ArrayLike) -> FloatArray:
        """Error (N, 3) µm for the stylus offset ``stylus_mm`` (mm, required: a pose does not know
        the machine; pass ``machine.probe.offset_mm`` for the machine's default)."""
        p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), self.translation_um.shape)
        return self.translation_um + 1000.0 * np.einsum("nij,nj->ni", self.rotation - np.eye(3), p)


def _written_names(data: Mapping[str, Any]) -> dict[str, str]:
    """Our name → the key the description used, for its ``[errors.*]`` tables and its
    ``[uncertainty.errors.*]`` (keys checked by the parser: unknown ones are not here)."""
    out: dict[str, str] = {}
    unc = data.get("uncertainty")
    sections = [data.get("errors"), unc.get("errors") if isinstance(unc, Mapping) else None]
    for section in sections:
        for key in section if isinstance(section, Mapping) else ():
            canon = canonical_name(str(key))
            if canon is not None:
                out.setdefault(canon, str(key))
    return out


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
    uncertainty: UncertaintyModel | None = None  # [uncertainty], defaults resolved
    #: our component name → the name the file used (``EXX`` …; :meth:`error_label`)
    error_names: dict[str, str] = field(default_factory=dict)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_toml(cls, path: str | Path) -> Machine:
        """Load ``machine.toml`` (docs/formats.md §1); :class:`MachineFileError` on any problem."""
        from .formats.machine_toml import read_machine_toml

        path = Path(path)
        return cls.from_dict(read_machine_toml(path), source=str(path), base_dir=path.parent)

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], *, source: str = "<dict>", base_dir: Path | None = None
    ) -> Machine:
        """Build from the parsed TOML structure (same rules and errors as :meth:`from_toml`)."""
        from .formats.machine_parser import parse_machine

        base = base_dir or Path.cwd()
        parsed = parse_machine(data, source=source, base_dir=base)
        machine = cls(
            name=parsed.name,
            model=parsed.model,
            chain=parsed.chain,
            volume=parsed.volume,
            probe=parsed.probe,
            thermal=parsed.thermal,
            squareness_urad=parsed.squareness_urad,
            tables=parsed.tables,
            squareness_random_urad=parsed.squareness_random_urad,
            arm=parsed.arm,
            effects=parsed.effects,
            description=parsed.description,
            source=source,
            warnings=parsed.warnings,
            uncertainty=parsed.uncertainty,
            error_names=_written_names(data),
        )
        try:
            refer_to_reference(machine, parsed.squareness_offset_mm)
        except ValueError as exc:
            raise MachineFileError(source, "errors", str(exc)) from None
        _check_magnitudes(machine)
        return machine

    @classmethod
    def from_parts(
        cls,
        *,
        model: str,
        volume: Volume | Sequence[Sequence[float]],
        errors: ParametricErrors | None = None,
        probe: Probe | Sequence[float] | None = None,
        thermal: Thermal | None = None,
        arm: ArmDeflection | None = None,
        effects: Sequence[Effect] = (),
        name: str = "machine",
    ) -> Machine:
        """A machine from Python objects, without writing a TOML-shaped dict.

        ``model`` a code or alias (``"MB1"`` or ``"moving_bridge"``, :mod:`.models`);
        ``volume`` a :class:`Volume` or ``((x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi))`` mm (the
        reference point is then the lower corner); ``errors`` from
        :meth:`ParametricErrors.from_polynomials` / :meth:`~ParametricErrors.from_tables`
        (None: all zero); ``probe`` a :class:`Probe` or the stylus offset (Xp, Yp, Zp) mm.
        Built through :meth:`from_dict`, so the checks, offsets and ``description`` are those of
        an equivalent ``machine.toml`` (:meth:`to_toml` writes it).
        """
        from .formats.machine_toml import description_from_parts

        if not isinstance(volume, Volume):
            lower, upper = np.array([[float(v) for v in pair] for pair in volume]).T
            volume = Volume(lower_mm=lower, upper_mm=upper, reference_mm=lower.copy())
        if not isinstance(probe, Probe):
            offset = np.zeros(3) if probe is None else np.asarray(probe, dtype=float)
            probe = Probe(offset_mm=offset)
        data = description_from_parts(
            name=name,
            model=model,
            volume=volume,
            probe=probe,
            thermal=thermal or Thermal(),
            arm=arm or ArmDeflection(),
            error_sections=(errors or ParametricErrors()).toml_sections(),
            effects=effects,
        )
        return cls.from_dict(data, source="<python>")

    def to_toml(self, path: str | Path) -> None:
        """Write a self-contained description (tables inline) that loads back to this machine,
        each error table under the name the file used (ISO 230-1 or ours)."""
        from .formats.machine_toml import write_machine_toml

        write_machine_toml(self._description_as_written(), Path(path))

    def _description_as_written(self) -> dict[str, Any]:
        data = json.loads(json.dumps(self.description))
        errors = data.get("errors")
        if isinstance(errors, dict):
            data["errors"] = {self.error_names.get(k, k): v for k, v in errors.items()}
        return data

    def with_effects(self, effects: list[Effect]) -> Machine:
        """A copy of this machine with ``effects`` added (the description is updated too)."""
        data = self._description_as_written()
        data["effects"] = list(data.get("effects", [])) + [e.to_table() for e in effects]
        return type(self).from_dict(data, source=self.source, base_dir=Path.cwd())

    def error_label(self, component: str) -> str:
        """The name to show a user for a table component (ours or ISO): the one the file used,
        or for a component it did not name, the convention it used (ISO 230-1 or ours)."""
        canon = canonical_name(component) or component
        return names_as_written(self.error_names).get(canon, component)

    # ------------------------------------------------------------------ identity
    def identity_sha256(self) -> str:
        """SHA-256 of the normalised description: changes whenever the model changes."""
        blob = json.dumps(self.description, sort_keys=True, separators=(",", ":"), default=float)
        return hashlib.sha256(blob.encode()).hexdigest()

    def runtime_signals(self) -> dict[str, float]:
        """Runtime inputs the model depends on, with their reference values."""
        out = self.thermal.runtime_signals()
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
        self.thermal.add_expansion(ctx)
        self._arm_terms(ctx)
        for effect in self.effects:
            effect.add_direct(ctx)
        return ctx

    def context(
        self,
        points_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> EvalContext:
        """The model's evaluation context at indicated ``points_mm`` (N, 3): parametric errors
        after reversal and effects (N, 3, 6), squareness (N, 3), the direct terms (thermal,
        effects) µm and the signals. What the virtual CMM (:mod:`.uncertainty`) perturbs."""
        return self._context(points_mm, temps_C, inputs)

    def uncertainty_model(self) -> UncertaintyModel:
        """The machine's uncertainty model (``[uncertainty]``, docs/formats.md §1.11) with its
        defaults resolved; built from the defaults alone for a machine made without a file."""
        if self.uncertainty is not None:
            return self.uncertainty
        from .uncertainty.model import resolve_uncertainty

        return resolve_uncertainty(
            None,
            tables=self.tables,
            lower_mm=self.volume.lower_mm,
            upper_mm=self.volume.upper_mm,
            reference_mm=self.volume.reference_mm,
            expansion=self.thermal.expansion,
            workpiece_expansion=self.thermal.workpiece_expansion,
            probe_random_um=self.probe.random_um,
        )

    def stylus_or_probe(self, stylus_mm: ArrayLike | None) -> FloatArray:
        """``stylus_mm`` as floats, or the machine's probe offset when it is None (the default
        stylus of every function that takes one)."""
        return np.asarray(self.probe.offset_mm if stylus_mm is None else stylus_mm, dtype=float)

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
        stylus_mm: ArrayLike | None = None,
        temps_C: Mapping[str, Any] | None = None,
        *,
        inputs: Mapping[str, Any] | None = None,
        method: str = "exact",
    ) -> FloatArray:
        """Volumetric error (N, 3) µm at indicated ``points_mm`` (N, 3) for a stylus offset (mm).

        ``stylus_mm`` (3,) or (N, 3); None (the default) is the machine's probe offset
        (``probe.offset_mm``), as for the map, diagonals and line reports.

        ``temps_C`` maps temperature names (``T_x`` … ``T_air``) to scalars or (N,) arrays;
        ``inputs`` any other runtime signal (``dir_x`` …, ``nx`` …, ``t``). ``method`` is
        ``"exact"`` (full rigid-body transforms) or ``"first_order"`` (the paper's A.1 form).
        """
        ctx = self._context(points_mm, temps_C, inputs)
        p = np.broadcast_to(self.stylus_or_probe(stylus_mm), ctx.q_mm.shape)
        if method == "exact":
            rot, t_um = exact_pose(self.chain, ctx.u_mm, ctx.errors, ctx.squareness_urad)
            rigid = t_um + 1000.0 * np.einsum("nij,nj->ni", rot - np.eye(3), p)
        elif method == "first_order":
            rigid = first_order_error(self.chain, ctx.u_mm, ctx.errors, ctx.squareness_urad, p)
        else:
            raise ValueError(f"method must be 'exact' or 'first_order', got {method!r}")
        return rigid + ctx.direct_um

    def random_error(self, points_mm: ArrayLike, stylus_mm: ArrayLike | None = None) -> FloatArray:
        """Random volumetric error (N, 3) µm (2σ), the paper's propagation formula (§5.1).

        ``stylus_mm`` (mm) None (the default) is the machine's probe offset.

        ``RΔX_i = sqrt(Σ_j (∂ΔX_i/∂E_j · ΔRE_j)² + ΔXp²)`` with the first-order partial
        derivatives of the chain and the random parts ΔRE_j of the 21 errors (2σ bands).
        """
        q = _as_points(points_mm)
        p = np.broadcast_to(self.stylus_or_probe(stylus_mm), q.shape)
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
    out: dict[str, FloatArray] = {name: np.full(n, reference_C) for name in TEMPERATURE_ROLES}
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


#: Largest |value| of a linear error (µm: 1 km) and of an angle (µrad: 1 rad) in the volume: beyond
#: them a value is a unit mistake or a corrupt table, not a machine error (an angle of 1e300 µrad
#: wrapped through sin/cos into plausible mm; a 1e300 µm error overflowed every RMS to inf).
MAX_LINEAR_UM = 1e9
MAX_ANGLE_URAD = 1e6


def _check_magnitudes(machine: Machine) -> None:
    """MachineFileError naming every error table (systematic or random part) and squareness
    whose value within the working volume is not finite or beyond the limits above."""
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    problems: list[tuple[str, str]] = []
    for name, table in machine.tables.items():
        c = table.component
        k = AXIS_INDEX[c.axis]
        q = np.linspace(lo[k], hi[k], 201)
        if table.position_mm is not None:
            inside = table.position_mm[(table.position_mm >= lo[k]) & (table.position_mm <= hi[k])]
            q = np.union1d(q, inside)
        limit = MAX_ANGLE_URAD if c.is_angular else MAX_LINEAR_UM
        for part, values in (("value", table.evaluate(q)), ("random", table.evaluate_random(q))):
            with np.errstate(invalid="ignore"):
                bad = ~(np.abs(values) <= limit)
            if bad.any():
                i = int(np.argmax(bad))
                problems.append(
                    (
                        f"errors.{name}",
                        f"{part} reaches {values[i]:g} {c.unit} at {c.axis} = {q[i]:g} mm: beyond "
                        f"±{limit:g} {c.unit} it is no machine error (check the values and the "
                        f"unit, {c.unit})",
                    )
                )
    for what, values in (
        ("squareness", machine.squareness_urad),
        ("squareness random", machine.squareness_random_urad),
    ):
        if not np.all(np.abs(values) <= MAX_ANGLE_URAD):
            problems.append(
                (
                    what,
                    f"{np.asarray(values).tolist()} urad: beyond ±{MAX_ANGLE_URAD:g} urad it is "
                    "no machine error (check the values and the unit, urad)",
                )
            )
    if problems:
        where, problem = problems[0]
        lines = [f"{machine.source}: {w}: {p}" for w, p in problems]
        raise MachineFileError(machine.source, where, problem, lines=lines)
