"""What the data could not identify, stated explicitly (docs/calibration.md §gauge).

* The rigid-body motions of the whole volume (3 translations, 3 rotations) that no data kind
  sees: translations are fixed by referring every linear error to the reference point,
  rotations are pinned at zero in θ (an inner constraint); for each data kind whether it sees
  them is checked, not assumed.
* The null space of the data: directions of θ that no reading sees to first order (the
  nuisance parameters — plate poses, stations, dead paths — marginalised), beyond the rigid
  rotations, for all data and for each data kind alone. Each is described by the errors it
  involves: one error's shapes (e.g. a run sees no constant), a pair seen only in combination
  (e.g. a yaw and a straightness seen through one stylus offset), or more; and by what it does
  to the volumetric error at the calibration stylus (after removing a rigid motion) and at
  other styli (±150 mm): zero at the calibration stylus but not elsewhere means "errors only
  seen through one stylus offset".
* The condition of the problem: of the data's information (whitened by the weak prior,
  without its null space) and of the full normal matrix.

Units: fields µm; positions mm.
"""

from __future__ import annotations

from itertools import combinations
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .rigid import grid_points, rigid_basis
from .solver import NULL_RATIO, Problem

__all__ = ["analyse_gauge"]

FloatArray = NDArray[np.float64]
_OTHER_STYLI_MM = ((150.0, 0.0, 0.0), (0.0, 150.0, 0.0), (0.0, 0.0, -150.0), (0.0, 0.0, 150.0))
_ONE = 1.0 - 1e-6  # a principal cosine above this: the subspaces share that direction
_SEEN_UM = 1e-3  # a field below this (µm per unit whitened step) is "nothing"


def _null_of(
    problem: Problem, stats: list[Any], blocks: set[int], lam: dict[str, float]
) -> FloatArray:
    """(P, k) the roughness-free directions the data of ``blocks`` do not see (whitened by the
    weak prior, orthonormal; zero on the shapes, which the smoothness prior carries)."""
    free, info = problem.free_information(stats, lam, blocks)
    w, v = np.linalg.eigh(info)
    out = np.zeros((problem.p, int(np.sum(w < NULL_RATIO))))
    out[free] = v[:, w < NULL_RATIO]
    return out


class _Fields:
    """Volumetric fields (rigid-free at the calibration stylus, raw at other styli) of whitened
    θ directions."""

    def __init__(
        self,
        problem: Problem,
        stylus_mm: FloatArray,
        steps: tuple[int, int, int],
        lam: dict[str, float],
    ):
        lay = problem.model.layout
        q = grid_points(lay.lower_mm, lay.upper_mm, steps)
        self.problem = problem
        self.root = np.sqrt(problem.ridge_internal)
        b = rigid_basis(q)
        proj = np.eye(b.shape[0]) - b @ np.linalg.pinv(b)
        g = problem.model.error_jacobian(problem.model.points(q, stylus_mm)).reshape(-1, lay.n)
        self.calib = proj @ problem.to_theta_jacobian(g)
        self.other = [
            problem.to_theta_jacobian(
                problem.model.error_jacobian(
                    problem.model.points(q, stylus_mm + np.asarray(s))
                ).reshape(-1, lay.n)
            )
            for s in _OTHER_STYLI_MM
        ]

    def effect(self, v: FloatArray) -> tuple[float, float]:
        """(RMS µm at the calibration stylus, rigid-free; RMS at other styli, change from the
        calibration stylus' field) of the whitened direction v (unit: one prior sd)."""
        x = v / self.root
        at_cal = float(np.sqrt(np.mean((self.calib @ x) ** 2)))
        base = self.other[0] @ x  # fields at other styli differ from each other by the Abbe terms
        others = max(float(np.sqrt(np.mean((o @ x - base) ** 2))) for o in self.other[1:])
        return at_cal, others


