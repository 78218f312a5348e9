"""Random but realistic nominal machine descriptions for all ten kinematic models.

A :class:`MachineSpec` carries the TOML-shaped dict (docs/formats.md §1) that
``Machine.from_dict`` accepts, plus the numbers the generator needs (span, reference,
expansion). The nominal parametric errors are smooth random polynomials in the indicated axis
position (``polynomial = [c0, c1, …]``, q in mm): positional 2–20 µm, straightness 1–6 µm,
angular 1–10 µrad over the travel. This is what the diagnosis is given; the hidden effects
(:mod:`.effects`) are added on top by the generator's own chain.

Units: mm, µm, µrad, °C, µm/(m·°C).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .chains import AXES, MODELS

FloatArray = NDArray[np.float64]

# amplitude ranges of the nominal tables over the travel (µm or µrad)
_NOMINAL_RANGE = {"positional": (2.0, 20.0), "straightness": (1.0, 6.0), "angular": (1.0, 10.0)}


@dataclass
class MachineSpec:
    """A nominal machine: its description dict and the numbers the generator uses."""

    model: str
    description: dict[str, Any]
    lower_mm: FloatArray  # (3,)
    upper_mm: FloatArray  # (3,)
    reference_mm: FloatArray  # (3,)
    probe_mm: FloatArray  # (3,) default stylus
    expansion: dict[str, float]  # µm/(m·°C) per axis
    reference_C: float
    workpiece_expansion: float  # µm/(m·°C)
    workpiece_fixture_mm: FloatArray  # (3,)

    @property
    def span_mm(self) -> FloatArray:
        return self.upper_mm - self.lower_mm

    def machine(self) -> Any:
        """The project's ``Machine`` for this description (the diagnosis' nominal model)."""
        from cmm_comp.compensation.machine import Machine

        return Machine.from_dict(self.description, source=f"<independent {self.model}>")


def smooth_polynomial(
    rng: np.random.Generator, lo: float, hi: float, amplitude: float
) -> list[float]:
    """Power-series coefficients (c0 first, q in mm) of a smooth random curve of peak ≈ amplitude on [lo, hi]."""
    order = int(rng.integers(2, 5))
    s = np.cos(np.pi * (np.arange(order + 1) + 0.5) / (order + 1))  # Chebyshev nodes
    values = rng.normal(0.0, 1.0, order + 1)
    q = lo + (s + 1.0) / 2.0 * (hi - lo)
    poly = np.polynomial.Polynomial.fit(q, values, order)
    grid = np.linspace(lo, hi, 50)
    peak = np.abs(poly(grid)).max()
    coef = poly.convert().coef * amplitude / max(peak, 1e-12)
    return [float(c) for c in coef]


def _kind(component: str) -> str:
    if component[0] == "e":
        return "angular"
    return "positional" if component[1] == component[3] else "straightness"


def draw_machine(rng: np.random.Generator, model: str | None = None) -> MachineSpec:
    """A random machine of ``model`` (random of the ten when None)."""
    code = model or str(rng.choice(sorted(MODELS)))
    column = code.startswith("C")
    x_span = rng.uniform(400.0, 900.0) if column else rng.uniform(500.0, 2000.0)
    y_span = rng.uniform(300.0, 700.0) if column else rng.uniform(400.0, 2000.0)
    z_span = rng.uniform(250.0, 600.0) if column else rng.uniform(300.0, 1200.0)
    span = np.array([x_span, y_span, z_span]).round(0)
    lower = np.zeros(3) if rng.random() < 0.6 else rng.uniform(-300.0, 100.0, 3).round(0)
    upper = lower + span
    where = rng.random()
    if where < 0.4:
        reference = lower.copy()
    elif where < 0.6:
        reference = (lower + span / 2.0).round(1)
    else:
        reference = (lower + rng.uniform(0.0, 1.0, 3) * span).round(1)
    probe = np.array([0.0, 0.0, -float(rng.uniform(50.0, 250.0))]).round(1)
    base_alpha = float(rng.choice([8.0, 10.5, 11.5]))
    expansion = {a: round(base_alpha + float(rng.uniform(-0.8, 0.8)), 2) for a in AXES}
    reference_C = 20.0
    wp_alpha = float(rng.choice([11.5, 16.5, 23.0]))
    fixture = (lower + rng.uniform(0.2, 0.8, 3) * span).round(0)
    fixture[2] = lower[2]
    errors: dict[str, Any] = {}
    for j, axis in enumerate(AXES):
        for i in AXES:
            for prefix in ("d", "e"):
                comp = f"{prefix}{i}_{axis}"
                lo_a, hi_a = _NOMINAL_RANGE[_kind(comp)]
                amp = float(rng.uniform(lo_a, hi_a))
                if comp == f"ex_{axis}":
                    amp *= 0.5  # rolls are usually smaller
                errors[comp] = {"polynomial": smooth_polynomial(rng, lower[j], upper[j], amp)}
    squareness = {k: round(float(rng.uniform(-30.0, 30.0)), 2) for k in ("alpha", "beta1", "beta2")}
    description: dict[str, Any] = {
        "format": "cmm-machine/1",
        "name": f"indep-{code.lower()}",
        "model": code,
        "volume": {
            "x": [float(lower[0]), float(upper[0])],
            "y": [float(lower[1]), float(upper[1])],
            "z": [float(lower[2]), float(upper[2])],
            "reference": [float(v) for v in reference],
        },
        "probe": {"offset": [float(v) for v in probe]},
        "thermal": {
            "reference_C": reference_C,
            "expansion": expansion,
            "workpiece_expansion": wp_alpha,
            "workpiece_fixture": [float(v) for v in fixture],
        },
        "squareness": squareness,
        "errors": errors,
    }
    return MachineSpec(
        model=code,
        description=description,
        lower_mm=lower,
        upper_mm=upper,
        reference_mm=reference,
        probe_mm=probe,
        expansion=expansion,
        reference_C=reference_C,
        workpiece_expansion=wp_alpha,
        workpiece_fixture_mm=fixture,
    )
