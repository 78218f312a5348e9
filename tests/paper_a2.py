"""Appendix A.2 of Park, Burdekin & Peggs, transcribed as printed (OCR noise cleaned only).

Transcription source: ../shared/seeds/000_189ae6c983475e5b.txt, appendix A.2 "Transformation
rules for parametric errors with measurement offsets". Each model maps every transformed error
(``δ*`` for the nine linear errors, ``α* β1* β2*``) to ``(expression, criterion)``:

* the expression is the printed right-hand side in the variables ``dI_J`` (µm), ``eI_J`` (µrad),
  ``alpha, beta1, beta2`` (µrad) and the measurement location ``x, y, z`` and reference point
  ``xo, yo, zo``; as in ``tests/paper_a1.py`` the arms are in **metres** so that µrad·m = µm;
* ``criterion`` is True where the paper prints ``↔``: "the right hand terms have to be processed
  by the straightness criterion ... after arithmetic calculations have been performed".

Angular errors in a rule are the angular errors of the line being transformed, evaluated at the
same axis position; in the squareness rules ``E(a)/(a − ao)`` is the paper's chord slope of an
angular error along its own axis, and a bare ``E`` is its value at the measurement location.

OCR clean-up only (no metrology changed): ``d*x(z)`` → ``δ*x(z)``; ``δ*z(y) + δz(y) …`` (MB1) has
its ``↔`` printed as ``+``; ``δxy(y)`` (FH1) → ``δ*y(y)``; ``∫32`` (CY1) → ``β2*``; ``βi``, ``β_{i*``
→ ``β1``. FH1's ``β2*`` is illegible in the source (``\\int_{0}^{2} x =``) and is recorded as
``None``. Where the printed rule disagrees with the kinematic chain the disagreement is listed in
``SLIPS``/``SQUARENESS_AGREE`` below and explained in docs/seed-equations-a2.md; the expressions in
``PRINTED`` are the paper's, not ours.
"""

from __future__ import annotations

LINEAR_TARGETS: tuple[str, ...] = (
    "dx_x",
    "dy_y",
    "dz_z",
    "dx_y",
    "dx_z",
    "dy_x",
    "dy_z",
    "dz_y",
    "dz_x",
)  # in the paper's printed order
SQUARENESS_TARGETS: tuple[str, ...] = ("alpha", "beta1", "beta2")

Rule = tuple[str | None, bool]

