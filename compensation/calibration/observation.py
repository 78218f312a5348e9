"""What every observation block gives the solver (:mod:`.solver`): its rows' residuals
(model − data, µm or µrad) linearised in the machine's parameters θ and in the block's own
nuisance parameters (a plate placement's pose, a station's position and dead path), the
variance group of each row and the rows whose constant (and slope) the instrument cannot see.

A block's nuisance *state* is immutable: :meth:`Block.advance` returns the state after a step,
so the solver can try a step and keep the old state when it does not reduce the misfit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .model import MachineModel

__all__ = ["Block", "Linearization", "Projection", "VarianceGroup"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


@dataclass(frozen=True)
class VarianceGroup:
    """Rows that share one standard uncertainty: ``sigma0`` a priori (the plan's), re-estimated
    by the fit. ``unit`` µm or µrad; ``quantity`` names it in the report."""

    dataset: int
    quantity: str
    unit: str
    sigma0: float


@dataclass(frozen=True)
class Projection:
    """Rows whose readings are relative: the least-squares fit of ``design`` (rows × k: a
    constant, or a constant and a line) is removed from data and model alike (what the
    instrument cannot see: a run's zero, a straightness pass' line)."""

    rows: IntArray
    design: FloatArray


@dataclass(frozen=True)
class Linearization:
    """Residuals (n,) and Jacobians with respect to θ (n, P) and the block's nuisance (n, Q)."""

    residual: FloatArray
    jac_machine: FloatArray
    jac_nuisance: FloatArray


@dataclass
class Block:
    """Base of the observation blocks; subclasses implement the model of one data kind."""

    kind: str  # laser | plate | multilateration
    dataset: int
    source: str
    groups: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))  # local index
    variance_groups: list[VarianceGroup] = field(default_factory=list)
    projections: list[Projection] = field(default_factory=list)
    lines: tuple[int, ...] = ()

    @property
    def n_rows(self) -> int:
        return int(self.groups.shape[0])

    @property
    def n_nuisance(self) -> int:
        return 0

    def nuisance_precision(self) -> FloatArray:
        """(Q,) prior precision of the nuisance parameters (0 = flat)."""
        return np.zeros(self.n_nuisance)

    def random_effects(self) -> list[tuple[IntArray, str, float]]:
        """Nuisance parameters that are random effects: (their indices within the block's
        nuisance, a name, the a-priori σ); their prior N(0, σ²) has its σ estimated by the fit."""
        return []

    def local_nuisance(self) -> IntArray:
        """Nuisance parameters (indices within the block's, in groups of 3) that each only its
        own rows see, no two groups sharing a row — a point's offsets: the solver eliminates
        them from its normal matrix by a Schur complement (:mod:`.normal`)."""
        return np.zeros(0, dtype=np.intp)

    def initial_state(self, model: MachineModel, theta: FloatArray) -> Any:
        return None

    def linearize(self, model: MachineModel, theta: FloatArray, state: Any) -> Linearization:
        raise NotImplementedError

    def advance(self, state: Any, delta: FloatArray) -> Any:
        return state

    def describe_state(self, state: Any, covariance: FloatArray | None) -> dict[str, Any]:
        return {}


def project(rows_values: FloatArray, projections: list[Projection]) -> FloatArray:
    """``rows_values`` ((n,) or (n, P)) with each projection's least-squares fit removed."""
    out = np.array(rows_values, dtype=float, copy=True)
    for p in projections:
        block = out[p.rows]
        coef, *_ = np.linalg.lstsq(p.design, block, rcond=None)
        out[p.rows] = block - p.design @ coef
    return out


def kabsch(source_mm: FloatArray, target_mm: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The rotation R and translation t (mm) minimising Σ|R·source + t − target|² (Kabsch)."""
    cs, ct = source_mm.mean(axis=0), target_mm.mean(axis=0)
    h = (source_mm - cs).T @ (target_mm - ct)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, ct - r @ cs


def skew(v: FloatArray) -> FloatArray:
    """(…, 3, 3) cross-product matrices: skew(v) @ w = v × w."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rotation_from_vector(phi_rad: FloatArray) -> FloatArray:
    """Rodrigues: the rotation of the rotation vector ``phi_rad`` (3,)."""
    angle = float(np.linalg.norm(phi_rad))
    if angle < 1e-300:
        return np.eye(3)
    k = skew(np.asarray(phi_rad) / angle)
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)
