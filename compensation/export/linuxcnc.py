"""LinuxCNC per-joint compensation files (``[JOINT_n] COMP_FILE`` / ``COMP_FILE_TYPE``).

Per the LinuxCNC INI documentation and its motion module: a file holds one triplet per line,
``nominal forward reverse`` in machine units, nominals strictly ascending, at most 256 triplets
(``EMCMOT_COMP_SIZE``); reading stops at the first line that is not a triplet, so the file has no
comments. ``COMP_FILE_TYPE = 0``: forward/reverse are the *actual* positions when the joint is
commanded to the nominal while moving up/down (the trim is ``nominal − actual``);
``COMP_FILE_TYPE = 1``: they are the trims themselves. The motion module adds the trim of the
current direction (the sign of the commanded velocity; at rest the last one) to the commanded
position, interpolating linearly between nominals and holding the end trims beyond the ends;
trims and slopes are stored as single-precision floats. With error = true − indicated, the
actual position at a nominal is ``nominal + e/1000`` mm and the trim ``−e/1000`` mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .limits import ExportError
from .plan import Plan
from .splines import FloatArray, Knots

__all__ = [
    "JointComp",
    "build_linuxcnc",
    "linuxcnc_error_um",
    "render_linuxcnc",
]


@dataclass
class JointComp:
    """One joint's triplets as written (mm): nominal, forward and reverse (as of the file type)."""

    axis: int
    nominal_mm: FloatArray
    forward_mm: FloatArray
    reverse_mm: FloatArray
    file_type: int

    def trims_mm(self) -> tuple[FloatArray, FloatArray]:
        if self.file_type == 0:
            return self.nominal_mm - self.forward_mm, self.nominal_mm - self.reverse_mm
        return self.forward_mm, self.reverse_mm


def _round7(v: FloatArray) -> FloatArray:
    return np.round(np.asarray(v, dtype=float), 7)


def build_linuxcnc(
    plan: Plan, knots: tuple[Knots, Knots, Knots], file_type: int
) -> list[JointComp]:
    """One file per joint from an own-axis plan (values rounded as printed, 7 decimals of mm)."""
    if file_type not in (0, 1):
        raise ExportError(f"linuxcnc: COMP_FILE_TYPE must be 0 or 1, got {file_type}")
    out: list[JointComp] = []
    for k in range(3):
        kn = knots[k]
        nominal = np.round(kn.positions(), 6)
        base = plan.plain.get((k, k), np.zeros(kn.count))
        h = plan.directional.get((k, k), np.zeros(kn.count))
        e_fwd, e_rev = (base + h) / 1000.0, (base - h) / 1000.0
        if file_type == 0:
            fwd, rev = _round7(nominal + e_fwd), _round7(nominal + e_rev)
        else:
            fwd, rev = _round7(-e_fwd), _round7(-e_rev)
        out.append(JointComp(k, nominal, fwd, rev, file_type))
    return out


def linuxcnc_error_um(
    joints: Sequence[JointComp], q_mm: FloatArray, dirs: FloatArray
) -> FloatArray:
    """The error (N, 3) µm the files take off: the writer's own emulation of the motion module
    (single-precision trims and slopes, linear between nominals, end trims held)."""
    q = np.asarray(q_mm, dtype=float)
    out = np.zeros((q.shape[0], 3))
    for j in joints:
        nom = j.nominal_mm
        f_trim, r_trim = j.trims_mm()
        values = []
        for trim in (f_trim, r_trim):
            t32 = trim.astype(np.float32).astype(float)
            slope = np.zeros(len(nom))
            slope[:-1] = ((t32[1:] - t32[:-1]) / np.diff(nom)).astype(np.float32)
            i = np.clip(np.searchsorted(nom, q[:, j.axis], side="right") - 1, -1, len(nom) - 1)
            inside = i >= 0
            ii = np.maximum(i, 0)
            v = np.where(inside, t32[ii] + slope[ii] * (q[:, j.axis] - nom[ii]), t32[0])
            values.append(v)
        corr = np.where(dirs[:, j.axis] > 0, values[0], values[1])
        out[:, j.axis] += -corr * 1000.0
    return out


def render_linuxcnc(joint: JointComp) -> str:
    """The comp file: ``nominal forward reverse`` per line, nothing else."""
    return "".join(
        f"{n:.6f} {f:.7f} {r:.7f}\n"
        for n, f, r in zip(joint.nominal_mm, joint.forward_mm, joint.reverse_mm, strict=True)
    )
