"""A second session generator for ``cmm-comp diagnose`` (issue 24): a machine axis measured by a
reference instrument, with effects of both instruments and the truth of which one carries each.

Written apart from the diagnosis: it imports nothing of the project (a test checks it) and
meets it only through the file formats (docs/formats.md §1, §2, §4) and the public CLI. See
README.md here for what it simulates, from which physics, and its truth rules.

Importable as ``reference_generator`` with ``tests/`` on ``sys.path``.
Units: positions mm, errors µm, speeds mm/s, times s, temperatures °C.
"""

from .case import Case, UnreachableCase, draw_case, simulate
from .families import FAMILIES, VARIANTS, mode_of
from .files import machine_toml, measurement_rows, write_case
from .runner import Run, find_cli, run_case
from .scoring import PERIOD_TOLERANCE, Score, identity_mismatch, score_diagnosis
from .separability import LAMBDA_MIN, drift_lambda, lock_lambda, uniform_drift_lambda
from .truth import Hidden, SamplePoints, SessionFacts, truth_labels

__all__ = [
    "FAMILIES",
    "LAMBDA_MIN",
    "PERIOD_TOLERANCE",
    "VARIANTS",
    "Case",
    "Hidden",
    "Run",
    "SamplePoints",
    "Score",
    "SessionFacts",
    "UnreachableCase",
    "draw_case",
    "drift_lambda",
    "find_cli",
    "identity_mismatch",
    "lock_lambda",
    "machine_toml",
    "measurement_rows",
    "mode_of",
    "run_case",
    "score_diagnosis",
    "simulate",
    "truth_labels",
    "uniform_drift_lambda",
    "write_case",
]
