"""Measurement offsets: refer parametric errors measured away from the reference point to it.

The paper's section 4 / appendix A.2, derived here from the kinematic chain instead of by
intuition (docs/seed-equations.md compares the two):

* A linear error ``δ_i(a)`` of axis a measured along a line through the offset point ``o`` reads
  the model's ``δ_i(a)`` plus the Abbe terms of axis a's angular errors at ``o``. With ``J`` the
  first-order coefficients of the chain (:func:`kinematics.first_order_jacobian`)::

      δ*_i(a)(q) = δ_i(a)(q) − Σ_k J_i,ak(o; q) · ε_k(a)(q)

  and straightness tables are then processed by their straightness criterion. For a tool-side
  axis ``J(ref) = 0``, so this is the paper's "difference of arms" rule. For a table (workpiece
  side) ``J(ref)`` is not zero: the table turns about its own reference point, which the stylus
  is ``u_a`` away from (the ``+y·Ez(y)`` of FB1's ΔX), and a line measured through the reference
  reads that term too; it is removed, so the model reproduces the measured line.
  A table *without* ``offset`` is taken as the model's parametric error itself (the paper's A.1
  δ), untransformed.
* A squareness measured with lines through ``o`` is the angle between the two fitted lines; the
  angular errors of all axes bend those lines (Abbe terms along each line), so the measured value
  is corrected by the least-squares slopes of those terms: for α,
  ``α* = α_m + slope_x(ΔY_ang) + slope_y(ΔX_ang)`` (both along lines through ``o``), and likewise
  for β1 (XZ) and β2 (YZ).

Angular errors are the same everywhere on a rigid carriage and are never transformed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .kinematics import first_order_jacobian
from .parametric_errors import AXIS_INDEX

if TYPE_CHECKING:
    from .machine import Machine

#: squareness → (the two axes whose lines define it, the error component each line shows)
_SQUARENESS_LINES = {
    0: (("x", 1), ("y", 0)),  # α: ΔY along X, ΔX along Y
    1: (("x", 2), ("z", 0)),  # β1: ΔZ along X, ΔX along Z
    2: (("y", 2), ("z", 1)),  # β2: ΔZ along Y, ΔY along Z
}


def angular_terms(
    machine: Machine, axis: str, q_mm: np.ndarray, at_mm: np.ndarray, *, all_axes: bool = False
) -> np.ndarray:
    """First-order contribution (N, 3) µm of angular errors along a line parallel to ``axis``
    (that axis at ``q_mm`` (N,), the others at the point ``at_mm`` (3,), stylus zero): of the
    moving axis' own angular errors, or with ``all_axes`` of every axis' (whose arms may grow
    along the line)."""
    k = AXIS_INDEX[axis]
    pts = np.repeat(np.asarray(at_mm, dtype=float)[None, :], len(q_mm), axis=0)
    pts[:, k] = q_mm
    u = pts - machine.volume.reference_mm
    jac, _ = first_order_jacobian(machine.chain, u, np.zeros(3))
    errors = machine.parametric_errors(pts)
    if all_axes:
        return np.einsum("nias,nas->ni", jac[:, :, :, 3:], errors[:, :, 3:])
    return np.einsum("nis,ns->ni", jac[:, :, k, 3:], errors[:, k, 3:])


def refer_to_reference(machine: Machine, squareness_offset_mm: np.ndarray | None) -> None:
    """Transform, in place, every table with an ``offset`` and apply straightness criteria."""
    from .straightness import apply_criterion

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
            values = table.value - angular_terms(machine, comp.axis, q, table.offset_mm)[:, i]
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


def squareness_angular_part(machine: Machine, at_mm: np.ndarray, samples: int = 101) -> np.ndarray:
    """The part of (α, β1, β2) µrad that angular errors add when the squareness is measured with
    lines through ``at_mm``: least-squares slopes of their Abbe terms along the two lines. Each
    line is sampled where its straightness table is tabulated (the same runs give the squareness),
    else at ``samples`` points over the axis' travel in the working volume."""
    out = np.zeros(3)
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    for j, lines in _SQUARENESS_LINES.items():
        total = 0.0
        for axis, comp in lines:
            k = AXIS_INDEX[axis]
            table = machine.tables.get(f"d{'xyz'[comp]}_{axis}")
            if table is not None and table.position_mm is not None and len(table.position_mm) >= 2:
                q = table.position_mm
            else:
                q = np.linspace(lo[k], hi[k], samples)
            terms = angular_terms(machine, axis, q, at_mm, all_axes=True)[:, comp]
            slope_um_per_mm = np.polyfit(q, terms, 1)[0]
            total += slope_um_per_mm * 1000.0  # µm/mm → µrad
        out[j] = -total
    return out
