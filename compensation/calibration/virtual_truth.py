"""Virtual machines for the planner: a machine drawn from a guess' uncertainty model — the virtual
CMM's model (docs/uncertainty.md, :mod:`..uncertainty.fields`): every table of the guess plus
one smooth random function (u·Z(q) + u_per_m·d·ξ₁ + u_relative·value·ξ₂, Z the unit Gaussian
process of the table's correlation length), every squareness plus u·ξ.

The drawn machine is an ordinary :class:`Machine` (tables tabulated densely over the plan's
travel), so the readings it gives come from the public machine API (:mod:`.simulate`).
Units: mm, µm, µrad.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np

from ..parametric_errors import AXES, AXIS_INDEX, SQUARENESS, TABLE_COMPONENTS
from ..uncertainty.fields import squared_exponential_basis

if TYPE_CHECKING:
    from ..machine import Machine
    from .plan import Plan

__all__ = ["draw_machine", "guess_on_plan"]

TABLE_POINTS = 61


def guess_on_plan(guess: Machine, plan: Plan) -> Machine:
    """The guess with the plan's volume (reference at the lower corner) and stylus, its tables
    tabulated over the plan's travel (what a table evaluates to there)."""
    return _rebuilt(guess, plan, None)


def draw_machine(guess: Machine, plan: Plan, rng: np.random.Generator) -> Machine:
    """One virtual machine: the guess plus a draw of its calibration uncertainty."""
    return _rebuilt(guess, plan, rng)


def _rebuilt(guess: Machine, plan: Plan, rng: np.random.Generator | None) -> Machine:
    from ..machine import Machine

    if guess.model != plan.model:
        raise ValueError(
            f"{guess.source}: model {guess.model} but the plan {plan.source} is for {plan.model}"
        )
    mdl = guess.uncertainty_model()
    vol = plan.base.volume
    errors: dict[str, Any] = {}
    for comp in TABLE_COMPONENTS:
        table = guess.tables.get(comp)
        tu = mdl.tables.get(comp)
        if table is None and (tu is None or rng is None):
            continue
        k = AXIS_INDEX[comp[-1]]
        q = np.linspace(vol.lower_mm[k], vol.upper_mm[k], TABLE_POINTS)
        base = table.evaluate(q) if table is not None else np.zeros_like(q)
        value = base.copy()
        if rng is not None and tu is not None and not tu.is_zero:
            lo, hi = tu.span_mm
            z = np.zeros_like(q)
            if tu.u > 0 and hi > lo:
                basis = squared_exponential_basis(lo, hi, tu.correlation_mm)
                z = basis.features(q) @ rng.standard_normal(basis.modes)
            value += (
                tu.u * z
                + tu.u_per_m * (q - tu.reference_mm) / 1000.0 * rng.standard_normal()
                + tu.u_relative * base * rng.standard_normal()
            )
        entry: dict[str, Any] = {"position": q.tolist(), "value": value.tolist()}
        if table is not None and table.reversal is not None:
            entry["reversal"] = table.evaluate_reversal(q).tolist()
        errors[comp] = entry
    sq = np.asarray(guess.squareness_urad, dtype=float).copy()
    if rng is not None:
        sq += mdl.squareness_urad * rng.standard_normal(3)
    desc = json.loads(json.dumps(guess.description, default=float))
    desc["errors"] = errors
    desc["squareness"] = dict(zip(SQUARENESS, sq.tolist(), strict=True))
    desc["volume"] = {
        a: [float(vol.lower_mm[k]), float(vol.upper_mm[k])] for k, a in enumerate(AXES)
    }
    desc["probe"] = {"offset": [float(v) for v in plan.stylus_mm]}
    desc.pop("uncertainty", None)
    return Machine.from_dict(desc, source=f"virtual machine drawn from {guess.source}")
