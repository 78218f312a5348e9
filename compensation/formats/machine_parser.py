"""A machine description (the ``machine.toml`` structure, docs/formats.md §1) checked
(:mod:`.machine_schema`: every problem at once, one :class:`MachineFileError` naming the source
and each key) and built into the parts of a machine (:class:`ParsedMachine`). Reading and
writing the file itself is :mod:`.machine_toml`. Units as in the file: positions mm, linear
errors µm, angles µrad, °C.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..effects.base import Effect, effect_from_table
from ..errors import MachineFileError, SchemaError
from ..kinematics import MODEL_CHAINS, Chain
from ..machine_parts import ArmDeflection, Probe, Volume
from ..parametric_errors import AXES, canonical_name, parse_component
from ..tables import ErrorTable
from ..thermal import Thermal
from ..toml_schema import validate
from ..uncertainty.model import UncertaintyModel, resolve_uncertainty
from .machine_schema import CRITERIA, FORMAT, ErrorTableSection, MachineFile

__all__ = ["CRITERIA", "FORMAT", "ParsedMachine", "parse_machine", "plain_copy"]


@dataclass
class ParsedMachine:
    """A validated machine description: the keyword arguments of ``Machine`` plus the squareness
    measurement offset, which is applied once the machine exists (:mod:`..offsets`)."""

    name: str
    model: str
    chain: Chain
    volume: Volume
    probe: Probe
    thermal: Thermal
    squareness_urad: np.ndarray
    squareness_random_urad: np.ndarray
    squareness_offset_mm: np.ndarray | None
    tables: dict[str, ErrorTable]
    arm: ArmDeflection
    effects: list[Effect]
    description: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    uncertainty: UncertaintyModel | None = None


def parse_machine(data: Mapping[str, Any], *, source: str, base_dir: Path) -> ParsedMachine:
    """Check the TOML structure ``data`` (tables named in ``file`` keys are read relative to
    ``base_dir``) and build its parts; :class:`MachineFileError` listing every problem, each
    naming ``source`` and the key."""
    try:
        doc: MachineFile = validate(MachineFile, data, source, {"base_dir": base_dir})
    except SchemaError as exc:
        raise MachineFileError.from_schema(exc, source) from None
    model = doc.model_code()
    chain = doc.chain.chain() if doc.chain is not None else MODEL_CHAINS[model]
    vol = doc.volume
    lower = np.array([vol.x[0], vol.y[0], vol.z[0]], dtype=float)
    upper = np.array([vol.x[1], vol.y[1], vol.z[1]], dtype=float)
    volume = Volume(
        lower_mm=lower,
        upper_mm=upper,
        reference_mm=lower.copy() if vol.reference is None else np.array(vol.reference, float),
        steps=None if vol.steps is None else (vol.steps[0], vol.steps[1], vol.steps[2]),
    )
    probe = Probe(offset_mm=np.array(doc.probe.offset, float), random_um=doc.probe.random_um)
    th = doc.thermal
    thermal = Thermal(
        reference_C=th.reference_C,
        expansion=np.array([getattr(th.expansion, a) for a in AXES], dtype=float),
        workpiece_expansion=th.workpiece_expansion,
        workpiece_fixture_mm=None
        if th.workpiece_fixture is None
        else np.array(th.workpiece_fixture, float),
    )
    warnings: list[str] = []
    tables: dict[str, ErrorTable] = {}
    normalised: dict[str, Any] = {}
    for key, section in doc.errors.items():
        canon = str(canonical_name(key))
        tables[canon], normalised[canon] = _error_table(canon, section, source, warnings)
    sq = doc.squareness
    uncertainty = resolve_uncertainty(
        doc.uncertainty,
        tables=tables,
        lower_mm=volume.lower_mm,
        upper_mm=volume.upper_mm,
        reference_mm=volume.reference_mm,
        expansion=thermal.expansion,
        workpiece_expansion=thermal.workpiece_expansion,
        probe_random_um=probe.random_um,
        given=data.get("uncertainty") if isinstance(data.get("uncertainty"), Mapping) else None,
    )
    description = plain_copy(data)
    description["format"] = FORMAT
    description["model"] = model
    description["errors"] = normalised
    return ParsedMachine(
        name=doc.name.strip(),
        model=model,
        chain=chain,
        volume=volume,
        probe=probe,
        thermal=thermal,
        squareness_urad=sq.values(),
        squareness_random_urad=sq.random.values(),
        squareness_offset_mm=None if sq.offset is None else np.array(sq.offset, float),
        tables=tables,
        arm=ArmDeflection(phi1=doc.arm_deflection.phi1, phi2=doc.arm_deflection.phi2),
        effects=[effect_from_table(t) for t in doc.effects],
        description=description,
        warnings=warnings,
        uncertainty=uncertainty,
    )


def _error_table(
    canon: str, section: ErrorTableSection, source: str, warnings: list[str]
) -> tuple[ErrorTable, dict[str, Any]]:
    """The :class:`ErrorTable` of a checked ``[errors.<canon>]`` and its normalised table."""
    comp = parse_component(canon)
    norm: dict[str, Any] = {}
    position = value = poly = random = reversal = None
    tabulated = section.tabulated()
    if tabulated is not None:
        position, value, random = tabulated
        if section.reversal is not None:
            reversal = np.array(section.reversal, dtype=float)
            norm["reversal"] = reversal.tolist()
        norm.update(position=position.tolist(), value=value.tolist())
        if random is not None:
            norm["random"] = random.tolist()
    elif section.polynomial is not None:
        poly = np.array(section.polynomial, dtype=float)
        norm["polynomial"] = poly.tolist()
    elif section.curve is not None:
        poly = section.curve.polynomial()
        norm["polynomial"] = poly.tolist()
    band = section.random_band
    if band is not None:
        norm["random_band"] = band
    offset = None
    if section.offset is not None:
        offset = np.array(section.offset, dtype=float)
        norm["offset"] = offset.tolist()
    criterion = section.criterion
    if criterion is not None and not comp.is_straightness:
        warnings.append(
            f"{source}: errors.{canon}.criterion: a straightness criterion applies to "
            f"straightness tables only; ignored for {canon}"
        )
        criterion = None
    if criterion is not None:
        norm["criterion"] = criterion
    table = ErrorTable(
        component=comp,
        position_mm=position,
        value=value,
        polynomial=poly,
        random_2sigma=random,
        random_band=band,
        offset_mm=offset,
        criterion=criterion,
        reversal=reversal,
        source=dict(norm),
    )
    return table, norm


def plain_copy(data: Mapping[str, Any]) -> dict[str, Any]:
    """A JSON-able deep copy of the parsed TOML (for hashing and writing back)."""
    return json.loads(json.dumps(data, default=str))
