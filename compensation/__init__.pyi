"""Public API of ``compensation`` (read by lazy_loader: names load on first use)."""

from .diagnosis import Diagnosis, diagnose
from .effects import Effect, EvalContext, effect_from_table, known_causes, register_effect
from .errors import (
    CalibrationError,
    CmmCompError,
    GridFileError,
    MachineFileError,
    MeasurementFileError,
    RealDataError,
)
from .formats.measurements import Measurements, read_measurements, write_measurements
from .formats.seedfiles import find_seed_machines, load_seed_fileset, write_seed_fileset
from .grid import CorrectionGrid
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

__all__ = [
    "ALL_COMPONENTS",
    "CRITERIA",
    "ISO_ALIASES",
    "MODEL_ALIASES",
    "MODEL_CHAINS",
    "TABLE_COMPONENTS",
    "ArmDeflection",
    "CalibrationError",
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
