"""A random machine: volume, reference point, stylus, smooth nominal errors as polynomials.

This is what the user *knows* about the machine (the description handed to the diagnosis, written
as ``machine.toml`` per docs/formats.md §1); hidden effects are added on top of it by the truth.

Nominal errors are drawn as smooth random curves in the normalised travel s ∈ [0, 1] (Legendre
series of order 2–4, magnitudes typical of a calibrated machine: positional ±2–15 µm, straightness
±1–6 µm, angles ±2–12 µrad, squareness ±2–20 µrad) and converted exactly to the polynomial in the
indicated position q (mm) that the format asks for.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.polynomial import Polynomial
from numpy.polynomial import legendre as leg
from numpy.typing import NDArray

from .chain import AXES, MODEL_AXES, TABLE_NAMES, stylus_error_um, table_slot

FloatArray = NDArray[np.float64]

MODELS = tuple(MODEL_AXES)
SQUARENESS = ("alpha", "beta1", "beta2")


@dataclass
class RandomMachine:
    """A machine description with everything needed to evaluate its nominal model."""

    model: str
    lower_mm: FloatArray
    upper_mm: FloatArray
    reference_mm: FloatArray
    stylus_mm: FloatArray  # the machine's default stylus (probe.offset)
    polynomials: dict[str, list[float]]  # table name → coefficients in q (mm), c0 first
    squareness_urad: FloatArray
    expansion: dict[str, float]  # scale CTE per axis, µm/(m·°C)
    workpiece_expansion: float | None
    workpiece_fixture_mm: FloatArray
    name: str = "heldout"
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def span_mm(self) -> FloatArray:
        return self.upper_mm - self.lower_mm

    def normalised(self, q_mm: FloatArray) -> FloatArray:
        """Positions as s ∈ [0, 1] of each axis' travel."""
        return (q_mm - self.lower_mm) / self.span_mm

    def table_values(self, q_mm: FloatArray) -> FloatArray:
        """(N, 3 axes, 6) nominal parametric errors (µm, µrad) at indicated positions."""
        out = np.zeros((q_mm.shape[0], 3, 6))
        for name, coeffs in self.polynomials.items():
            k, slot = table_slot(name)
            out[:, k, slot] = np.polynomial.polynomial.polyval(q_mm[:, k], coeffs)
        return out

    def thermal_um(self, q_mm: FloatArray, temps_C: dict[str, FloatArray]) -> FloatArray:
        """The described thermal terms (docs/formats.md §1.5), µm."""
        u = q_mm - self.reference_mm
        out = np.zeros_like(q_mm)
        for k, axis in enumerate(AXES):
            out[:, k] += self.expansion[axis] * (temps_C[f"T_{axis}"] - 20.0) * u[:, k] / 1e3
        if self.workpiece_expansion is not None:
            dq = q_mm - self.workpiece_fixture_mm
            out -= self.workpiece_expansion * (temps_C["T_wp"] - 20.0)[:, None] * dq / 1e3
        return out

    def nominal_error_um(
        self, q_mm: FloatArray, stylus_mm: FloatArray, temps_C: dict[str, FloatArray]
    ) -> FloatArray:
        """What the description predicts (N, 3) µm: chain of the tables + thermal terms."""
        n = q_mm.shape[0]
        rigid = stylus_error_um(
            self.model,
            q_mm - self.reference_mm,
            stylus_mm,
            self.table_values(q_mm),
            np.broadcast_to(self.squareness_urad, (n, 3)),
        )
        return rigid + self.thermal_um(q_mm, temps_C)

    def toml_dict(self) -> dict[str, Any]:
        """The description as the dict of a ``machine.toml`` (docs/formats.md §1)."""
        thermal: dict[str, Any] = {
            "reference_C": 20.0,
            "expansion": {a: float(self.expansion[a]) for a in AXES},
        }
        if self.workpiece_expansion is not None:
            thermal["workpiece_expansion"] = float(self.workpiece_expansion)
            thermal["workpiece_fixture"] = [float(v) for v in self.workpiece_fixture_mm]
        return {
            "format": "cmm-machine/1",
            "name": self.name,
            "model": self.model,
            "volume": {
                **{
                    a: [float(self.lower_mm[k]), float(self.upper_mm[k])]
                    for k, a in enumerate(AXES)
                },
                "reference": [float(v) for v in self.reference_mm],
            },
            "probe": {"offset": [float(v) for v in self.stylus_mm]},
            "thermal": thermal,
            "squareness": {
                s: float(v) for s, v in zip(SQUARENESS, self.squareness_urad, strict=True)
            },
            "errors": {
                name: {"polynomial": [float(c) for c in cs]}
                for name, cs in self.polynomials.items()
            },
        }


