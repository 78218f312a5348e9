"""Issue 24 item 7 sessions, built from physics with the held-out generator's own exact chain
(``tests/heldout_generator``: written apart from the diagnosis, imports nothing of it).

* :func:`bend_case`: a guideway that bends by an amount that changes with another axis' position
  (the bridge of a fixed-bridge machine sagging more as the ram extends; the base rail of a
  fixed horizontal-arm machine as the carriage climbs the column), and the carriage riding it
  pitches by the local slope of the bend. A beam under a load: deflection
  ``w(s) = A·g(s_b)·(s − 2s³ + s⁴)·16/5`` (a simply supported beam under a uniform load,
  normalised to 1 at mid-span) along the guideway's travel ``s ∈ [0, 1]``, the pitch
  ``−dw/dx`` (µrad = µm/mm·1000; a rail bent up towards +z tilts the carriage's x axis towards
  +z, a negative rotation about y). One physical cause.
* :func:`bump_case`: a local defect (a Gaussian bump of the error field) centred near an edge of
  the volume, to check where the diagnosis says it sits.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from heldout_generator.case import Case
from heldout_generator.design import SessionDesign, make_session
from heldout_generator.effect_base import Contribution, HiddenEffect
from heldout_generator.files import write_case
from heldout_generator.identity import Identity
from heldout_generator.machine import random_machine
from heldout_generator.truth import effect_signal_um, rms3d_um, true_error_um

AXES = ("x", "y", "z")


def _beam(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Simply supported beam under a uniform load: deflection (1 at mid-span) and d/ds."""
    w = (s - 2 * s**3 + s**4) * 16.0 / 5.0
    dw = (1 - 6 * s**2 + 4 * s**3) * 16.0 / 5.0
    return w, dw


def _finish(case_id: str, seed: int, design: SessionDesign, machine, session, effect, size):
    """Scale the effect to ``size`` × the noise RMS, add noise, return the Case."""
    unit = rms3d_um(effect_signal_um(machine, session, effect.forward(1.0)))
    knob = size * design.noise_rms_3d_um / unit
    effect.knob = knob
    total = effect.forward(knob)
    truth = true_error_um(machine, session, total)
    rng = np.random.default_rng(seed + 1000)
    noise = rng.normal(0.0, design.noise_um, (session.n, 3))
    return Case(
        case_id=case_id,
        seed=seed,
        design=design,
        description=machine,
        session=session,
        effects=[effect],
        indicated_mm=session.q_mm,
        reference_mm=session.q_mm + (truth + noise) / 1e3,
        hidden_signal_um=effect_signal_um(machine, session, total),
        noise_um=noise,
    )


def bend_case(model: str, seed: int, size: float = 3.0, n_points: int = 700) -> Case:
    """A guideway of X bending in z by an amount linear in the z position (the moment of the
    ram / carriage), its carriage pitching by the slope (module docstring)."""
    rng = np.random.default_rng(seed)
    design = replace(SessionDesign(), model=model, n_points=n_points)
    machine = random_machine(rng, model)
    session = make_session(rng, design, machine)
    lo, hi = machine.lower_mm, machine.upper_mm
    s = (session.q_mm - lo) / (hi - lo)
    w, dw = _beam(s[:, 0])
    g = s[:, 2]  # grows as the ram extends downwards / the carriage climbs
    span_x = float(hi[0] - lo[0])

    def forward(amplitude_um: float) -> Contribution:
        c = Contribution.zeros(session.n)
        c.errors[:, 0, 2] += amplitude_um * g * w  # dz_x: the bend
        c.errors[:, 0, 4] += -amplitude_um * g * dw / span_x * 1000.0  # ey_x = −dw/dx, µrad
        return c

    effect = HiddenEffect(
        identity=Identity("coupling", component="dz_x", varies_with="z"),
        variant="bend-with-slope",
        params={},
        forward=forward,
        knob_name="amplitude_um",
        knob_range=(0.01, 100.0),
    )
    return _finish(f"bend-{model}-s{seed}", seed, design, machine, session, effect, size)


def bump_case(
    model: str, seed: int, corner: tuple[float, float, float], size: float = 3.0
) -> tuple[Case, np.ndarray, float]:
    """A Gaussian bump of the x error centred at ``corner`` (fractions of the travel per axis),
    radius 12 % of the volume's diagonal; returns the case, the centre (mm) and the radius."""
    rng = np.random.default_rng(seed)
    design = replace(SessionDesign(), model=model, n_points=700)
    machine = random_machine(rng, model)
    session = make_session(rng, design, machine)
    lo, hi = machine.lower_mm, machine.upper_mm
    centre = lo + np.asarray(corner) * (hi - lo)
    radius = 0.12 * float(np.linalg.norm(hi - lo))
    weight = np.exp(-0.5 * np.sum(((session.q_mm - centre) / radius) ** 2, axis=1))

    def forward(peak_um: float) -> Contribution:
        c = Contribution.zeros(session.n)
        c.direct_um[:, 0] += peak_um * weight
        return c

    effect = HiddenEffect(
        identity=Identity("unexplained"),
        variant="edge-bump",
        params={},
        forward=forward,
        knob_name="peak_um",
        knob_range=(0.01, 100.0),
    )
    case = _finish(f"bump-{model}-s{seed}", seed, design, machine, session, effect, size)
    return case, centre, radius


def write(case: Case, folder: Path) -> tuple[Path, Path]:
    return write_case(case, folder)