def _describe(problem: Problem, null: FloatArray, fields: _Fields) -> list[dict[str, Any]]:
    """The null space ``null`` (whitened, orthonormal) in terms of the errors involved."""
    lay = problem.model.layout
    groups: list[tuple[str, list[int], list[int]]] = []  # name, all coords, line coords
    for fn in lay.functions:
        n_line = fn.size - sum(
            1 for j in range(fn.start, fn.start + fn.size) if problem.shape_class[j]
        )
        groups.append(
            (
                fn.name,
                list(range(fn.start, fn.start + fn.size)),
                list(range(fn.start, fn.start + n_line)),
            )
        )
    for name, j in lay.squareness.items():
        groups.append((name, [j], [j]))
    out: list[dict[str, Any]] = []
    single_dim: dict[str, int] = {}
    explained = 0
    for name, cols, line in groups:
        dim, vecs = _intersection(null, cols)
        single_dim[name] = dim
        if dim:
            line_dim, _ = _intersection(null, line)
            out.append(_entry([name], dim, vecs, fields, _shapes(name, dim, line_dim, len(cols))))
            explained += dim
    for (na, ca, _), (nb, cb, _) in combinations(groups, 2):
        dim, vecs = _intersection(null, ca + cb)
        extra = dim - single_dim[na] - single_dim[nb]
        if extra > 0:
            out.append(
                _entry(
                    [na, nb],
                    extra,
                    vecs,
                    fields,
                    f"only their combination is seen ({extra} direction(s))",
                )
            )
            explained += extra
    rest = null.shape[1] - explained
    if rest > 0:
        share = {name: float(np.sum(null[cols, :] ** 2)) for name, cols, _ in groups}
        total = sum(share.values()) or 1.0
        involved = [n for n, v in sorted(share.items(), key=lambda kv: -kv[1]) if v / total > 0.02]
        out.append(
            {
                "errors": involved,
                "dimension": int(rest),
                "what": "combinations of three or more of these errors that no reading sees",
                "consequence": "see the pairs and single errors above; the U of the volumetric "
                "error carries whatever these do at the calibration stylus",
            }
        )
    return out


def _intersection(null: FloatArray, cols: list[int]) -> tuple[int, FloatArray]:
    """dim(span(coordinate axes ``cols``) ∩ span(null)) and an orthonormal basis of it."""
    if null.shape[1] == 0 or not cols:
        return 0, np.zeros((null.shape[0], 0))
    _, s, vt = np.linalg.svd(null[cols, :], full_matrices=False)
    keep = s > _ONE
    return int(np.sum(keep)), null @ vt[keep].T


def _shapes(name: str, dim: int, line_dim: int, size: int) -> str:
    if dim == size:
        return "not seen at all"
    if line_dim == dim and dim <= 2:
        return "its constant" if dim == 1 else "its constant and slope"
    return f"{dim} of its {size} shapes not seen"


def _entry(
    names: list[str], dim: int, vecs: FloatArray, fields: _Fields, what: str
) -> dict[str, Any]:
    effects = [fields.effect(vecs[:, k]) for k in range(vecs.shape[1])]
    at_cal = max((e[0] for e in effects), default=0.0)
    other = max((e[1] for e in effects), default=0.0)
    if at_cal <= _SEEN_UM and other > _SEEN_UM:
        consequence = "errors only seen through one stylus offset: the calibration stylus is right, others are not"
    elif at_cal <= _SEEN_UM:
        consequence = "no effect on any volumetric error"
    else:
        consequence = "not identified: the volumetric error at the calibration stylus depends on it (U carries the prior)"
    return {
        "errors": names,
        "dimension": int(dim),
        "what": what,
        "consequence": consequence,
        "effect_at_calibration_stylus_um_per_prior_sd": at_cal,
        "effect_at_other_styli_um_per_prior_sd": other,
    }


