"""compensation: the parametric volumetric error model of a CMM and its correction grid.

Fixed entry points (FORMATS.md §5)::

    from cmm_comp.compensation import Machine, CorrectionGrid
    machine = Machine.from_toml("machine.toml")
    err_um = machine.volumetric_error(points_mm, stylus_mm=(0, 0, 0), temps_C=None)

Units: positions mm, linear errors µm, angles µrad, temperatures °C; error = true − indicated.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .components import ALL_COMPONENTS, ISO_ALIASES, TABLE_COMPONENTS, Component, parse_component
from .diagnosis import Diagnosis, diagnose
from .effects_base import Effect, EvalContext, effect_from_table, known_causes, register_effect
from .errors import CmmCompError, MachineFileError, MeasurementFileError
from .kinematics import MODEL_CHAINS, Chain, exact_pose, first_order_error, first_order_jacobian
from .machine import Machine, PoseError, Volume
from .maps import (
    LineReport,
    VolumetricMap,
    diagonal_endpoints,
    diagonals_um,
    length_error_um,
    line_report,
    volumetric_map,
)
from .measurements import Measurements, read_measurements, write_measurements
from .seedfiles import find_seed_machines, load_seed_fileset, write_seed_fileset
from .straightness import CRITERIA, apply_criterion, reference_line, straightness_um
from .tables import ErrorTable

if TYPE_CHECKING:
    from .grid import CorrectionGrid, GridFileError

__all__ = [
    "ALL_COMPONENTS",
    "CRITERIA",
    "ISO_ALIASES",
    "MODEL_CHAINS",
    "TABLE_COMPONENTS",
    "Chain",
    "CmmCompError",
    "Component",
    "CorrectionGrid",
    "Diagnosis",
    "Effect",
    "ErrorTable",
    "EvalContext",
    "GridFileError",
    "LineReport",
    "Machine",
    "MachineFileError",
    "MeasurementFileError",
    "Measurements",
    "PoseError",
    "Volume",
    "VolumetricMap",
    "apply_criterion",
    "diagnose",
    "diagonal_endpoints",
    "diagonals_um",
    "effect_from_table",
    "exact_pose",
    "find_seed_machines",
    "first_order_error",
    "first_order_jacobian",
    "known_causes",
    "length_error_um",
    "line_report",
    "load_seed_fileset",
    "parse_component",
    "read_measurements",
    "reference_line",
    "register_effect",
    "straightness_um",
    "volumetric_map",
    "write_measurements",
    "write_seed_fileset",
]


def __getattr__(name: str) -> Any:
    # The grid pulls in numba; import it only when asked for.
    if name in ("CorrectionGrid", "GridFileError"):
        from . import grid

        return getattr(grid, name)
    raise AttributeError(f"module 'compensation' has no attribute {name!r}")
