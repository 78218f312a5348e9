"""A corrected re-evaluation of an ISO 230-2 run (``cmm-comp calibrate apply``): the run's
readings with a machine's correction applied, written as an ISO 230-2 ``.dat`` file that
``cmm-comp iso230`` evaluates (docs/calibration.md §real data).

At target P_i in cycle j, direction d, the machine indicates P_i; corrected = P_i + e(P_i, d)/1000
with e the machine's positional error of the axis at the line and optic given (µm, the reversal
of the direction of approach included); the corrected deviation is reference − corrected, so the
written reference is ``REF − e/1000`` against the same targets. Choose cycles the machine was
*not* calibrated on for an honest (cross-validated) figure. Positions mm, errors µm.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError, RealDataError
from ..parametric_errors import AXIS_INDEX

if TYPE_CHECKING:
    from ..formats.realdata import Iso230Run
    from ..machine import Machine

__all__ = ["corrected_iso230", "write_iso230_dat"]

FloatArray = NDArray[np.float64]


def corrected_iso230(
    machine: Machine,
    dat_path: Path,
    axis: str,
    *,
    line_mm: FloatArray | None = None,
    optic_mm: FloatArray | None = None,
    cycles: tuple[int, ...] | None = None,
    correct: bool = True,
) -> Iso230Run:
    """The run of ``dat_path`` (its ``cycles``, default all) corrected by ``machine``
    (``correct`` False: the same cycles uncorrected, the comparison's "before")."""
    from ..formats.realdata import Iso230Run, read_iso230_dat

    try:
        run = read_iso230_dat(dat_path)
    except RealDataError as exc:
        raise CalibrationError(str(exc)) from None
    if axis not in AXIS_INDEX:
        raise CalibrationError(f"--axis {axis!r}: allowed x, y, z")
    k = AXIS_INDEX[axis]
    n = run.fwd_mm.shape[1]
    chosen = cycles or tuple(range(1, n + 1))
    bad = [c for c in chosen if not 1 <= c <= n]
    if bad:
        raise CalibrationError(f"{dat_path}: cycle {bad[0]} does not exist (the file has 1…{n})")
    idx = [c - 1 for c in chosen]
    line = machine.volume.reference_mm if line_mm is None else np.asarray(line_mm, float)
    optic = np.zeros(3) if optic_mm is None else np.asarray(optic_mm, float)
    pts = np.repeat(np.asarray(line, float)[None], run.target_mm.size, 0)
    pts[:, k] = run.target_mm
    inside = machine.volume.contains(pts, tol_mm=1e-6)
    if not np.all(inside):
        i = int(np.argmin(inside))
        raise CalibrationError(
            f"{dat_path}: target {run.target_mm[i]:g} mm is outside {machine.source}'s volume"
        )
    corr = {}
    for name, d in (("fwd", 1.0), ("bwd", -1.0)):
        err = machine.volumetric_error(pts, optic, inputs={f"dir_{axis}": np.full(len(pts), d)})
        corr[name] = err[:, k] / 1000.0 if correct else np.zeros(len(pts))
    return Iso230Run(
        target_mm=run.target_mm.copy(),
        fwd_mm=run.fwd_mm[:, idx] - corr["fwd"][:, None],
        bwd_mm=run.bwd_mm[:, idx] - corr["bwd"][:, None],
        source=f"{dat_path} corrected by {machine.source}",
        meta=dict(run.meta),
    )


def write_iso230_dat(run: Iso230Run, path: Path, note: str) -> None:
    """Write ``run`` as an ecmc ISO 230-2 ``key=value`` file (mm), atomically."""
    from ..formats.atomic import write_text_atomic

    m, n = run.fwd_mm.shape
    lines = [f"# {line}" for line in note.splitlines()]
    lines += ["UNIT=mm", f"CYCLES={n}", f"POSITIONS={m}", "DEC=6"]
    for i in range(m):
        lines.append(f"TGT_DATA[{i + 1}]={float(run.target_mm[i])!r}")
    for name, data in (("REF_DATA_FWD", run.fwd_mm), ("REF_DATA_BWD", run.bwd_mm)):
        for c in range(n):
            for i in range(m):
                lines.append(f"{name}[{i + 1},{c + 1}]={float(data[i, c])!r}")
    write_text_atomic(path, "\n".join(lines) + "\n")
