"""Diagnosis: compare a machine model with verification measurements, find the physical causes of
what it gets wrong, extend the model with them and show the gain on held-out data.

Modules: :mod:`.residuals` (residuals and statistics), :mod:`.candidates` (the causes of
docs/formats.md §4 as fit-ready terms), :mod:`.fitting` (least squares, profiles, grouped CV,
F-tests), :mod:`.selection` (greedy out-of-sample selection, :func:`diagnose`),
:mod:`.unexplained` (structure no cause explains), :mod:`.report` (plots and HTML).
"""

from .outcome import Diagnosis
from .residuals import Residuals, axis_statistics, compute_residuals, length_error_e0_um, rms3d
from .selection import diagnose

__all__ = [
    "Diagnosis",
    "Residuals",
    "axis_statistics",
    "compute_residuals",
    "diagnose",
    "length_error_e0_um",
    "rms3d",
]