PRINTED: dict[str, dict[str, Rule]] = {
    "MB1": {
        "dx_x": ("dx_x - (y - yo)*ey_x", False),
        "dy_y": ("dy_y + (z - zo)*ex_y - (x - xo)*ez_y", False),
        "dz_z": ("dz_z", False),
        "dx_y": ("dx_y - (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x + (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y + (x - xo)*ey_y", True),
        "dz_x": ("dz_x", False),
        "alpha": ("alpha + ez_y - (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 + ey_y + ey_x", False),
        "beta2": ("beta2 - ex_x - ex_y - (x - xo)*ey_y/(y - yo)", False),
    },
    "MB2": {
        "dx_x": ("dx_x + (y - yo)*ez_x - (z - zo)*ey_x", False),
        "dy_y": ("dy_y + (z - zo)*ex_y", False),
        "dz_z": ("dz_z", False),
        "dx_y": ("dx_y - (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x + (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y", False),
        "dz_x": ("dz_x - (y - yo)*ex_x", True),
        "alpha": ("alpha - (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 + ey_y + ey_x + (y - yo)*ex_x/(x - xo)", False),
        "beta2": ("beta2 - ex_y - ex_x", False),
    },
    "FB1": {
        "dx_x": ("dx_x - (z - zo)*ey_x", False),
        "dy_y": ("dy_y - (z - zo)*ex_y + (x - xo)*ez_y", False),
        "dz_z": ("dz_z", False),
        "dx_y": ("dx_y + (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x + (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y - (x - xo)*ey_y", True),
        "dz_x": ("dz_x", False),
        "alpha": ("alpha - ez_y - (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 + ey_x - ey_y", False),
        "beta2": ("beta2 - ex_x + ex_y + (x - xo)*ey_y/(y - yo)", False),
    },
    "FB2": {
        "dx_x": ("dx_x - (y - yo)*ez_x + (z - zo)*ey_x", False),
        "dy_y": ("dy_y + (z - zo)*ex_y", False),
        "dz_z": ("dz_z", False),
        "dx_y": ("dx_y - (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x - (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y", False),
        "dz_x": ("dz_x + (y - yo)*ex_x", True),
        "alpha": ("alpha - ez_x + (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 + ey_y - ey_x + (y - yo)*ex_x/(x - xo)", False),
        "beta2": ("beta2 - ex_y + ex_x", False),
    },
    "MH1": {
        "dx_x": ("dx_x", False),
        "dy_y": ("dy_y + (z - zo)*ex_y - (x - xo)*ez_y", False),
        "dz_z": ("dz_z + (x - xo)*ey_z", False),
        "dx_y": ("dx_y - (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x - (z - zo)*ex_x", True),
        "dy_z": ("dy_z - (x - xo)*ez_z", True),
        "dz_y": ("dz_y + (x - xo)*ey_y", True),
        "dz_x": ("dz_x", False),
        "alpha": ("alpha + ez_y + ez_z", False),
        "beta1": ("beta1 + ey_y", False),
        "beta2": ("beta2 - ex_y + (x - xo)*ez_z/(z - zo) - (x - xo)*ey_y/(y - yo)", False),
    },
    "MH2": {
        "dx_x": ("dx_x + (y - yo)*ez_x - (z - zo)*ey_x", False),
        "dy_y": ("dy_y", False),
        "dz_z": ("dz_z - (y - yo)*ex_z", False),
        "dx_y": ("dx_y", False),
        "dx_z": ("dx_z + (y - yo)*ez_z", True),
        "dy_x": ("dy_x + (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y", False),
        "dz_x": ("dz_x - (y - yo)*ex_x", True),
        "alpha": ("alpha - (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 + ey_x - (y - yo)*ez_z/(z - zo) + (y - yo)*ex_x/(x - xo)", False),
        "beta2": ("beta2 - ex_x", False),
    },
    "FH1": {
        "dx_x": ("dx_x + (z - zo)*ey_x", False),
        "dy_y": ("dy_y + (z - zo)*ex_y", False),
        "dz_z": ("dz_z", False),
        "dx_y": ("dx_y - (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x - (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y", False),
        "dz_x": ("dz_x + (y - yo)*ex_x", True),
        "alpha": ("alpha - ez_x + (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 - ey_x + ey_y - (y - yo)*ey_y/(x - xo)", False),
        "beta2": (None, False),  # illegible in the source
    },
    "FH2": {
        "dx_x": ("dx_x - (z - zo)*ey_x", False),
        "dy_y": ("dy_y - (z - zo)*ex_y + (x - xo)*ez_y", False),
        "dz_z": ("dz_z", False),
        "dx_y": ("dx_y + (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x + (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y - (x - xo)*ey_y", True),
        "dz_x": ("dz_x", False),
        "alpha": ("alpha - ez_y - (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 + ey_x - ey_y + (y - yo)*ex_x/(x - xo)", False),
        "beta2": ("beta2 - ex_x + ex_y + (x - xo)*ey_y/(y - yo)", False),
    },
    "CX1": {
        "dx_x": ("dx_x + (z - zo)*ey_x", False),
        "dy_y": ("dy_y - (z - zo)*ex_y + (x - xo)*ez_y", False),
        "dz_z": ("dz_z", False),
        "dx_y": ("dx_y + (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x - (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y - (x - xo)*ey_y", True),
        "dz_x": ("dz_x", False),
        "alpha": ("alpha - ez_x - ez_y + (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 - ey_y - ey_x - (y - yo)*ex_x/(x - xo)", False),
        "beta2": ("beta2 + ex_x + ex_y + (x - xo)*ey_y/(y - yo)", False),
    },
    "CY1": {
        "dx_x": ("dx_x - (y - yo)*ez_x + (z - zo)*ey_x", False),
        "dy_y": ("dy_y - (z - zo)*ex_y", False),
        "dz_z": ("dz_z", False),
        "dx_y": ("dx_y + (z - zo)*ey_y", True),
        "dx_z": ("dx_z", False),
        "dy_x": ("dy_x - (z - zo)*ex_x", True),
        "dy_z": ("dy_z", False),
        "dz_y": ("dz_y", False),
        "dz_x": ("dz_x + (y - yo)*ex_x", True),
        "alpha": ("alpha - ez_x + (z - zo)*ex_x/(x - xo)", False),
        "beta1": ("beta1 - ey_x - ey_y + (x - xo)*ex_x/(y - yo)", False),
        "beta2": ("beta2 + ex_x + ex_y + (x - xo)*ey_y/(y - yo)", False),
    },
}

#: (model, linear error) → the rule the kinematic chain gives where the printed one differs.
#: Filled from the derivation (tests/test_offsets.py checks both directions: every rule not
#: listed here agrees coefficient by coefficient, every rule listed disagrees as stated).
SLIPS: dict[tuple[str, str], str] = {
    # MB1's ΔX (A.1) has z·Ey(x), not y·Ey(x): the pitch of X acts on a Z offset
    ("MB1", "dx_x"): "dx_x - (z - zo)*ey_x",
    # MH1's X is the arm itself: nothing it carries sits at an offset, A.1 has no z·Ex(x) in ΔY
    ("MH1", "dy_x"): "dy_x",
    # FH1 = FB2's chain (the table is X): the table's yaw acts on a Y offset, as printed for FB2;
    # the same term is missing from FH1's ΔX in A.1 (tests/paper_a1.py CORRECTIONS)
    ("FH1", "dx_x"): "dx_x - (y - yo)*ez_x + (z - zo)*ey_x",
}

#: The printed squareness rules that agree with the chain (docs/seed-equations-a2.md, with the
#: chord ``E(a)/(a − ao)`` read as the least-squares slope of E along its axis). Every other
#: printed squareness rule disagrees with the derivation; the table in the doc lists how.
SQUARENESS_AGREE: frozenset[tuple[str, str]] = frozenset(
    {("MB1", "beta2"), ("MB2", "beta1"), ("MH1", "beta2"), ("MH2", "beta1")}
)
