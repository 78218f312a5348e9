"""How much of a hidden signal a *static* change of the machine's tables could explain.

Not a diagnosis: a yardstick for reading the benchmark. For each of the 18 tables and the three
squareness values, the first-order response of the chain to a unit error (evaluated by finite
difference of the exact chain at the session's points and styli) times Legendre polynomials of the
table's own axis (order ≤ 6), plus one constant offset per axis, spans every static table change;
``share(signal)`` is the fraction of the signal's sum of squares (about its mean) that a
least-squares fit of that span removes (by projection on an orthonormal basis computed once per session).
Near 1: in this session the effect *is* a table change (e.g. a Z angular table with one stylus
is a Z straightness table). The generator refuses couplings that one table, or all tables
together, explain almost entirely; the benchmark prints the shares beside every miss.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import legendre as leg
from numpy.typing import NDArray

from .chain import TABLE_NAMES, stylus_error_um, table_slot
from .design import Session
from .machine import SQUARENESS, RandomMachine

FloatArray = NDArray[np.float64]

ORDER = 6


def _orthonormal(a: FloatArray) -> FloatArray:
    """An orthonormal basis of the columns of ``a``: modified Gram–Schmidt, each column projected
    out twice (numerically as good as Householder for this use), a column kept only when more
    than 1e-7 of its (unit) norm is left. einsum only: no multi-threaded BLAS, which on a busy
    2-core machine is a hundred times slower than one thread."""
    a = a / np.maximum(np.sqrt(np.einsum("ij,ij->j", a, a)), 1e-300)
    q = np.empty_like(a)
    rank = 0
    for j in range(a.shape[1]):
        v = a[:, j].copy()
        for _ in range(2):
            if rank:
                coef = np.einsum("ik,i->k", q[:, :rank], v)
                v -= np.einsum("ik,k->i", q[:, :rank], coef)
        norm = float(np.sqrt(np.einsum("i,i->", v, v)))
        if norm > 1e-7:
            q[:, rank] = v / norm
            rank += 1
    return q[:, :rank]


@dataclass
class TableBasis:
    """Orthonormal bases of the static table changes at one session's points (offsets included)."""

    names: list[str]
    all_tables: FloatArray  # (3N, r)
    single: list[FloatArray]  # per name: (3N, r_k)

    @staticmethod
    def _share(q: FloatArray, signal: FloatArray) -> float:
        y = (signal - signal.mean(axis=0)).reshape(-1)
        total = float(y @ y)
        if total <= 0:
            return 0.0
        proj = np.einsum("ij,i->j", q, y)
        return float(np.clip((proj @ proj) / total, 0.0, 1.0))

    def share(self, signal_um: FloatArray) -> float:
        """Fraction of the signal's sum of squares (about its mean) all tables together explain."""
        return self._share(self.all_tables, signal_um)

    def single_shares(self, signal_um: FloatArray) -> dict[str, float]:
        """The same for each table alone."""
        return {n: self._share(q, signal_um) for n, q in zip(self.names, self.single, strict=True)}


def table_basis(machine: RandomMachine, session: Session) -> TableBasis:
    q = session.q_mm
    n = q.shape[0]
    u = q - machine.reference_mm
    base_errors = machine.table_values(q)
    base_sq = np.broadcast_to(machine.squareness_urad, (n, 3)).copy()
    base = stylus_error_um(machine.model, u, session.stylus_mm, base_errors, base_sq)
    s = 2 * machine.normalised(q) - 1
    names: list[str] = []
    blocks: list[FloatArray] = []
    for name in TABLE_NAMES:
        k, slot = table_slot(name)
        errors = base_errors.copy()
        errors[:, k, slot] += 1.0
        response = stylus_error_um(machine.model, u, session.stylus_mm, errors, base_sq) - base
        poly = leg.legvander(s[:, k], ORDER)  # (N, ORDER + 1)
        blocks.append((response[:, :, None] * poly[:, None, :]).reshape(3 * n, ORDER + 1))
        names.append(name)
    for j, name in enumerate(SQUARENESS):
        sq = base_sq.copy()
        sq[:, j] += 1.0
        response = stylus_error_um(machine.model, u, session.stylus_mm, base_errors, sq) - base
        blocks.append(response.reshape(3 * n, 1))
        names.append(name)
    offsets = np.zeros((3 * n, 3))
    for k in range(3):
        offsets[k::3, k] = 1.0
    return TableBasis(
        names=names,
        all_tables=_orthonormal(np.hstack([*blocks, offsets])),
        single=[_orthonormal(np.hstack([b, offsets])) for b in blocks],
    )
