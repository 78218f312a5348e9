"""The identified machine as a ``machine.toml`` description (docs/formats.md §1), loadable by every
command: the plan's model, volume (reference at the lower corner), calibration stylus and thermal
data; the identified tables (spline nodes as tabulated values — exactly what the fit evaluated —
or polynomials), reversals, squareness; ``[uncertainty]`` from the fit's covariance
(:func:`.covariance.table_uncertainty`); ``[meta]`` saying where it came from.
Units: mm, µm, µrad, °C.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError, MachineFileError
from ..parametric_errors import AXES, SQUARENESS, TABLE_COMPONENTS
from .basis import Layout
from .covariance import FunctionBand, table_uncertainty

if TYPE_CHECKING:
    from ..machine import Machine
    from .plan import Plan

__all__ = ["build_machine", "machine_description"]

FloatArray = NDArray[np.float64]


def _base_sections(plan: Plan) -> dict[str, Any]:
    """format, name, model, volume (the plan's grid steps), probe, thermal of the machine file."""
    from ..formats.machine_toml import description_from_parts
    from ..machine_parts import ArmDeflection, Probe, Volume

    vol = plan.base.volume
    data = description_from_parts(
        name=plan.name,
        model=plan.model,
        volume=Volume(vol.lower_mm, vol.upper_mm, vol.reference_mm, plan.steps),
        probe=Probe(offset_mm=plan.stylus_mm),
        thermal=plan.base.thermal,
        arm=ArmDeflection(),
        error_sections={},
    )
    del data["arm_deflection"]  # the plan's machines have none
    return data


def machine_description(
    plan: Plan,
    layout: Layout,
    theta: FloatArray,
    bands: list[FunctionBand],
    sq_u: dict[str, float],
    *,
    probe_um: float | None,
    meta: dict[str, Any],
) -> dict[str, Any]:
    """The ``machine.toml`` structure of the identified machine."""
    data = _base_sections(plan)
    sq = layout.squareness_values(theta)
    data["squareness"] = {name: float(sq[j]) for j, name in enumerate(SQUARENESS)}
    errors: dict[str, Any] = {}
    effects: list[dict[str, Any]] = []
    u_errors: dict[str, Any] = {}
    band_of = {b.name: b for b in bands}
    reference = plan.base.volume.reference_mm
    for fn in layout.functions:
        params = theta[fn.cols]
        if fn.is_reversal:
            continue
        if fn.basis == "spline":
            assert fn.nodes_mm is not None
            entry: dict[str, Any] = {
                "position": [float(v) for v in fn.nodes_mm],
                "value": [float(v) for v in fn.full_values(params)],
            }
        else:
            entry = {"polynomial": [float(v) for v in fn.power_series(params)]}
        errors[fn.name] = entry
        u_errors[fn.name] = table_uncertainty(band_of[fn.name], float(reference[fn.axis]))
    for fn in layout.functions:
        if not fn.is_reversal:
            continue
        params = theta[fn.cols]
        if fn.basis == "hat":
            errors[fn.component]["reversal"] = [float(v) for v in params]
        else:
            effects.append(
                {
                    "cause": "reversal",
                    "axis": AXES[fn.axis],
                    "half_step_um": [float(params[0]), float(params[1])],
                    "span_mm": [fn.lo_mm, fn.hi_mm],
                }
            )
    data["errors"] = errors
    if effects:
        data["effects"] = effects
    unc: dict[str, Any] = {"errors": u_errors}
    if sq_u:
        unc["squareness"] = {k: float(v) for k, v in sq_u.items()}
    if probe_um is not None:
        unc["probe_um"] = float(probe_um)
    data["uncertainty"] = unc
    not_identified = [c for c in TABLE_COMPONENTS if c not in errors]
    note = "identified by cmm-comp calibrate from the plan " + plan.source.name
    if not_identified:
        note += "; held at zero (not identified): " + ", ".join(not_identified)
    data["meta"] = {"note": note, **meta}
    return data


def build_machine(description: dict[str, Any], source: str) -> Machine:
    """Load ``description`` exactly as ``Machine.from_toml`` would (the same checks)."""
    from ..machine import Machine

    try:
        return Machine.from_dict(description, source=source)
    except MachineFileError as exc:  # a bug here, not the user's input: say so plainly
        raise CalibrationError(f"the identified machine does not load: {exc}") from None
