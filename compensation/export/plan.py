"""Which parts of the model a format's tables carry: a :class:`Plan` in error space (µm).

A plan lists, per output axis k, one-axis tables ``plain[(a, k)]`` (a function of axis a added to
the error of axis k), direction parts ``directional[(a, k)]`` (± that function as axis a last
moved up or down) and products ``u(q_a)·v(q_b)``. The format modules turn a plan into their own
tables (units, signs, rounding) and the residual is measured on what they write.

:func:`choose_greedy` fills a table budget (SINUMERIK's number of CEC tables) in order of the
mean square each table removes per table spent; :func:`left_out` names, with their size, the
parts of the model a plan leaves for the daemon.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..parametric_errors import AXES
from .decompose import Decomposition, Interaction
from .splines import FloatArray

__all__ = ["Plan", "choose_greedy", "left_out", "own_axis_plan"]


@dataclass
class Plan:
    """Tables in error space (µm at the points of their input axis)."""

    plain: dict[tuple[int, int], FloatArray] = field(default_factory=dict)
    directional: dict[tuple[int, int], FloatArray] = field(default_factory=dict)
    products: list[Interaction] = field(default_factory=list)

    def add_plain(self, d: Decomposition, a: int, k: int) -> None:
        """Table a → k with the main effect; the first table of output k also takes its mean."""
        values = d.main_values[k][a].copy()
        if not any(kk == k for _, kk in self.plain):
            values = values + d.mean_um[k]
        self.plain[(a, k)] = values

    def add_directional(self, d: Decomposition, a: int, k: int) -> None:
        self.directional[(a, k)] = d.dir_values[a][k].copy()


def own_axis_plan(d: Decomposition, cross: bool = False, min_rms_um: float = 0.01) -> Plan:
    """Each axis corrected by a table of its own position (with its direction part); with
    ``cross`` also by the one other axis whose main effect is largest (TwinCAT's one cross
    compensation per axis), when it is worth at least ``min_rms_um``."""
    plan = Plan()
    for k in range(3):
        plan.add_plain(d, k, k)
        if k in d.direction_axes and d.dir_energy[k][k] > 0:
            plan.add_directional(d, k, k)
        if cross:
            others = [a for a in range(3) if a != k]
            best = max(others, key=lambda a: d.main_energy[k, a])
            if math.sqrt(d.main_energy[k, best]) >= min_rms_um:
                plan.add_plain(d, best, k)
    return plan


@dataclass(frozen=True)
class _Candidate:
    kind: str  # "plain", "dir", "product"
    key: tuple[int, ...]
    gain: float  # µm², given its requirements are in
    cost: int
    requires: tuple[tuple[str, tuple[int, ...]], ...]


def _candidates(d: Decomposition, products: bool, min_rms_um: float) -> dict[Any, _Candidate]:
    floor = min_rms_um**2
    out: dict[Any, _Candidate] = {}
    for k in range(3):
        for a in range(3):
            out[("plain", (a, k))] = _Candidate("plain", (a, k), d.main_energy[k, a], 1, ())
            if a in d.direction_axes and d.dir_energy[a][k] >= floor:
                out[("dir", (a, k))] = _Candidate(
                    "dir", (a, k), float(d.dir_energy[a][k]), 1, (("plain", (a, k)),)
                )
    if products:
        for t in d.interactions:
            if t.energy < floor:
                continue
            # Siemens' example semantics: the referenced (arm) table acts only as the factor and
            # the referencing (rate) table's own value is < 1/1000 of the product: no plain
            # table is needed to take either back
            req: tuple[tuple[str, tuple[int, ...]], ...] = ()
            if t.rank > 1:
                req += (("product", (t.a, t.b, t.k, t.rank - 1)),)
            key = (t.a, t.b, t.k, t.rank)
            out[("product", key)] = _Candidate("product", key, t.energy, 2, req)
    return out


def choose_greedy(
    d: Decomposition, max_tables: int, products: bool, min_rms_um: float = 0.01
) -> Plan:
    """Spend at most ``max_tables`` tables (a direction pair counts 2, a product 2) on the parts
    that remove the most mean square per table, requirements included (a direction part needs
    its plain table, a rank-2 product its rank-1 product); a part smaller than ``min_rms_um``
    RMS is not worth a table. The mean of an output goes with its first table."""
    cands = _candidates(d, products, min_rms_um)
    chosen: set[Any] = set()
    budget = max_tables

    def closure(key: Any) -> list[Any]:
        need: list[Any] = []
        stack = [key]
        while stack:
            item = stack.pop()
            if item in chosen or item in need:
                continue
            need.append(item)
            stack.extend(cands[item].requires if item in cands else [])
        return need

    def gain_of(items: list[Any]) -> float:
        """Mean square removed by adding ``items``; an output's mean counts once, with the
        first plain table of that output."""
        g = sum(cands[i].gain for i in items)
        have = {x[1][1] for x in chosen if x[0] == "plain"}
        new = {cands[i].key[1] for i in items if cands[i].kind == "plain"} - have
        return g + sum(float(d.mean_um[k] ** 2) for k in new)

    while True:
        best, best_ratio = None, 0.0
        for key, c in cands.items():
            if key in chosen or c.gain < min_rms_um**2:
                continue
            need = closure(key)
            if any(n not in cands for n in need):
                continue
            cost = sum(cands[n].cost for n in need)
            if cost > budget:
                continue
            ratio = gain_of(need) / cost
            if ratio > best_ratio:
                best, best_ratio = key, ratio
        if best is None:
            break
        for n in reversed(closure(best)):
            chosen.add(n)
            budget -= cands[n].cost
    plan = Plan()
    by_key = {(t.a, t.b, t.k, t.rank): t for t in d.interactions}
    for kind, key in sorted(chosen, key=lambda x: (x[0] != "plain", x[0] != "dir", x)):
        if kind == "plain":
            plan.add_plain(d, *key)
        elif kind == "dir":
            plan.add_directional(d, *key)
        else:
            plan.products.append(by_key[key])
    # an output whose tables were all too small still gets nothing: its mean stays in the residual
    return plan


def left_out(d: Decomposition, plan: Plan) -> list[dict[str, Any]]:
    """The parts of the model the plan does not carry, largest first: ``{"output", "part",
    "rms_um"}`` (RMS over the volume, from the decomposition's quadrature)."""
    rows: list[tuple[float, str, str]] = []
    for k in range(3):
        out = AXES[k].upper()
        if not any(kk == k for _, kk in plan.plain) and abs(d.mean_um[k]) > 0:
            rows.append((float(d.mean_um[k] ** 2), out, "mean offset over the volume"))
        for a in range(3):
            if (a, k) not in plan.plain:
                rows.append((float(d.main_energy[k, a]), out, f"function of {AXES[a]} alone"))
        for a in d.direction_axes:
            if (a, k) not in plan.directional:
                rows.append(
                    (float(d.dir_energy[a][k]), out, f"direction-dependent part (dir_{AXES[a]})")
                )
    for (a, b, k), total in d.pair_energy.items():
        kept = sum(t.energy for t in plan.products if (t.a, t.b, t.k) == (a, b, k))
        rows.append(
            (max(total - kept, 0.0), AXES[k].upper(), f"two-axis term of {AXES[a]} and {AXES[b]}")
        )
    rows = [r for r in rows if r[0] >= 1e-6]  # below 0.001 µm RMS: quadrature noise
    rows.sort(key=lambda r: -r[0])
    return [{"output": o, "part": p, "rms_um": float(np.sqrt(e))} for e, o, p in rows]
