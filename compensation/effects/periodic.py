"""Cyclic positional error along an axis (docs/formats.md §4 cause ``periodic``).

``Σ_n Σ_j P_j(s)·(a_nj·cos(n·φ(q)) + b_nj·sin(n·φ(q)))`` µm added to the axis' positional error,
minus its value at the reference point: φ the phase of the period law (:mod:`.period_law`;
``constant``: φ = 2πq/P), n = 1, 2, … the harmonics, P_j Legendre polynomials of the position
normalised over ``span_mm`` (the envelope: an amplitude that changes along the travel; j = 0, a
constant amplitude, is the usual cyclic error). ``a_cos_um``/``b_sin_um`` are (n, j) = (1, 0),
``harmonics_um`` the (n ≥ 2, 0) pairs, ``envelope_um`` the terms with j ≥ 1 as ``[n, j, a, b]``.

:func:`ripple_columns` gives the same terms as columns (per unit amplitude) for any coordinate:
the diagnosis fits them on the axis' position (the machine's cyclic error) and on the reference's
reading (the reference instrument's, :mod:`cmm_comp.compensation.diagnosis.reference_effects`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.polynomial import legendre

from ..parametric_errors import AXIS_INDEX
from .base import (
    Effect,
    EvalContext,
    FloatArray,
    read_axis,
    read_floats,
    read_number,
    read_span,
    read_str,
    register_effect,
)
from .period_law import PeriodLaw

__all__ = ["PeriodicEffect", "ripple_columns", "ripple_terms"]

#: One term of a cyclic error: (harmonic n ≥ 1, envelope order j ≥ 0, a_cos µm, b_sin µm).
Term = tuple[int, int, float, float]


def ripple_columns(
    r_mm: FloatArray,
    law: PeriodLaw,
    harmonics: int,
    envelope: int = 0,
    span_mm: Sequence[float] | None = None,
) -> FloatArray:
    """(N, 2·harmonics·(envelope + 1)) columns ``P_j(s)·cos(nφ)``, ``P_j(s)·sin(nφ)`` at the
    coordinate ``r_mm``, n-major then j (s normalised over ``span_mm``; needed when
    ``envelope`` > 0)."""
    r = np.asarray(r_mm, dtype=float)
    phi = law.phase(r)
    env = [np.ones_like(r)]
    if envelope > 0:
        if span_mm is None:
            raise ValueError("an envelope needs span_mm")
        lo, hi = float(span_mm[0]), float(span_mm[1])
        env = list(legendre.legvander(2.0 * (r - lo) / (hi - lo) - 1.0, envelope).T)
    cols = []
    for n in range(1, harmonics + 1):
        c, s = np.cos(n * phi), np.sin(n * phi)
        for e in env:
            cols += [e * c, e * s]
    return np.column_stack(cols)


def ripple_terms(coef: Sequence[float], harmonics: int, envelope: int) -> list[Term]:
    """The coefficients of :func:`ripple_columns` as ``(n, j, a, b)`` terms."""
    out: list[Term] = []
    i = 0
    for n in range(1, harmonics + 1):
        for j in range(envelope + 1):
            out.append((n, j, float(coef[i]), float(coef[i + 1])))
            i += 2
    return out


def _value(terms: Sequence[Term], law: PeriodLaw, r: FloatArray, span: Any) -> FloatArray:
    phi = law.phase(r)
    out = np.zeros_like(r)
    for n, j, a, b in terms:
        env: Any = 1.0
        if j:
            lo, hi = float(span[0]), float(span[1])
            c = np.zeros(j + 1)
            c[j] = 1.0
            env = legendre.legval(2.0 * (r - lo) / (hi - lo) - 1.0, c)
        out += env * (a * np.cos(n * phi) + b * np.sin(n * phi))
    return out


def amplitude_um(terms: Sequence[Term], law: PeriodLaw, span_mm: Sequence[float]) -> float:
    """The largest amplitude (µm) of the first harmonic along ``span_mm``."""
    r = np.linspace(float(span_mm[0]), float(span_mm[1]), 201)
    a = np.zeros_like(r)
    b = np.zeros_like(r)
    for n, j, ca, cb in terms:
        if n != 1:
            continue
        c = np.zeros(j + 1)
        c[j] = 1.0
        env = legendre.legval(2.0 * (r - span_mm[0]) / (span_mm[1] - span_mm[0]) - 1.0, c)
        a += env * ca
        b += env * cb
    return float(np.max(np.hypot(a, b)))


class PeriodicEffect(Effect):
    """Cyclic positional error along an axis: see the module docstring."""

    cause: ClassVar[str] = "periodic"

    def __init__(
        self,
        axis: str,
        period_mm: float,
        a_cos_um: float,
        b_sin_um: float,
        harmonics_um: Sequence[Sequence[float]] = (),
        law: PeriodLaw | None = None,
        envelope_um: Sequence[Sequence[float]] = (),
        span_mm: tuple[float, float] | None = None,
    ) -> None:
        self.axis = read_axis(axis)
        if not (math.isfinite(period_mm) and period_mm > 0):
            raise ValueError(f"period_mm must be finite and > 0, got {period_mm}")
        self.period_mm = float(period_mm)
        self.a_cos_um = float(a_cos_um)
        self.b_sin_um = float(b_sin_um)
        self.harmonics_um = [tuple(read_floats(h, "harmonics_um", 2)) for h in harmonics_um]
        self.law = law if law is not None else PeriodLaw("constant", self.period_mm)
        if self.law.period_mm != self.period_mm:
            raise ValueError("period_mm must be the law's period at its centre")
        self.envelope_um: list[Term] = []
        for t in envelope_um:
            n, j, a, b = read_floats(t, "envelope_um [n, j, a, b]", 4)
            if n < 1 or j < 1 or n != int(n) or j != int(j):
                raise ValueError(f"envelope_um terms need integer n ≥ 1 and j ≥ 1, got {t!r}")
            self.envelope_um.append((int(n), int(j), a, b))
        if self.envelope_um and span_mm is None:
            raise ValueError("envelope_um needs span_mm")
        self.span_mm = span_mm

    @property
    def terms(self) -> list[Term]:
        """Every term as ``(n, j, a, b)``."""
        out: list[Term] = [(1, 0, self.a_cos_um, self.b_sin_um)]
        out += [(n, 0, a, b) for n, (a, b) in enumerate(self.harmonics_um, start=2)]
        return out + self.envelope_um

    def value_um(self, q_mm: FloatArray) -> FloatArray:
        """The cyclic error at ``q_mm`` (µm), not yet referred to the reference point."""
        return _value(self.terms, self.law, np.asarray(q_mm, dtype=float), self.span_mm)

    def shape(
        self, q_mm: FloatArray, ref_mm: float, harmonic: int = 1
    ) -> tuple[FloatArray, FloatArray]:
        """(cos, sin) of harmonic n at ``q_mm``, each minus its value at ``ref_mm``."""
        phi = harmonic * self.law.phase(np.asarray(q_mm, dtype=float))
        phi0 = harmonic * float(self.law.phase(np.array([ref_mm]))[0])
        return np.cos(phi) - math.cos(phi0), np.sin(phi) - math.sin(phi0)

    def shortest_wavelength_mm(self) -> dict[str, float]:
        """The period of the highest harmonic (of a chirped law: where it is shortest)."""
        n = max(t[0] for t in self.terms)
        p = self.period_mm
        if self.law.kind != "constant" and self.span_mm is not None:
            p = float(np.min(self.law.period_at(np.linspace(*self.span_mm, 101))))
        return {self.axis: p / n}

    def modify_errors(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        ref = float(ctx.reference_mm[k])
        value = self.value_um(ctx.q_mm[:, k]) - float(self.value_um(np.array([ref]))[0])
        ctx.errors[:, k, k] += value

    def to_table(self) -> dict[str, Any]:
        t: dict[str, Any] = {
            "cause": self.cause,
            "axis": self.axis,
            "period_mm": self.period_mm,
            "a_cos_um": self.a_cos_um,
            "b_sin_um": self.b_sin_um,
        }
        if self.harmonics_um:
            t["harmonics_um"] = [list(h) for h in self.harmonics_um]
        t.update(self.law.to_table())
        if self.envelope_um:
            t["envelope_um"] = [list(e) for e in self.envelope_um]
        if self.span_mm is not None:
            t["span_mm"] = list(self.span_mm)
        return t

    def describe(self) -> dict[str, Any]:
        params: dict[str, Any] = {
            "period_mm": self.period_mm,
            "amplitude_um": math.hypot(self.a_cos_um, self.b_sin_um),
            "a_cos_um": self.a_cos_um,
            "b_sin_um": self.b_sin_um,
        }
        for n, (a_n, b_n) in enumerate(self.harmonics_um, start=2):
            params[f"harmonic_{n}_amplitude_um"] = math.hypot(a_n, b_n)
        if self.span_mm is not None:
            params["amplitude_um"] = amplitude_um(self.terms, self.law, self.span_mm)
            params.update(self.law.describe(self.span_mm))
        return {
            "cause": self.cause,
            "axis": self.axis,
            "period_mm": self.period_mm,
            "parameters": params,
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> PeriodicEffect:
        harmonics = t.get("harmonics_um", [])
        if not isinstance(harmonics, list):
            raise ValueError(f"harmonics_um must be a list of [a, b] pairs, got {harmonics!r}")
        envelope = t.get("envelope_um", [])
        if not isinstance(envelope, list):
            raise ValueError(f"envelope_um must be a list of [n, j, a, b], got {envelope!r}")
        period = read_number(t, "period_mm")
        span = read_span(t["span_mm"], "span_mm") if "span_mm" in t else None
        return cls(
            read_str(t, "axis"),
            period,
            read_number(t, "a_cos_um"),
            read_number(t, "b_sin_um"),
            harmonics,
            PeriodLaw.from_table(t, period),
            envelope,
            span,
        )


register_effect(PeriodicEffect.cause, PeriodicEffect.from_table)
