"""Probe effects (docs/formats.md §4 cause ``probe_lobing``): the n-lobe error of a kinematic probe.

Signals: six derived signals ``lobe<k>_c_x`` … ``lobe<k>_s_z`` computed from the probing direction
by :func:`lobing_signals` (``nx``, ``ny``, ``nz`` are converted automatically when given to
:meth:`Machine.volumetric_error` or to the correction grid). Units: errors µm.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from ..parametric_errors import AXES
from .base import Effect, EvalContext, FloatArray, read_number, register_effect, signal_or

__all__ = ["ProbeLobingEffect", "lobing_signals"]


def lobing_signals(nx: Any, ny: Any, nz: Any, lobes: int = 3) -> dict[str, FloatArray]:
    """Derived, linear signals of an n-lobe probe term from the probing direction (unit vector).

    With ``C + iS = (nx + i·ny)^lobes`` (= ρⁿ·e^{inφ}: the azimuth harmonic, fading for vertical
    probing), returns ``lobe<n>_c_<i> = n_i·C`` and ``lobe<n>_s_<i> = n_i·S`` for i in x, y, z.
    """
    n = [np.asarray(v, dtype=float) for v in (nx, ny, nz)]
    z = (n[0] + 1j * n[1]) ** int(lobes)
    out: dict[str, FloatArray] = {}
    for i, axis in enumerate(AXES):
        out[f"lobe{lobes}_c_{axis}"] = n[i] * z.real
        out[f"lobe{lobes}_s_{axis}"] = n[i] * z.imag
    return out


class ProbeLobingEffect(Effect):
    """Error along the probing direction n varying with its azimuth φ:
    ``n·ρⁿ·(a·cos nφ + b·sin nφ)`` µm, n = ``lobes`` (3 for a kinematic 3-lobe probe)."""

    cause: ClassVar[str] = "probe_lobing"

    def __init__(self, lobes: int, a_cos_um: float, b_sin_um: float) -> None:
        if int(lobes) < 1:
            raise ValueError(f"lobes must be ≥ 1, got {lobes}")
        self.lobes = int(lobes)
        self.a_cos_um = float(a_cos_um)
        self.b_sin_um = float(b_sin_um)

    def signals(self) -> dict[str, float]:
        return {f"lobe{self.lobes}_{p}_{a}": 0.0 for p in "cs" for a in AXES}

    def transform_signals(self, ctx: EvalContext) -> None:
        if f"lobe{self.lobes}_c_x" in ctx.signals:
            return
        if all(k in ctx.signals for k in ("nx", "ny", "nz")):
            ctx.signals.update(
                lobing_signals(ctx.signals["nx"], ctx.signals["ny"], ctx.signals["nz"], self.lobes)
            )

    def add_direct(self, ctx: EvalContext) -> None:
        for i, axis in enumerate(AXES):
            c = signal_or(ctx, f"lobe{self.lobes}_c_{axis}", 0.0)
            s = signal_or(ctx, f"lobe{self.lobes}_s_{axis}", 0.0)
            ctx.direct_um[:, i] += self.a_cos_um * c + self.b_sin_um * s

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "lobes": self.lobes,
            "a_cos_um": self.a_cos_um,
            "b_sin_um": self.b_sin_um,
        }

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "lobes": self.lobes,
            "parameters": {
                "amplitude_um": math.hypot(self.a_cos_um, self.b_sin_um),
                "a_cos_um": self.a_cos_um,
                "b_sin_um": self.b_sin_um,
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ProbeLobingEffect:
        return cls(
            int(read_number(t, "lobes", 3.0)),
            read_number(t, "a_cos_um"),
            read_number(t, "b_sin_um"),
        )


register_effect(ProbeLobingEffect.cause, ProbeLobingEffect.from_table)
