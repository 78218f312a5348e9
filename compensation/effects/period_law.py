"""How the period of a cyclic error varies along the coordinate it is locked to (the law), and
its phase.

A cyclic error of constant period P is ``a·cos(2πq/P) + b·sin(2πq/P)``: a screw's pitch, a
scale's interpolation error, an interferometer's λ/2 nonlinearity. Some instruments have a
cyclic error whose period changes along their range (a *chirp*): a laser triangulation sensor
images its spot on a detector whose pixels (or interpolation steps) are periodic in the image
coordinate u ∝ 1/(r − r0), r the distance read and r0 where the sensor's distance law goes to
zero; an error periodic in u is periodic in r with the local period

    p(r) = P·((r − r0)/(c − r0))²           (law ``triangulation``),

P the period at the centre c of the travel. A general slowly varying period is
given by its values at knots (law ``smooth``): log p through them, a monotone cubic (PCHIP),
with constant slope beyond the first and last knot. The phase is φ(r) = 2π∫_c^r dr'/p(r') (0 at the
centre): closed form for ``triangulation``, integrated numerically for ``smooth``; ``constant``
keeps φ = 2πr/P (0 at r = 0, as the cyclic errors of the machine description always had).

Units: mm, radians.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = ["LAWS", "PeriodLaw"]

#: The period laws a cyclic error may follow.
LAWS = ("constant", "triangulation", "smooth")
#: Grid points of the numerical phase integral of a ``smooth`` law.
_SMOOTH_GRID = 4001


@dataclass(frozen=True)
class PeriodLaw:
    """A period law (module docstring). ``period_mm`` is the period at ``centre_mm``
    (``constant``: everywhere); ``r0_mm`` the distance law's zero (``triangulation``); ``knots_mm``
    and ``period_at_knots_mm`` the smooth law's knots (≥ 2, increasing)."""

    kind: str = "constant"
    period_mm: float = 1.0
    centre_mm: float = 0.0
    r0_mm: float | None = None
    knots_mm: tuple[float, ...] = ()
    period_at_knots_mm: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in LAWS:
            raise ValueError(f"law must be one of {', '.join(LAWS)}, got {self.kind!r}")
        if not (math.isfinite(self.period_mm) and self.period_mm > 0):
            raise ValueError(f"period_mm must be finite and > 0, got {self.period_mm}")
        if self.kind == "triangulation":
            if self.r0_mm is None or not math.isfinite(self.r0_mm):
                raise ValueError("a triangulation law needs a finite r0_mm")
            if self.r0_mm == self.centre_mm:
                raise ValueError("r0_mm must differ from the centre of the travel")
        if self.kind == "smooth":
            k, p = np.asarray(self.knots_mm, float), np.asarray(self.period_at_knots_mm, float)
            if len(k) < 2 or len(k) != len(p):
                raise ValueError("a smooth law needs ≥ 2 knots_mm and as many period_at_knots_mm")
            if not (np.all(np.isfinite(k)) and np.all(np.diff(k) > 0)):
                raise ValueError("knots_mm must be finite and increasing")
            if not (np.all(np.isfinite(p)) and np.all(p > 0)):
                raise ValueError("period_at_knots_mm must be finite and > 0")
            at_centre = float(self.period_at(np.array([self.centre_mm]))[0])
            if abs(at_centre - self.period_mm) > 1e-6 * self.period_mm:
                raise ValueError(
                    f"period_mm {self.period_mm} must be the law's period at centre_mm "
                    f"({at_centre:.6g} mm there)"
                )

    # ------------------------------------------------------------------ the law
    def _log_period(self, r: FloatArray) -> FloatArray:
        """log p through the knots (a monotone cubic, PCHIP; constant slope beyond them)."""
        from scipy.interpolate import PchipInterpolator

        k = np.asarray(self.knots_mm, float)
        f = PchipInterpolator(k, np.log(self.period_at_knots_mm), extrapolate=True)
        lo, hi = float(k[0]), float(k[-1])
        inside = np.clip(r, lo, hi)
        slope_lo, slope_hi = float(f.derivative()(lo)), float(f.derivative()(hi))
        out = f(inside)
        out = out + np.where(r < lo, (r - lo) * slope_lo, 0.0)
        return np.asarray(out + np.where(r > hi, (r - hi) * slope_hi, 0.0), float)

    def period_at(self, r_mm: Any) -> FloatArray:
        """Local period (mm) at ``r_mm``."""
        r = np.asarray(r_mm, dtype=float)
        if self.kind == "constant":
            return np.full_like(r, self.period_mm)
        if self.kind == "triangulation":
            r0 = float(self.r0_mm)  # type: ignore[arg-type]
            return self.period_mm * ((r - r0) / (self.centre_mm - r0)) ** 2
        return np.asarray(np.exp(self._log_period(r)), float)

    def phase(self, r_mm: Any) -> FloatArray:
        """φ(r) (rad) of the first harmonic (module docstring)."""
        r = np.asarray(r_mm, dtype=float)
        if self.kind == "constant":
            return 2.0 * np.pi * r / self.period_mm
        c = self.centre_mm
        if self.kind == "triangulation":
            r0 = float(self.r0_mm)  # type: ignore[arg-type]
            k = (c - r0) ** 2 / self.period_mm
            return np.asarray(2.0 * np.pi * k * (1.0 / (r0 - r) - 1.0 / (r0 - c)), float)
        lo = min(float(np.min(r, initial=c)), c, self.knots_mm[0])
        hi = max(float(np.max(r, initial=c)), c, self.knots_mm[-1])
        grid = np.linspace(lo, hi, _SMOOTH_GRID)
        inv = 1.0 / self.period_at(grid)
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(grid))])
        cum -= float(np.interp(c, grid, cum))
        return np.asarray(2.0 * np.pi * np.interp(r, grid, cum), float)

    # ------------------------------------------------------------------ tables
    def to_table(self) -> dict[str, Any]:
        """The law's keys of an ``[[effects]]`` table (none for ``constant``)."""
        if self.kind == "constant":
            return {}
        out: dict[str, Any] = {"law": self.kind, "centre_mm": self.centre_mm}
        if self.kind == "triangulation":
            out["r0_mm"] = self.r0_mm
        else:
            out["knots_mm"] = list(self.knots_mm)
            out["period_at_knots_mm"] = list(self.period_at_knots_mm)
        return out

    def describe(self, span_mm: Sequence[float]) -> dict[str, Any]:
        """The law's figures for a report: its kind, parameters and the period at the ends of
        ``span_mm``."""
        lo, hi = float(span_mm[0]), float(span_mm[1])
        out: dict[str, Any] = {
            "law": self.kind,
            "period_at_ends_mm": [float(v) for v in self.period_at([lo, hi])],
        }
        out.update({k: v for k, v in self.to_table().items() if k != "law"})
        return out

    @classmethod
    def from_table(cls, t: Any, period_mm: float) -> PeriodLaw:
        """The law of an ``[[effects]]`` table (``law`` absent: constant)."""
        kind = t.get("law", "constant")
        if kind == "constant":
            return cls("constant", period_mm)

        def number(key: str) -> float:
            try:
                v = float(t[key])
            except KeyError:
                raise ValueError(f"law {kind!r} needs {key}") from None
            except (TypeError, ValueError):
                raise ValueError(f"{key} must be a number, got {t[key]!r}") from None
            return v

        def floats(key: str) -> tuple[float, ...]:
            try:
                return tuple(float(v) for v in t[key])
            except KeyError:
                raise ValueError(f"law {kind!r} needs {key}") from None
            except (TypeError, ValueError):
                raise ValueError(f"{key} must be a list of numbers, got {t[key]!r}") from None

        if kind == "triangulation":
            return cls(kind, period_mm, number("centre_mm"), r0_mm=number("r0_mm"))
        if kind == "smooth":
            return cls(
                kind,
                period_mm,
                number("centre_mm"),
                knots_mm=floats("knots_mm"),
                period_at_knots_mm=floats("period_at_knots_mm"),
            )
        raise ValueError(f"law must be one of {', '.join(LAWS)}, got {kind!r}")
