"""The diagnosis names what the independent generator hid (issue 11, item 3), on a fixed handful
of cases: sizes 1–3× the noise, different models and session designs.

The generator (tests/independent_generator/) shares no code with the diagnosis' candidates: each
effect is its own physical forward model through its own chain. A case passes when the set of
identities named equals the hidden set (a hidden identity may also be listed among an entry's
``alternatives``). Cases noted "failed when written" failed on an earlier diagnosis (the
diagnosis is being reworked to pass them); the assertion stays.

The full rate table: benchmarks/bench_discovery_independent.py.
"""

from __future__ import annotations

import pytest
from independent_generator.scoring import run_case
from independent_generator.sessions import Design

H1, H8 = 3600.0, 8 * 3600.0

# (label, size, seed, model, design)
CASES = [
    # FB1: the Y table's pitch changes with the carriage's x (uniform in y)
    ("coupling", 1.0, 32, "FB1", Design("random", 200, 1, H1, 0.5)),
    # MB1: the bridge's roll ex_y changes uniformly with x - on MB1 exactly the roll table of X
    # (same Abbe arm): named only when the diagnosis lists the other as an alternative
    ("coupling", 3.0, 47, "MB1", Design("random", 200, 1, H1, 0.5)),
    # the case: X guideway simply supported, bows with T_top − T_bottom, carriage tilts
    # (failed on an earlier diagnosis: also named drift z)
    ("thermal_gradient", 1.0, 34, "MB1", Design("random", 200, 1, H1, 0.4)),
    # Z ram bends (tapered gradient) and turns about its guide H mm beside the chain's point
    # (failed on an earlier diagnosis: also named parametric dz_z)
    ("thermal_gradient", 3.0, 22, "FB1", Design("random", 200, 5, H8, 0.4)),
    ("periodic", 1.0, 23, "MH2", Design("iso_lines", 200, 1, H1, 0.3)),
    ("scale_expansion", 1.0, 24, "CX1", Design("iso_lines", 200, 1, H8, 0.5)),
    # Z positional table changed by low-frequency sines (failed on an earlier diagnosis)
    ("parametric", 3.0, 25, "FH1", Design("random", 200, 1, H1, 0.25)),
    ("drift", 1.0, 26, "MB2", Design("random", 200, 1, H8, 0.5)),
    ("reversal", 1.0, 27, "CY1", Design("random", 200, 5, H1, 0.6)),
    # a Gaussian blob in one corner: `unexplained` only, never a named cause (the local basis
    # competes with every cause; docs/discovery.md "Method")
    ("unexplained", 3.0, 30, "FH2", Design("random", 200, 1, H1, 0.4)),
    ("periodic+reversal", 1.0, 29, "MB1", Design("iso_lines", 200, 1, H1, 0.4)),
    ("none", 0.0, 28, "FH2", Design("random", 200, 1, H1, 0.5)),
]


@pytest.mark.parametrize(
    ("label", "size", "seed", "model", "design"),
    CASES,
    ids=[
        f"{c.values[0]}-{c.values[1]}x-{c.values[3]}"
        if hasattr(c, "marks")
        else f"{c[0]}-{c[1]}x-{c[3]}-{c[4].layout}"
        for c in CASES
    ],
)
def test_diagnosis_names_the_hidden_effects(
    label: str, size: float, seed: int, model: str, design: Design
) -> None:
    r = run_case(label, size, seed, model=model, design=design)
    assert r["named"], (
        f"{label} at {size}× on {model} {design.label}: hidden {r['hidden']} "
        f"({[h['variant'] for h in r['hidden_detail']]}), found {r['found']} "
        f"alternatives {r['alternatives']}"
    )
    assert r["heldout_ok"], (
        f"held-out {r['heldout_rms_um']:.3f} µm > 1.5 × {r['noise_rms_3d_um']:.3f}"
    )
