"""The machine's reversal (backlash) in sequential multilateration.

Every station runs the same program of points; at each stop an axis' positional error carries
``dir·h`` (h the half reversal step, dir the axis' last direction of travel). In a program of
points in random order the direction correlates with the position (a point near an axis' upper
end is mostly reached moving up), so a fit that does not know the directions reads about half
the step as a scale error of that axis: on the generator's mixed cases that bias (0.3–0.6 ppm)
was the largest miss of U (docs/calibration.md §8.1, run of 2026-12-06 03:30).

* :func:`travel_directions` against directions worked out by hand (the reader's contract: each
  station's rows in the order measured);
* hidden truth: a multilateration-only case of the independent generator
  (tests/calibration_generator, its own exact chain and reversal model) — the reversal is
  identified from the lengths on every axis and its mean half step agrees with the truth within
  3 standard uncertainties (a fit that ignored the directions writes no reversal at all).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration_generator.case import build_case

from cmm_comp.compensation.calibration.calibrate import calibrate
from cmm_comp.compensation.calibration.multilateration import (
    read_multilateration,
    travel_directions,
)
from cmm_comp.compensation.calibration.plan import read_plan

# each station's rows in the order measured, the two stations interleaved in the file
ROWS = [  # station, x, y, z
    ("A", 0.0, 0.0, 0.0),
    ("B", 50.0, 50.0, 50.0),
    ("A", 10.0, 0.0, 5.0),
    ("A", 5.0, 0.0, 5.0),
    ("B", 40.0, 60.0, 50.0),
    ("A", 5.0, 3.0, 1.0),
]
# by hand: a station's first row knows no direction (0); an axis that does not move keeps its
# last direction (0 until its first move); station B's rows follow B's previous row, not A's
EXPECTED = [
    (0, 0, 0),
    (0, 0, 0),
    (1, 0, 1),
    (-1, 0, 1),
    (-1, 1, 0),
    (-1, 1, -1),
]


def test_travel_directions_follow_each_stations_own_rows() -> None:
    station = np.array([0 if s == "A" else 1 for s, *_ in ROWS], dtype=np.intp)
    q = np.array([r[1:] for r in ROWS], dtype=float)
    np.testing.assert_array_equal(travel_directions(station, q), np.array(EXPECTED, dtype=float))


def test_the_reader_gives_each_row_its_direction(tmp_path: Path) -> None:
    lines = ["station,point,x,y,z,length_mm"]
    for i, (s, x, y, z) in enumerate(ROWS):
        lines.append(f"{s},{i + 1},{x},{y},{z},{100.0 + i}")
    for s in ("A", "B"):  # ≥ 4 points per station, ≥ 4 stations: padding after the rows above
        lines += [f"{s},p{j},{5.0 + j},{3.0},{1.0},{200.0 + j}" for j in range(3)]
    lines += [f"{s},q{j},{1.0 + j},{1.0},{1.0},{300.0 + j}" for s in ("C", "D") for j in range(4)]
    (tmp_path / "trac.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    plan = tmp_path / "calibration.toml"
    plan.write_text(
        'model = "MB1"\n\n[volume]\nx = [0.0, 100.0]\ny = [0.0, 100.0]\nz = [0.0, 100.0]\n\n'
        "[probe]\noffset = [0.0, 0.0, -50.0]\n\n[[multilateration]]\n"
        'file = "trac.csv"\nstylus_mm = [0.0, 0.0, -50.0]\n'
        "station_guess_mm = [[0, 0, -50], [100, 0, -50], [100, 100, -50], [0, 100, -50]]\n",
        encoding="utf-8",
    )
    p = read_plan(plan)
    data = read_multilateration(
        p.multilaterations[0], p.base.volume.lower_mm, p.base.volume.upper_mm
    )
    np.testing.assert_array_equal(data.direction[: len(ROWS)], np.array(EXPECTED, dtype=float))


@pytest.mark.timeout(300)
def test_multilateration_identifies_the_true_reversal(tmp_path: Path) -> None:
    """Development seed 1010, MB1 (its three reversals 0.25–0.39 µm; two reflector offsets)."""
    case = build_case(tmp_path / "case", 1010, "multilateration", "MB1")
    result = calibrate(read_plan(case.plan))
    layout = result.problem.model.layout
    cov = result.solution.covariance_theta_pinned
    found = {}
    for fn in layout.functions:
        if fn.is_reversal:
            mean = fn.matrix(np.linspace(fn.lo_mm, fn.hi_mm, 201)).mean(axis=0)
            found["xyz"[fn.axis]] = (
                float(mean @ result.solution.theta[fn.cols]),
                float(np.sqrt(mean @ cov[fn.cols, fn.cols] @ mean)),
            )
    assert sorted(found) == ["x", "y", "z"], f"reversal identified on {sorted(found)} only"
    for axis, (h_um, u_um) in found.items():
        true_um = case.machine.reversal_um[axis]
        assert abs(h_um - true_um) <= 3.0 * u_um, (axis, h_um, u_um, true_um)
        assert u_um < 0.5 * true_um, (axis, u_um, true_um)  # a measurement, not the prior
