"""compensation: the parametric volumetric error model of a CMM and its correction grid.

Fixed entry points (docs/formats.md §5)::

    from cmm_comp.compensation import Machine, CorrectionGrid
    machine = Machine.from_toml("machine.toml")
    err_um = machine.volumetric_error(points_mm, temps_C=None)  # stylus: machine.probe.offset_mm

or in Python, without a file::

    errors = ParametricErrors.from_polynomials({"dx_x": [0.0, 2e-3], "ez_x": [0.0, 0.0, 1e-5]})
    machine = Machine.from_parts(model="moving_bridge", volume=[(0, 900), (0, 1150), (0, 400)],
                                 errors=errors, probe=(0, 0, -120))

Every function taking ``stylus_mm`` defaults it to the machine's probe offset. The ten models:
:func:`model_table`, :func:`describe_model` (``"MB1"`` ↔ ``"moving_bridge"``).

Units: positions mm, linear errors µm, angles µrad, temperatures °C; error = true − indicated.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .diagnosis import Diagnosis, diagnose
from .effects import Effect, EvalContext, effect_from_table, known_causes, register_effect
from .errors import (
    CmmCompError,
    GridFileError,
    MachineFileError,
    MeasurementFileError,
    RealDataError,
)
from .formats.measurements import Measurements, read_measurements, write_measurements
from .formats.seedfiles import find_seed_machines, load_seed_fileset, write_seed_fileset
from .kinematics import MODEL_CHAINS, Chain, exact_pose, first_order_error, first_order_jacobian
from .machine import Machine, PoseError
from .machine_parts import ArmDeflection, Probe, Volume
from .models import MODEL_ALIASES, describe_model, model_code, model_table
from .parametric_errors import (
    ALL_COMPONENTS,
    ISO_ALIASES,
    TABLE_COMPONENTS,
    Component,
    ParametricErrors,
    parse_component,
)
from .reports.maps import (
    LineReport,
    VolumetricMap,
    diagonal_endpoints,
    diagonals_um,
    length_error_um,
    line_report,
    volumetric_map,
)
from .straightness import CRITERIA, apply_criterion, reference_line, straightness_um
from .tables import ErrorTable

if TYPE_CHECKING:
    from .grid import CorrectionGrid

__all__ = [
    "ALL_COMPONENTS",
    "CRITERIA",
    "ISO_ALIASES",
    "MODEL_ALIASES",
    "MODEL_CHAINS",
    "TABLE_COMPONENTS",
    "ArmDeflection",
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
    "ParametricErrors",
    "PoseError",
    "Probe",
    "RealDataError",
    "Volume",
    "VolumetricMap",
    "apply_criterion",
    "describe_model",
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
    "model_code",
    "model_table",
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
    if name == "CorrectionGrid":
        from . import grid

        return getattr(grid, name)
    raise AttributeError(f"module 'compensation' has no attribute {name!r}")
