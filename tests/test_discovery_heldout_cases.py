"""A handful of sessions from the held-out generator (tests/heldout_generator) diagnosed in-process.

The generator was written apart from the diagnosis (its own chain, beams, lags, its own shapes
of each cause; it imports nothing of the project). Its scoring (``score_diagnosis``) is the
oracle: a hidden identity must be named, or listed among an entry's ``alternatives`` where the
session cannot tell them apart, and nothing else may be named.

The cases below were missed by an earlier diagnosis, each for a physical reason now modelled:

* a bridge twist that **sags** with the other axis' position (the carriage's tilt is largest
  with the load mid-span, zero at both ends) — a coupling quadratic, not only linear, in the
  other axis; with one stylus its first-order equivalent (a straightness of another axis
  varying with the first) is named instead and the twist must then be listed as an alternative;
* a coupling on ISO 10360 length lines with five styli, where each half of the volume sees other
  styli: the "same law across the volume" test must not extrapolate what a half cannot pin down;
* a straightness table change whose reference line was fitted on the session's points: the
  line is part of the table change, not a second cause (a squareness);
* a thermal gradient calibrated on site: the session sees mostly the static image of the bend
  in the tables, beside its variation with T_top − T_bottom;
* structure refused as local in an early round is re-tested against the causes finally named
  before it is reported as ``unexplained``.

The full rate table is benchmarks/bench_discovery_heldout.py (not in the suite: minutes).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from heldout_generator import UnreachableCase, draw_case, score_diagnosis, write_case

from cmm_comp.compensation import Machine, read_measurements
from cmm_comp.compensation.diagnosis import diagnose


def _case(causes: tuple[str, ...], sizes: tuple[float, ...], seed: int, case_id: str):
    """The case exactly as benchmarks/bench_discovery_heldout.py draws it: seed 0 on the
    default design, other seeds on a random design (redrawn while the cause is unreachable)."""
    try:
        return draw_case(causes, sizes, seed, case_id, default_first=seed == 0)[0]
    except UnreachableCase:
        pytest.skip(f"{case_id}: no reachable design")


CASES = [
    # MB1, 700 random points, one stylus: ez_y sags with z (+ a small cyclic error of y)
    (("coupling", "periodic"), (3.0, 0.5), 0, "coupling+periodic-3x0.5x-s0"),
    # CY1: ey_x sags with y, beside a z periodic error with harmonics
    (("coupling", "periodic"), (1.0, 1.0), 1, "coupling+periodic-1x1x-s1"),
    # MB2, 200 points, five styli: ex_y sags with x
    (("coupling",), (3.0,), 2, "coupling-3x-s2"),
    # MB1, 200 points on length lines, five styli: ez_z grows with y along z
    (("coupling",), (1.0,), 2, "coupling-1x-s2"),
    # MH2, five styli: a smooth random change of the Y straightness of Z (line removed on the
    # session's points)
    (("parametric",), (3.0,), 1, "parametric-3x-s1"),
    # the outside check's design: a Y guideway on Bessel supports bending with T_top − T_bottom,
    # calibrated on site in another gradient (what the session sees is mostly the image of the
    # bend in the tables), beside an S-shaped change of the X pitch table
    (("thermal_gradient", "parametric"), (3.0, 0.5), 0, "thermal_gradient+parametric-3x0.5x-s0"),
    # MH2, 2000 random points, five styli: a squareness that drifts; an early round fitted it
    # by a coupling in one half of the volume (refused as local), and that stale refusal was
    # reported as `unexplained` although the squareness drift named later explains it
    (("squareness_drift",), (1.0,), 3, "squareness_drift-1x-s3"),
]


@pytest.mark.parametrize(("causes", "sizes", "seed", "case_id"), CASES, ids=[c[3] for c in CASES])
def test_heldout_case_is_named(
    causes: tuple[str, ...], sizes: tuple[float, ...], seed: int, case_id: str, tmp_path: Path
) -> None:
    case = _case(causes, sizes, seed, case_id)
    write_case(case, tmp_path)  # through the files, as a user runs it
    machine = Machine.from_toml(tmp_path / "machine.toml")
    data = read_measurements(tmp_path / "measurements.csv")
    result = diagnose(machine, data).to_json()
    hidden = case.hidden
    score = score_diagnosis(hidden, result, case.noise_rms_3d_um)
    named = [e.get("label") for e in result["effects"]]
    assert score.named, (case_id, [str(h) for h in hidden], named)
    assert score.heldout_ok, (case_id, result["heldout_rms_um"], case.noise_rms_3d_um)
