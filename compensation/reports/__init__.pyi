"""Public API of ``reports`` (read by lazy_loader: names load on first use)."""

from .iso230 import Iso230Result, evaluate_iso230, format_iso230_report, plot_iso230
from .maps import (
    LineReport,
    VolumetricMap,
    check_steps,
    diagonal_endpoints,
    diagonals_um,
    length_error_um,
    line_report,
    volumetric_map,
)
from .plots import plot_diagonals, plot_line, plot_parametric_errors, plot_vector_map
from .sixdof import (
    SixDofLayout,
    grid_from_readings,
    pose_first_order,
    pose_from_readings,
    readings_from_pose,
)

__all__ = [
    "Iso230Result",
    "LineReport",
    "SixDofLayout",
    "VolumetricMap",
    "check_steps",
    "diagonal_endpoints",
    "diagonals_um",
    "evaluate_iso230",
    "format_iso230_report",
    "grid_from_readings",
    "length_error_um",
    "line_report",
    "plot_diagonals",
    "plot_iso230",
    "plot_line",
    "plot_parametric_errors",
    "plot_vector_map",
    "pose_first_order",
    "pose_from_readings",
    "readings_from_pose",
    "volumetric_map",
]
