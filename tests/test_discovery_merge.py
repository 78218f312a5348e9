"""One cause for several (compensation/diagnosis/merge.py), judged by the independent generator.

The generator (tests/independent_generator) was written apart from the diagnosis: its own chain
and its own shape of each cause; its ``judge`` is the oracle. The two sessions below were named
as several causes by forward selection before the merge step existed, each part of one physical
cause entering as its own best single step:

* a workpiece expanding with a temperature that barely moves during a 1 h session on length
  lines: three scale tables (dx_x, dy_y, dz_z), the isotropic expansion being the one cause;
* a guideway bowing with T_top − T_bottom: a coupling plus a straightness table.

And the guard: two distinct causes in one session (a cyclic error beside a reversal) stay two.
"""

from __future__ import annotations

import pytest
from independent_generator.scoring import run_case


@pytest.mark.parametrize(
    ("label", "size", "seed"),
    [("workpiece_expansion", 0.5, 4), ("thermal_gradient", 1.0, 2)],
)
def test_one_cause_named_where_forward_selection_took_several(
    label: str, size: float, seed: int
) -> None:
    got = run_case(label, size, seed)
    assert got["strict"], (got["hidden"], got["found"], got["alternatives"])
    assert got["heldout_ok"], (got["heldout_rms_um"], got["noise_rms_3d_um"])


def test_two_distinct_causes_are_not_merged() -> None:
    got = run_case("periodic+reversal", 1.0, 1000)
    assert got["named"], (got["hidden"], got["found"], got["alternatives"])
    assert len(got["found"]) == 2
