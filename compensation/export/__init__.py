"""export: a machine's volumetric model as a controller's own compensation tables.

``export_tables(machine, "sinumerik-cec" | "twincat-cnc" | "linuxcnc", tool_mm)`` fits the
tables the format can hold to the model over the working volume, writes them (in memory) and
measures what is left after the control's own interpolation (docs/export.md). The fit
(:mod:`.decompose`, :mod:`.plan`) is shared; each format has its own module (:mod:`.sinumerik`,
:mod:`.twincat`, :mod:`.linuxcnc`); :mod:`.report` writes the JSON, PNG and HTML;
:mod:`.check` lists what no document settles (``unverified``) and writes the one-table sign
check that settles it on the machine (``check_tables``).
"""

from __future__ import annotations

from .check import CheckResult, check_tables, unverified
from .decompose import Decomposition, decompose, direction_axes, model_error_um
from .export import (
    FORMATS,
    ExportOptions,
    ExportResult,
    describe,
    direction_combinations,
    evaluation_points,
    export_tables,
    measure_residual,
    validate_axes,
)
from .limits import ExportError
from .plan import Plan
from .splines import Knots

__all__ = [
    "FORMATS",
    "CheckResult",
    "Decomposition",
    "ExportError",
    "ExportOptions",
    "ExportResult",
    "Knots",
    "Plan",
    "check_tables",
    "decompose",
    "describe",
    "direction_axes",
    "direction_combinations",
    "evaluation_points",
    "export_tables",
    "measure_residual",
    "model_error_um",
    "unverified",
    "validate_axes",
]
