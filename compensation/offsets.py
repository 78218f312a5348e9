"""Measurement offsets: refer parametric errors measured away from the reference point to it.

The paper's section 4 / appendix A.2, derived here from the kinematic chain instead of by
intuition (docs/seed-equations.md compares the two):

* A linear error ``δ_i(a)`` of axis a measured along a line through the offset point ``o`` picks
  up the Abbe terms of axis a's angular errors with arms measured from the reference point. With
  ``J`` the first-order coefficients of the chain (:func:`kinematics.first_order_jacobian`)::

      δ*_i(a)(q) = δ_i(a)(q) − Σ_k [J_i,ak(o) − J_i,ak(ref)] · ε_k(a)(q)

  and straightness tables are then processed by their straightness criterion.
* A squareness measured with lines through ``o`` is the angle between the two fitted lines; the
  angular errors bend those lines (Abbe terms along each line), so the measured value is corrected
  by the least-squares slopes of those terms: for α, ``α* = α_m + slope_x(ΔY_ang) + slope_y(ΔX_ang)``
  (both along lines through ``o``), and likewise for β1 (XZ) and β2 (YZ).

Angular errors are the same everywhere on a rigid carriage and are never transformed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .components import AXIS_INDEX
from .kinematics import first_order_jacobian

if TYPE_CHECKING:
    from .machine import Machine

#: squareness → (the two axes whose lines define it, the error component each line shows)
_SQUARENESS_LINES = {
    0: (("x", 1), ("y", 0)),  # α: ΔY along X, ΔX along Y
    1: (("x", 2), ("z", 0)),  # β1: ΔZ along X, ΔX along Z
    2: (("y", 2), ("z", 1)),  # β2: ΔZ along Y, ΔY along Z
}


def angular_terms(machine: Machine, axis: str, q_mm: np.ndarray, at_mm: np.ndarray) -> np.ndarray:
    """First-order contribution (N, 3) µm of axis ``axis``'s angular errors when that axis is at
    ``q_mm`` (N,) and the other axes at the point ``at_mm`` (3,), stylus zero."""
    k = AXIS_INDEX[axis]
    pts = np.repeat(np.asarray(at_mm, dtype=float)[None, :], len(q_mm), axis=0)
    pts[:, k] = q_mm
    u = pts - machine.volume.reference_mm
    jac, _ = first_order_jacobian(machine.chain, u, np.zeros(3))
    errors = machine.parametric_errors(pts)
    return np.einsum("nis,ns->ni", jac[:, :, k, 3:], errors[:, k, 3:])


def refer_to_reference(machine: Machine, squareness_offset_mm: np.ndarray | None) -> None:
    """Transform, in place, every table with an ``offset`` and apply straightness criteria."""
    from .straightness import apply_criterion

    ref = machine.volume.reference_mm
    for name, table in list(machine.tables.items()):
        comp = table.component
        if comp.is_angular:
            if table.offset_mm is not None or table.criterion is not None:
                pass  # angular errors are independent of where they were measured
            continue
        values = None
        if table.offset_mm is not None:
            if table.position_mm is None or table.value is None:
                raise ValueError(
                    f"{name}: a measurement offset needs tabulated values, not a polynomial"
                )
            q = table.position_mm
            i = AXIS_INDEX[comp.direction]
            at_offset = angular_terms(machine, comp.axis, q, table.offset_mm)[:, i]
            at_ref = angular_terms(machine, comp.axis, q, ref)[:, i]
            values = table.value - (at_offset - at_ref)
        if table.criterion is not None:
            assert table.position_mm is not None and table.value is not None
            base = table.value if values is None else values
            values = apply_criterion(table.position_mm, base, table.criterion)
        if values is not None:
            machine.tables[name] = table.with_values(values)
    if squareness_offset_mm is not None:
        machine.squareness_urad = machine.squareness_urad - squareness_angular_part(
            machine, squareness_offset_mm
        )


def squareness_angular_part(machine: Machine, at_mm: np.ndarray, samples: int = 41) -> np.ndarray:
    """The part of (α, β1, β2) µrad that angular errors add when the squareness is measured with
    lines through ``at_mm``: least-squares slopes of their Abbe terms along the two lines."""
    out = np.zeros(3)
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    for j, lines in _SQUARENESS_LINES.items():
        total = 0.0
        for axis, comp in lines:
            k = AXIS_INDEX[axis]
            q = np.linspace(lo[k], hi[k], samples)
            terms = angular_terms(machine, axis, q, at_mm)[:, comp]
            slope_um_per_mm = np.polyfit(q, terms, 1)[0]
            total += slope_um_per_mm * 1000.0  # µm/mm → µrad
        out[j] = -total
    return out
