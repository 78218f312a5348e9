"""Held-out session generator for ``cmm-comp diagnose`` (issue 11).

Written apart from the diagnosis: it must never import from, or be shaped after,
``compensation/diagnosis``, ``compensation/effects``, ``compensation/thermal``, ``sim_controller``
or the other generators (see README.md here). It shares only the contract: the file formats and
the nominal kinematic model (checked in tests/test_heldout_generator.py).
"""

from .case import (
    DESIGN_REDRAWS,
    DRAWERS,
    MIN_NONTABLE_CHI2,
    SIZES,
    Case,
    UnreachableCase,
    draw_case,
    make_case,
)
from .chain import MODEL_AXES, TABLE_NAMES, stylus_error_um
from .design import Session, SessionDesign, default_design, random_design
from .files import write_case, write_machine, write_measurements
from .identity import CAUSES, IDENTITY_KEYS, Identity, identity_from_entry
from .machine import MODELS, RandomMachine, random_machine
from .scoring import Score, score_diagnosis
from .truth import effect_signal_um, rms3d_um

__all__ = [
    "CAUSES",
    "DESIGN_REDRAWS",
    "DRAWERS",
    "IDENTITY_KEYS",
    "MIN_NONTABLE_CHI2",
    "MODELS",
    "MODEL_AXES",
    "SIZES",
    "TABLE_NAMES",
    "Case",
    "Identity",
    "RandomMachine",
    "Score",
    "Session",
    "SessionDesign",
    "UnreachableCase",
    "default_design",
    "draw_case",
    "effect_signal_um",
    "identity_from_entry",
    "make_case",
    "random_design",
    "random_machine",
    "rms3d_um",
    "score_diagnosis",
    "stylus_error_um",
    "write_case",
    "write_machine",
    "write_measurements",
]
