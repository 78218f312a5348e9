"""grid: the correction grid — exact error poses at the nodes of the working volume,
interpolated (Squad for rotations, C² tricubic spline for translations).

* :mod:`.correction_grid` — :class:`CorrectionGrid`, the grid and everything it answers;
* :mod:`.nodes` — what a grid is made of, checked; :mod:`.build` — that node data from a
  machine model or from measured node poses, and the default steps;
* :mod:`.batch` — the batch correction path; :mod:`.point` — the single-reading path;
* :mod:`.status` — the one status rule both correction paths use;
* :mod:`.inputs` — the runtime signals the grid reads;
* :mod:`.file` — the versioned, checksummed grid file; :mod:`.signing` — its Ed25519
  signature (``cmm-comp grid sign``);
* :mod:`.interpolation` — the Squad and spline tables; :mod:`.kernels` — the compiled (numba)
  evaluation kernels, :mod:`.quaternion_kernels` their quaternion algebra;
  :mod:`.inverse` — command positions for a target;
* :mod:`.uncertainty` — the U a grid carries (its data, file header and compiled kernels);
* :mod:`.squad`, :mod:`.quaternion` — quaternion algebra and Squad interpolation;
* :mod:`.field` — an analytic error field (test and study oracle); :mod:`.study` — the
  interpolation study (``python -m cmm_comp.compensation.grid.study``).

Units: positions mm, translations µm, rotations as unit quaternions (w, x, y, z).
"""

from __future__ import annotations

from .build import (
    DEFAULT_STEPS,
    NODES_PER_WAVELENGTH,
    MachineLike,
    default_steps,
    effect_steps,
    unresolved_effects,
)
from .correction_grid import CorrectionGrid
from .file import GridFileError
from .inputs import GridSignal
from .interpolation import make_grid_continuous
from .nodes import MAX_NODES, MAX_STEPS_PER_AXIS, MIN_STEPS_PER_AXIS
from .signing import GridSignatureError, generate_signing_key, sign_grid
from .status import STATUS_DTYPE, VOLUME_TOL_MM, point_status

__all__ = [
    "DEFAULT_STEPS",
    "MAX_NODES",
    "MAX_STEPS_PER_AXIS",
    "MIN_STEPS_PER_AXIS",
    "NODES_PER_WAVELENGTH",
    "STATUS_DTYPE",
    "VOLUME_TOL_MM",
    "CorrectionGrid",
    "GridFileError",
    "GridSignal",
    "GridSignatureError",
    "MachineLike",
    "default_steps",
    "effect_steps",
    "generate_signing_key",
    "make_grid_continuous",
    "point_status",
    "sign_grid",
    "unresolved_effects",
]