def analyse_gauge(
    problem: Problem,
    stats: list[Any],
    kinds: list[str],
    stylus_mm: FloatArray,
    lam: dict[str, float],
) -> dict[str, Any]:
    """The gauge report: rigid-body freedoms, the null space of all data and of each data kind
    (``kinds`` the kind of each block), the condition numbers."""
    fields = _Fields(problem, np.asarray(stylus_mm, dtype=float), (4, 4, 4), lam)
    all_blocks = set(range(len(problem.blocks)))
    free, info_all = problem.free_information(stats, lam, all_blocks)
    w = np.linalg.eigvalsh(info_all)
    seen = w[w >= NULL_RATIO]
    rigid = _rigid(problem, stats, kinds, lam)
    per_kind = {}
    for kind in sorted(set(kinds)):
        blocks = {i for i, k in enumerate(kinds) if k == kind}
        null = _without_rotations(problem, _null_of(problem, stats, blocks, lam), lam)
        per_kind[kind] = {
            "null_dimension": int(null.shape[1]),
            "freedoms": _describe(problem, null, fields),
        }
    null_all = _without_rotations(problem, _null_of(problem, stats, all_blocks, lam), lam)
    return {
        "rigid_body": rigid,
        "all_data": {
            "null_dimension": int(null_all.shape[1]),
            "freedoms": _describe(problem, null_all, fields),
            "fixed_by": "the weak prior (zero) while iterating; the covariance keeps its variance",
        },
        "per_data_kind": per_kind,
        "condition": {
            "parameters": int(problem.p),
            "free_directions": int(free.size),
            "identified_directions": int(seen.size),
            "data_information": float(seen.max() / seen.min()) if seen.size else None,
            "note": "ratio of the largest to the smallest eigenvalue of the data's information "
            "about the errors' roughness-free parts (constants, slopes, parabolas, squareness; "
            "shapes and nuisance marginalised, whitened by the weak prior), over the directions "
            "the data see; the shapes are carried by the smoothness prior (smoothness_tau)",
        },
    }


def _without_rotations(problem: Problem, null: FloatArray, lam: dict[str, float]) -> FloatArray:
    """The null space less the rigid rotations (reported separately)."""
    del lam  # the whitening is the weak prior's
    if null.shape[1] == 0 or problem.rotation_misfit > 1e-6:
        return null
    root = np.sqrt(problem.ridge_internal)
    r = problem.rotations.copy()
    for cols, t in problem.t_blocks:
        r[cols] = np.linalg.solve(t, problem.rotations[cols])
    r = r * root[:, None]
    q, _ = np.linalg.qr(r)
    rest = null - q @ (q.T @ null)
    u, s, _ = np.linalg.svd(rest, full_matrices=False)
    return u[:, s > 0.5]


def _rigid(
    problem: Problem, stats: list[Any], kinds: list[str], lam: dict[str, float]
) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for axis in "xyz":
        out.append(
            {
                "freedom": f"rigid translation along {axis}",
                "seen_by": [],
                "fixed_by": "every linear error is zero at the reference point (the lower corner)",
            }
        )
    representable = problem.rotation_misfit <= 1e-6
    for k, axis in enumerate("xyz"):
        seen_by = []
        if representable:
            root = np.sqrt(problem.ridge_internal)
            r = problem.rotations[:, k].copy()
            for cols, t in problem.t_blocks:
                r[cols] = np.linalg.solve(t, problem.rotations[cols, k])
            for kind in sorted(set(kinds)):
                blocks = {i for i, kk in enumerate(kinds) if kk == kind}
                free, info = problem.free_information(stats, lam, blocks)
                v = (r * root)[free]
                v = v / max(float(np.linalg.norm(v)), 1e-300)
                if float(v @ info @ v) >= NULL_RATIO:
                    seen_by.append(kind)
        out.append(
            {
                "freedom": f"rigid rotation about {axis}",
                "seen_by": seen_by,
                "fixed_by": "pinned at zero in the identified errors (inner constraint)"
                if representable
                else "not expressible by the identified errors",
            }
        )
    return out
