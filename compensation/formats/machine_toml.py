"""Reading and writing ``machine.toml`` (docs/formats.md §1).

:func:`read_machine_toml` reads the file, :func:`.machine_parser.parse_machine` validates it into
the parts of a machine, :func:`write_machine_toml` writes a description back and
:func:`description_from_parts` gives the structure of a machine built in Python;
:meth:`Machine.from_toml <cmm_comp.compensation.machine.Machine.from_toml>` and friends put these
together. Nothing here imports the machine module, so there is no import circle.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import tomli_w

from ..effects.base import Effect
from ..errors import MachineFileError
from ..machine_parts import ArmDeflection, Probe, Volume
from ..parametric_errors import AXES
from ..thermal import Thermal
from .atomic import write_text_atomic
from .machine_parser import FORMAT, plain_copy

__all__ = ["description_from_parts", "read_machine_toml", "write_machine_toml"]


def read_machine_toml(path: Path) -> dict[str, Any]:
    """The parsed TOML of a machine description file; :class:`MachineFileError` if unreadable."""
    src = str(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MachineFileError(src, "", f"cannot read the file ({exc.strerror})") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise MachineFileError(src, "", "not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise MachineFileError(src, "", f"invalid TOML: {exc}") from None
    except RecursionError:
        raise MachineFileError(src, "", "invalid TOML: nested too deeply") from None
    return data


def write_machine_toml(description: Mapping[str, Any], path: Path) -> None:
    """Atomic write of a machine's normalised ``description``: nothing is written on failure."""
    data = json.loads(json.dumps(description))
    text = tomli_w.dumps(data)
    write_text_atomic(path, text)


def description_from_parts(
    *,
    name: str,
    model: str,
    volume: Volume,
    probe: Probe,
    thermal: Thermal,
    arm: ArmDeflection,
    error_sections: Mapping[str, Any],
    effects: Sequence[Effect] = (),
) -> dict[str, Any]:
    """The ``machine.toml`` structure of a machine given as Python objects (the inverse of
    :func:`parse_machine`); ``error_sections`` holds its ``errors`` and ``squareness`` tables."""
    vol: dict[str, Any] = {
        a: [float(volume.lower_mm[k]), float(volume.upper_mm[k])] for k, a in enumerate(AXES)
    }
    vol["reference"] = [float(v) for v in volume.reference_mm]
    if volume.steps is not None:
        vol["steps"] = [int(s) for s in volume.steps]
    th: dict[str, Any] = {
        "reference_C": float(thermal.reference_C),
        "expansion": {a: float(thermal.expansion[k]) for k, a in enumerate(AXES)},
    }
    if thermal.workpiece_expansion is not None:
        th["workpiece_expansion"] = float(thermal.workpiece_expansion)
    if thermal.workpiece_fixture_mm is not None:
        th["workpiece_fixture"] = [float(v) for v in thermal.workpiece_fixture_mm]
    data: dict[str, Any] = {
        "format": FORMAT,
        "name": name,
        "model": model,
        "volume": vol,
        "probe": {
            "offset": [float(v) for v in probe.offset_mm],
            "random_um": float(probe.random_um),
        },
        "thermal": th,
        "arm_deflection": {"phi1": float(arm.phi1), "phi2": float(arm.phi2)},
        **{key: plain_copy(value) for key, value in error_sections.items()},
    }
    if effects:
        data["effects"] = [e.to_table() for e in effects]
    return data
