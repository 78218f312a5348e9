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


def lobing_signals(
    nx: Any, ny: Any, nz: Any, lobes: int = 3, radial_power: int | None = None
) -> dict[str, FloatArray]:
    """Derived, linear signals of an n-lobe probe term from the probing direction (unit vector).

    With ``C + iS = ρᵖ·e^{inφ}`` (ρ the horizontal fraction of n, φ its azimuth; p =
    ``radial_power``, by default n, when ``C + iS = (nx + i·ny)ⁿ``: the azimuth harmonic fading
    for vertical probing as ρⁿ; p = 1 fades it in proportion to ρ), returns
    ``<prefix>_c_<i> = n_i·C`` and ``<prefix>_s_<i> = n_i·S`` for i in x, y, z, prefix
    :func:`lobing_prefix`.
    """
    n = [np.asarray(v, dtype=float) for v in (nx, ny, nz)]
    z = (n[0] + 1j * n[1]) ** int(lobes)
    power = int(lobes) if radial_power is None else int(radial_power)
    if power != int(lobes):
        rho = np.hypot(n[0], n[1])
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(rho > 0, z * rho ** float(power - int(lobes)), 0.0)
    prefix = lobing_prefix(lobes, radial_power)
    out: dict[str, FloatArray] = {}
    for i, axis in enumerate(AXES):
        out[f"{prefix}_c_{axis}"] = n[i] * z.real
        out[f"{prefix}_s_{axis}"] = n[i] * z.imag
    return out


def lobing_prefix(lobes: int, radial_power: int | None = None) -> str:
    """``lobe<n>`` (radial power n) or ``lobe<n>r<p>``: the signal names' prefix."""
    if radial_power is None or int(radial_power) == int(lobes):
        return f"lobe{int(lobes)}"
    return f"lobe{int(lobes)}r{int(radial_power)}"


class ProbeLobingEffect(Effect):
    """Error along the probing direction n varying with its azimuth φ:
    ``n·ρᵖ·(a·cos nφ + b·sin nφ)`` µm, n = ``lobes`` (3 for a kinematic 3-lobe probe), ρ the
    horizontal fraction of n and p = ``radial_power`` (default n; 1: the lobing fades in
    proportion to ρ as the probing direction turns vertical)."""

    cause: ClassVar[str] = "probe_lobing"

    def __init__(
        self, lobes: int, a_cos_um: float, b_sin_um: float, radial_power: int | None = None
    ) -> None:
        if int(lobes) < 1:
            raise ValueError(f"lobes must be ≥ 1, got {lobes}")
        power = int(lobes) if radial_power is None else int(radial_power)
        if power < 1:
            raise ValueError(f"radial_power must be ≥ 1, got {radial_power}")
        self.lobes = int(lobes)
        self.radial_power = power
        self.a_cos_um = float(a_cos_um)
        self.b_sin_um = float(b_sin_um)

    @property
    def _prefix(self) -> str:
        return lobing_prefix(self.lobes, self.radial_power)

    def signals(self) -> dict[str, float]:
        return {f"{self._prefix}_{p}_{a}": 0.0 for p in "cs" for a in AXES}

    def transform_signals(self, ctx: EvalContext) -> None:
        if f"{self._prefix}_c_x" in ctx.signals:
            return
        if all(k in ctx.signals for k in ("nx", "ny", "nz")):
            ctx.signals.update(
                lobing_signals(
                    ctx.signals["nx"],
                    ctx.signals["ny"],
                    ctx.signals["nz"],
                    self.lobes,
                    self.radial_power,
                )
            )

    def add_direct(self, ctx: EvalContext) -> None:
        for i, axis in enumerate(AXES):
            c = signal_or(ctx, f"{self._prefix}_c_{axis}", 0.0)
            s = signal_or(ctx, f"{self._prefix}_s_{axis}", 0.0)
            ctx.direct_um[:, i] += self.a_cos_um * c + self.b_sin_um * s

    def to_table(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "cause": self.cause,
            "lobes": self.lobes,
            "a_cos_um": self.a_cos_um,
            "b_sin_um": self.b_sin_um,
        }
        if self.radial_power != self.lobes:
            out["radial_power"] = self.radial_power
        return out

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "lobes": self.lobes,
            "parameters": {
                "amplitude_um": math.hypot(self.a_cos_um, self.b_sin_um),
                "a_cos_um": self.a_cos_um,
                "b_sin_um": self.b_sin_um,
                "radial_power": self.radial_power,
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ProbeLobingEffect:
        return cls(
            int(read_number(t, "lobes", 3.0)),
            read_number(t, "a_cos_um"),
            read_number(t, "b_sin_um"),
            int(read_number(t, "radial_power", read_number(t, "lobes", 3.0))),
        )


register_effect(ProbeLobingEffect.cause, ProbeLobingEffect.from_table)
