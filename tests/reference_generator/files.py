"""Writing a case as a user's files, in the shape ``cmm-comp import camonitor`` writes them.

``machine.toml`` (docs/formats.md §1): one axis' calibrated linear model — zero, or a positional
polynomial c0 + c1·q — on a model whose chain carries the axis on the tool side; no thermal terms
(no temperature is logged). ``measurements.csv`` (§2): ``x,y,z`` indicated (the other two axes at
their fixed positions), ``ref_x,ref_y,ref_z`` (the reference along the measured axis; the other
two equal to the indicated: nothing measured there), ``t``, ``dir_<axis>``, ``group``
(``cycle-N``), and the importer's two extra columns ``v_<axis>`` (mm/s) and ``state``.
Written with the csv module and plain text, not the project's writers.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from .case import Case

AXES = ("x", "y", "z")


def machine_toml(case: Case) -> str:
    """The description handed to the diagnosis (never the truth)."""
    d = case.design
    lo, hi = d.plan.lo - d.plan.overrun, d.plan.hi + d.plan.overrun
    margin = 0.05 * (hi - lo) + 1.0
    vol = []
    for i, a in enumerate(AXES):
        if a == d.axis:
            vol.append(f"{a} = [{lo - margin:.6f}, {hi + margin:.6f}]")
        else:
            vol.append(f"{a} = [{d.fixed_mm[i] - 1.0:.6f}, {d.fixed_mm[i] + 1.0:.6f}]")
    ref = [d.centre_mm if a == d.axis else d.fixed_mm[i] for i, a in enumerate(AXES)]
    lines = [
        f"# Simulated session {case.case_id} (tests/reference_generator): the axis' calibrated",
        "# linear model, as `cmm-comp import camonitor` writes one; the hidden effects are not here.",
        'format = "cmm-machine/1"',
        f'name = "refgen-{case.family}-{case.variant}-s{case.seed}"',
        f'model = "{d.model}"',
        "",
        "[volume]",
        *vol,
        "reference = [" + ", ".join(f"{v:.6f}" for v in ref) + "]",
        "",
        "[probe]",
        "offset = [0.0, 0.0, 0.0]",
        "",
        "[thermal]",
        "reference_C = 20.0",
        "expansion = { x = 0.0, y = 0.0, z = 0.0 }",
    ]
    c0, c1 = case.calibrated_um
    if c0 or c1:
        # the polynomial is in the indicated position q (mm), µm (docs/formats.md §1.7)
        lines += ["", f"[errors.d{d.axis}_{d.axis}]", f"polynomial = [{c0!r}, {c1!r}]"]
    return "\n".join(lines) + "\n"


def measurement_rows(case: Case) -> tuple[list[str], list[list[str]]]:
    a = case.axis
    k = AXES.index(a)
    header = ["x", "y", "z", "ref_x", "ref_y", "ref_z", "t", f"dir_{a}", "group", f"v_{a}", "state"]
    fixed = case.design.fixed_mm
    rows: list[list[str]] = []
    for i in range(case.n):
        ind = [fixed[0], fixed[1], fixed[2]]
        ref = list(ind)
        ind[k] = float(case.indicated_mm[i])
        ref[k] = float(case.reference_mm[i])
        rows.append(
            [f"{v:.9f}" for v in ind]
            + [f"{v:.9f}" for v in ref]
            + [
                f"{case.t_s[i]:.6f}",
                str(int(case.direction[i])),
                str(case.group[i]),
                f"{case.velocity_mm_s[i]:.6f}",
                str(case.state[i]),
            ]
        )
    return header, rows


def write_case(case: Case, directory: Path) -> tuple[Path, Path]:
    """``directory/machine.toml`` and ``directory/measurements.csv``."""
    directory.mkdir(parents=True, exist_ok=True)
    machine = directory / "machine.toml"
    machine.write_text(machine_toml(case), encoding="utf-8")
    meas = directory / "measurements.csv"
    header, rows = measurement_rows(case)
    with meas.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(header)
        writer.writerows(rows)
    return machine, meas


def observed_error_from_csv(path: Path, axis: str) -> np.ndarray:
    """(ref − indicated)·1000 µm of the axis, read back from the file (for tests)."""
    with path.open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return np.array([(float(r[f"ref_{axis}"]) - float(r[axis])) * 1000.0 for r in rows])
