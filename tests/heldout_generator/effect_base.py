"""What a hidden effect is: its identity, its own forward model, and the knob that sizes it.

A hidden effect adds to the *true* machine, never to the description. Its forward model returns a
:class:`Contribution`: extra parametric errors of the carriages (pushed through the exact chain, so
they get the Abbe arms of the machine's model), extra squareness, and direct terms added at the
stylus tip (probe, workpiece, thermal terms of the scales). The knob is one physical parameter
(an amplitude, a coefficient, a time constant); the case builder sets it so the effect's 3-D RMS
over the session's points is ``size ×`` the noise's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .chain import AXES
from .design import Session
from .identity import Identity
from .machine import RandomMachine

FloatArray = NDArray[np.float64]


@dataclass
class Contribution:
    """Additions to the true machine at the session's points."""

    errors: FloatArray  # (N, 3 axes, 6): δ µm, ε µrad
    squareness_urad: FloatArray  # (N, 3)
    direct_um: FloatArray  # (N, 3)

    @classmethod
    def zeros(cls, n: int) -> Contribution:
        return cls(np.zeros((n, 3, 6)), np.zeros((n, 3)), np.zeros((n, 3)))

    def __add__(self, other: Contribution) -> Contribution:
        return Contribution(
            self.errors + other.errors,
            self.squareness_urad + other.squareness_urad,
            self.direct_um + other.direct_um,
        )


@dataclass
class HiddenEffect:
    """One drawn effect. ``forward(knob)`` is its physics at the session's points."""

    identity: Identity
    variant: str
    params: dict[str, Any]
    forward: Callable[[float], Contribution]
    knob_name: str  # what the knob is, with its unit
    knob_range: tuple[float, float]  # physically plausible |knob|
    linear: bool = True  # signal proportional to the knob
    knob: float = float("nan")
    description_change: Callable[[RandomMachine], RandomMachine] | None = None
    record: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        return {
            "identity": self.identity.as_dict(),
            "label": self.identity.label(),
            "variant": self.variant,
            self.knob_name: float(self.knob),
            "params": _plain(self.params),
            **self.record,
        }


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def axis_index(axis: str) -> int:
    return AXES.index(axis)


def positional_slot(axis: str) -> int:
    """Slot of the positional error of ``axis`` (dx_x → 0, dy_y → 1, dz_z → 2)."""
    return AXES.index(axis)


def normalised(machine: RandomMachine, session: Session) -> FloatArray:
    """(N, 3) positions as s ∈ [0, 1] of each axis' travel."""
    return machine.normalised(session.q_mm)


Drawer = Callable[[np.random.Generator, RandomMachine, Session], HiddenEffect]
