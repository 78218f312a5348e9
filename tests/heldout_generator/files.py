"""Writing a case as a user's files: ``machine.toml`` (docs/formats.md §1) and
``measurements.csv`` (§2), with tomli-w and the csv module (not the project's writers)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import tomli_w

from .case import Case
from .environment import LOGGED


def write_machine(case: Case, path: Path) -> Path:
    """The description (never the truth) as ``machine.toml``."""
    path.write_bytes(tomli_w.dumps(case.description.toml_dict()).encode("utf-8"))
    return path


def measurement_rows(case: Case) -> tuple[list[str], list[list[str]]]:
    """Header and rows of ``measurements.csv``."""
    s = case.session
    header = ["x", "y", "z", "ref_x", "ref_y", "ref_z", "t", *LOGGED]
    header += ["dir_x", "dir_y", "dir_z", "nx", "ny", "nz"]
    many_styli = case.design.styli > 1
    if many_styli:
        header += ["px", "py", "pz"]
    if s.group is not None:
        header += ["group"]
    normals = s.normals / np.linalg.norm(s.normals, axis=1, keepdims=True)
    rows: list[list[str]] = []
    for i in range(s.n):
        row = [f"{v:.4f}" for v in case.indicated_mm[i]]
        row += [f"{v:.7f}" for v in case.reference_mm[i]]
        row += [f"{s.t_s[i]:.1f}"]
        row += [f"{s.temps_C[name][i]:.3f}" for name in LOGGED]
        row += [str(int(d)) for d in s.dirs[i]]
        row += [f"{v:.6f}" for v in normals[i]]
        if many_styli:
            row += [f"{v:.3f}" for v in s.stylus_mm[i]]
        if s.group is not None:
            row += [s.group[i]]
        rows.append(row)
    return header, rows


def write_measurements(case: Case, path: Path) -> Path:
    header, rows = measurement_rows(case)
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(header)
        writer.writerows(rows)
    return path


def write_case(case: Case, directory: Path) -> tuple[Path, Path]:
    """``directory/machine.toml`` and ``directory/measurements.csv``."""
    directory.mkdir(parents=True, exist_ok=True)
    return write_machine(case, directory / "machine.toml"), write_measurements(
        case, directory / "measurements.csv"
    )
