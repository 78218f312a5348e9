"""What people look at: volumetric maps, diagonals and line reports (:mod:`.maps`), PNG plots
(:mod:`.plots`), ISO 230-2 evaluation (:mod:`.iso230`) and the 6-DOF capture of node poses
(:mod:`.sixdof`). Units: positions mm, errors µm, angles µrad.

The plot and 6-DOF names are imported on first use (they pull in matplotlib and the grid's
numba kernels), so ``import cmm_comp.compensation`` stays light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

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

if TYPE_CHECKING:
    from .plots import plot_diagonals, plot_line, plot_parametric_errors, plot_vector_map
    from .sixdof import (
        SixDofLayout,
        grid_from_readings,
        pose_first_order,
        pose_from_readings,
        readings_from_pose,
    )

_LAZY = {
    "plot_diagonals": "plots",
    "plot_line": "plots",
    "plot_parametric_errors": "plots",
    "plot_vector_map": "plots",
    "SixDofLayout": "sixdof",
    "grid_from_readings": "sixdof",
    "pose_first_order": "sixdof",
    "pose_from_readings": "sixdof",
    "readings_from_pose": "sixdof",
}

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


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib import import_module

    return getattr(import_module(f".{module}", __name__), name)