def polynomial_in_q(coeffs_s: FloatArray, lower_mm: float, span_mm: float) -> list[float]:
    """Power coefficients in q (mm) of a power series in s = (q − lower)/span."""
    s_of_q = Polynomial([-lower_mm / span_mm, 1.0 / span_mm])
    p = Polynomial([0.0])
    for power, c in enumerate(coeffs_s):
        p = p + c * s_of_q**power
    return [float(c) for c in p.coef]


def _smooth_curve(rng: np.random.Generator, magnitude: float) -> FloatArray:
    """Power coefficients in s of a random Legendre series on [0, 1] (order 2–4)."""
    order = int(rng.integers(2, 5))
    c = rng.normal(0.0, 1.0, order + 1) / np.arange(1, order + 2) ** 0.7
    # Legendre in x = 2s − 1, then to powers of s
    power_x = leg.leg2poly(c)
    x_of_s = Polynomial([-1.0, 2.0])
    p = Polynomial([0.0])
    for k, ck in enumerate(power_x):
        p = p + ck * x_of_s**k
    values = p(np.linspace(0, 1, 101))
    scale = magnitude / max(np.abs(values).max(), 1e-12)
    return np.asarray(p.coef * scale)


def _default_stylus(model: str, rng: np.random.Generator) -> FloatArray:
    length = float(np.round(rng.uniform(50.0, 200.0)))
    if model == "MH1":  # a horizontal arm along x carries its stylus along the arm
        return np.array([length, 0.0, -float(np.round(rng.uniform(0.0, 60.0)))])
    if model == "MH2":
        return np.array([0.0, length, -float(np.round(rng.uniform(0.0, 60.0)))])
    return np.array([0.0, 0.0, -length])


def random_machine(rng: np.random.Generator, model: str) -> RandomMachine:
    """Draw a machine of kinematic model ``model`` (one of the ten codes)."""
    if model not in MODEL_AXES:
        raise ValueError(f"unknown kinematic model {model!r}; allowed: {', '.join(MODELS)}")
    span = np.round(
        np.array([rng.uniform(400, 1200), rng.uniform(400, 1500), rng.uniform(300, 800)]), -1
    )
    lower = np.where(rng.uniform(size=3) < 0.7, 0.0, np.round(rng.uniform(-0.5, 0.1, 3) * span, -1))
    upper = lower + span
    where = rng.choice(["lower", "centre", "random"])
    if where == "lower":
        reference = lower.copy()
    elif where == "centre":
        reference = lower + span / 2
    else:
        reference = np.round(lower + rng.uniform(0.0, 1.0, 3) * span, 1)
    magnitudes = {"positional": 15.0, "straightness": 6.0, "angular": 12.0}
    polynomials: dict[str, list[float]] = {}
    for name in TABLE_NAMES:
        k, slot = table_slot(name)
        if slot >= 3:
            kind = "angular"
        elif slot == k:
            kind = "positional"
        else:
            kind = "straightness"
        mag = magnitudes[kind] * rng.uniform(0.15, 1.0)
        polynomials[name] = polynomial_in_q(_smooth_curve(rng, mag), lower[k], span[k])
    expansion = {
        a: float(np.round(rng.choice([8.0, 10.5, 11.5]) + rng.uniform(-0.5, 0.5), 2)) for a in AXES
    }
    fixture = np.round(lower + rng.uniform(0.2, 0.8, 3) * span, 1)
    fixture[2] = lower[2]
    return RandomMachine(
        model=model,
        lower_mm=lower,
        upper_mm=upper,
        reference_mm=reference,
        stylus_mm=_default_stylus(model, rng),
        polynomials=polynomials,
        squareness_urad=np.round(rng.uniform(-20.0, 20.0, 3), 2),
        expansion=expansion,
        workpiece_expansion=float(np.round(rng.choice([11.5, 11.5, 10.8, 23.0]), 2)),
        workpiece_fixture_mm=fixture,
    )
