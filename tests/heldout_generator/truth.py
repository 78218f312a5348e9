"""The true machine at the session's points: description + hidden effects, exact chain."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .chain import stylus_error_um
from .design import Session
from .effect_base import Contribution
from .machine import RandomMachine

FloatArray = NDArray[np.float64]


def true_temperatures(session: Session) -> dict[str, FloatArray]:
    """The temperatures the machine really had at each point (no sensor noise)."""
    return {name: session.env.at(name, session.t_s) for name in session.temps_C}


def true_error_um(
    machine: RandomMachine, session: Session, extra: Contribution | None
) -> FloatArray:
    """(N, 3) µm true − indicated: the described tables and thermal terms (at the true
    temperatures) plus the hidden effects' contribution ``extra``."""
    n = session.n
    extra = extra or Contribution.zeros(n)
    errors = machine.table_values(session.q_mm) + extra.errors
    sq = np.broadcast_to(machine.squareness_urad, (n, 3)) + extra.squareness_urad
    rigid = stylus_error_um(
        machine.model, session.q_mm - machine.reference_mm, session.stylus_mm, errors, sq
    )
    return rigid + machine.thermal_um(session.q_mm, true_temperatures(session)) + extra.direct_um


def effect_signal_um(machine: RandomMachine, session: Session, extra: Contribution) -> FloatArray:
    """What the hidden contribution alone changes at the stylus tip, µm (N, 3)."""
    if not (np.any(extra.errors) or np.any(extra.squareness_urad)):
        return extra.direct_um.copy()
    n = session.n
    u = session.q_mm - machine.reference_mm
    errors = machine.table_values(session.q_mm)
    sq = np.broadcast_to(machine.squareness_urad, (n, 3)).copy()
    base = stylus_error_um(machine.model, u, session.stylus_mm, errors, sq)
    moved = stylus_error_um(
        machine.model, u, session.stylus_mm, errors + extra.errors, sq + extra.squareness_urad
    )
    return moved - base + extra.direct_um


def rms3d_um(signal_um: FloatArray) -> float:
    """3-D RMS about the per-axis mean (a constant offset is a nuisance of every diagnosis)."""
    centred = signal_um - signal_um.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
