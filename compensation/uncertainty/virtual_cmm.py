"""The virtual CMM (after ISO/TS 15530-4): whole machines drawn from the uncertainty model,
evaluated exactly, vectorised over Monte Carlo trials.

One trial is one plausible *true* machine: every parametric table is the machine's table plus
its calibration error (one smooth random function along the axis, :mod:`.fields`), every
squareness its value plus an error, the scale and workpiece expansion coefficients and the
temperature sensors likewise (one draw per machine: they are systematic over a measurement);
each probing point adds the tables' random parts (the paper's 2σ bands, independent at every
probing) and a probing error. The *corrected* position is what the model says (the grid
reproduces it to its interpolation error); the **residual** ``r = true error − model error``
(µm) is what the correction leaves: true position = corrected + r.

The chain is evaluated exactly (:func:`..kinematics.exact_pose`, full rigid-body transforms)
for the perturbed and the nominal errors at once; the thermal residual
``(α + εα)(ΔT + εT) − α·ΔT`` is evaluated exactly too. Effects (``[[effects]]``) enter as the
model has them, without uncertainty. Units: positions mm, residuals µm, angles µrad, °C.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..parametric_errors import AXIS_INDEX, parse_component
from ..thermal.roles import WORKPIECE, scale_role
from .chain_kernel import assemble_errors, chain_axes, exact_pose_compiled, residual_compiled
from .fields import squared_exponential_basis
from .model import UncertaintyModel

if TYPE_CHECKING:
    from ..machine import Machine

__all__ = ["ROWS_PER_CHUNK", "Prepared", "VirtualCMM"]

FloatArray = NDArray[np.float64]
ROWS_PER_CHUNK = 120_000  # trials × points evaluated at once (memory ~ 100 MB)


@dataclass(frozen=True)
class Prepared:
    """Everything about N probing points that does not change between trials.

    The tables' calibration errors of one trial are linear in standard normal numbers ξ (D,):
    at the S distinct (table, position) pairs they are ``ξ @ calibration`` (D, S); ``source``
    and ``target`` scatter them onto the flat (N·3·6) parametric errors. The random parts are
    σ·ζ at the flat indices ``random_target``."""

    q_mm: FloatArray
    stylus_mm: FloatArray  # (N, 3)
    errors: FloatArray  # (N, 3, 6) nominal parametric errors (after effects)
    squareness_urad: FloatArray  # (N, 3)
    u_mm: FloatArray  # (N, 3) positions from the reference
    rotation0: FloatArray  # (N, 3, 3) nominal error rotation
    translation0_um: FloatArray  # (N, 3)
    calibration: FloatArray  # (D, S) µm or µrad per standard normal number
    source: NDArray[np.intp]  # (P,) column of ``calibration`` …
    target: NDArray[np.intp]  # (P,) … added to this flat index of the (N, 3, 6) errors
    random_sigma: FloatArray  # (R,) σ of the random parts, µm or µrad
    random_target: NDArray[np.intp]  # (R,) their flat indices
    scale: tuple[tuple[int, float, FloatArray, float, float], ...]  # (k, α, ΔT (N,), uα, uT)
    workpiece: tuple[float, FloatArray, FloatArray, float, float] | None  # α, ΔT, lever mm, uα, uT

    @property
    def n(self) -> int:
        return int(self.q_mm.shape[0])

    @functools.cached_property
    def calibration_t(self) -> Any:
        """``calibration`` transposed as a sparse matrix (it is block diagonal, mostly zeros)."""
        from scipy.sparse import csr_array

        return csr_array(self.calibration.T)


class VirtualCMM:
    """Draws virtual machines consistent with ``machine``'s uncertainty model.

    ``temps_C`` / ``inputs``: the measurement conditions as the sensors report them (scalars or
    (N,) arrays per signal, as for :meth:`Machine.volumetric_error`; default the reference).
    ``model``: an :class:`UncertaintyModel` (default ``machine.uncertainty_model()``).
    """

    def __init__(
        self,
        machine: Machine,
        model: UncertaintyModel | None = None,
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> None:
        self.machine = machine
        self.model = model if model is not None else machine.uncertainty_model()
        self.temps_C = dict(temps_C) if temps_C else None
        self.inputs = dict(inputs) if inputs else None
        self._axes = chain_axes(machine.chain)

    # ------------------------------------------------------------------ preparation
    def prepare(self, points_mm: ArrayLike, stylus_mm: ArrayLike | None = None) -> Prepared:
        """Nominal model and the fixed parts of the draw at the probing points (N, 3) mm.

        ``stylus_mm`` (3,) or (N, 3) mm, None: the machine's probe offset. ValueError for
        points or styli that are not finite."""
        m = self.machine
        q = np.asarray(points_mm, dtype=float)
        if q.ndim == 1 and q.shape == (3,):
            q = q[None, :]
        if q.ndim != 2 or q.shape[1] != 3 or q.shape[0] == 0:
            raise ValueError(f"points must be an (N, 3) array of mm with N ≥ 1, got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError("points must be finite (NaN or infinite coordinates given)")
        n = q.shape[0]
        p = np.broadcast_to(m.stylus_or_probe(stylus_mm), (n, 3)).astype(float)
        if not np.all(np.isfinite(p)):
            raise ValueError("the stylus offset must be finite")
        ctx = m.context(q, self.temps_C, self.inputs)
        r0, t0 = exact_pose_compiled(self._axes, ctx.u_mm, ctx.errors, ctx.squareness_urad)
        calibration, source, target = self._calibration(q)
        random_sigma, random_target = self._random_parts(q)
        scale, workpiece = self._thermal(q, ctx.signals)
        return Prepared(
            q_mm=q,
            stylus_mm=p,
            errors=ctx.errors,
            squareness_urad=ctx.squareness_urad,
            u_mm=ctx.u_mm,
            rotation0=r0,
            translation0_um=t0,
            calibration=calibration,
            source=source,
            target=target,
            random_sigma=random_sigma,
            random_target=random_target,
            scale=scale,
            workpiece=workpiece,
        )

    def _calibration(self, q: FloatArray) -> tuple[FloatArray, NDArray[np.intp], NDArray[np.intp]]:
        """The calibration uncertainty of every table at the points ``q`` (N, 3) mm: the block
        diagonal factor (one block per table: tables are independent), and for each of its
        columns' values the source column and the target slot (point·18 + axis·6 + slot)."""
        m = self.machine
        n = q.shape[0]
        blocks: list[FloatArray] = []  # per table: (D_c, Q_c)
        source, target = [], []
        columns = 0
        for comp, tu in sorted(self.model.tables.items()):
            if tu.is_zero:
                continue
            c = parse_component(comp)
            k = AXIS_INDEX[c.axis]
            qk = np.clip(q[:, k], *tu.span_mm)
            uniq, inverse = np.unique(qk, return_inverse=True)
            table = m.tables.get(comp)
            value = table.evaluate(uniq) if table is not None else np.zeros_like(uniq)
            rows = []
            if tu.u > 0:
                basis = squared_exponential_basis(tu.span_mm[0], tu.span_mm[1], tu.correlation_mm)
                rows.append(tu.u * _sampling_factor(basis.features(uniq)).T)
            if tu.u_per_m > 0:
                rows.append(tu.u_per_m * ((uniq - tu.reference_mm) / 1000.0)[None, :])
            if tu.u_relative > 0:
                rows.append(tu.u_relative * np.asarray(value, dtype=float)[None, :])
            # one factor for the three parts: as few normal numbers as distinct positions
            blocks.append(_sampling_factor(np.vstack(rows).T).T)
            source.append(columns + inverse.reshape(-1))
            target.append(np.arange(n) * 18 + k * 6 + c.slot)
            columns += len(uniq)
        calibration = np.zeros((sum(b.shape[0] for b in blocks), columns))
        r0_ = c0_ = 0
        for b in blocks:  # block diagonal: tables are independent
            calibration[r0_ : r0_ + b.shape[0], c0_ : c0_ + b.shape[1]] = b
            r0_, c0_ = r0_ + b.shape[0], c0_ + b.shape[1]
        return (
            calibration,
            np.concatenate(source) if source else np.zeros(0, np.intp),
            np.concatenate(target) if target else np.zeros(0, np.intp),
        )

    def _random_parts(self, q: FloatArray) -> tuple[FloatArray, NDArray[np.intp]]:
        """σ of the tables' random parts at the points ``q`` (the non-zero ones) and their
        target slots (point·18 + axis·6 + slot)."""
        sig, sig_target = [], []
        for table in self.machine.tables.values():
            if not table.has_random:
                continue
            c = table.component
            k = AXIS_INDEX[c.axis]
            sigma = table.evaluate_random(q[:, k]) / 2.0  # 2σ band → σ
            nz = np.flatnonzero(sigma > 0)
            sig.append(sigma[nz])
            sig_target.append(nz * 18 + k * 6 + c.slot)
        return (
            np.concatenate(sig) if sig else np.zeros(0),
            np.concatenate(sig_target) if sig_target else np.zeros(0, np.intp),
        )

    def _thermal(
        self, q: FloatArray, signals: Mapping[str, Any]
    ) -> tuple[
        tuple[tuple[int, float, FloatArray, float, float], ...],
        tuple[float, FloatArray, FloatArray, float, float] | None,
    ]:
        """The scale terms (axis, α, ΔT, u_α, u_T) of the axes whose expansion is uncertain and
        the workpiece term (α, ΔT, lever mm, u_α, u_T) or None; ValueError for a temperature
        that is not finite."""
        m = self.machine
        ref_c = m.thermal.reference_C
        scale: list[tuple[int, float, FloatArray, float, float]] = []
        for k, axis in enumerate("xyz"):
            alpha = float(m.thermal.expansion[k])
            u_a, u_t = float(self.model.expansion[k]), float(self.model.scale_temperature_C[k])
            if (alpha == 0.0 or u_t == 0.0) and u_a == 0.0:
                continue
            d_t = signals[scale_role(axis)] - ref_c
            scale.append((k, alpha, np.asarray(d_t, float), u_a, u_t))
        workpiece = None
        alpha_wp = float(m.thermal.workpiece_expansion or 0.0)
        u_aw, u_tw = self.model.workpiece_expansion, self.model.workpiece_temperature_C
        if alpha_wp != 0.0 and (u_aw > 0 or u_tw > 0):
            fixture = (
                m.thermal.workpiece_fixture_mm
                if m.thermal.workpiece_fixture_mm is not None
                else m.volume.reference_mm
            )
            d_tw = np.asarray(signals[WORKPIECE] - ref_c, float)
            workpiece = (alpha_wp, d_tw, q - np.asarray(fixture, float), u_aw, u_tw)
        if not all(np.all(np.isfinite(s[2])) for s in scale) or (
            workpiece is not None and not np.all(np.isfinite(workpiece[1]))
        ):
            raise ValueError("temperatures must be finite")
        return tuple(scale), workpiece

    # ------------------------------------------------------------------ drawing
    def chunk_trials(self, prep: Prepared) -> int:
        """Trials evaluated together for these points (fixed by N: results do not depend on
        how the caller groups its runs)."""
        return max(1, ROWS_PER_CHUNK // prep.n)

    def residuals(
        self, prep: Prepared, n_trials: int, rng: np.random.Generator
    ) -> Iterator[FloatArray]:
        """Residuals ``true − corrected`` (µm), (trials, N, 3), in chunks of trials."""
        yield from self._draw(prep, n_trials, rng, pose=False)

    def pose_residuals(
        self, prep: Prepared, n_trials: int, rng: np.random.Generator
    ) -> Iterator[FloatArray]:
        """Residual error poses (trials, N, 6): translation at stylus 0 (µm) and rotation vector
        of ``R_true·R_modelᵀ`` (µrad), of the geometric part only (tables, squareness, random
        parts; no thermal, no probing: a grid adds those at run time)."""
        yield from self._draw(prep, n_trials, rng, pose=True)

    def _draw(
        self, prep: Prepared, n_trials: int, rng: np.random.Generator, *, pose: bool
    ) -> Iterator[FloatArray]:
        if n_trials < 1:
            raise ValueError(f"n_trials must be ≥ 1, got {n_trials}")
        chunk = self.chunk_trials(prep)
        done = 0
        while done < n_trials:
            t = min(chunk, n_trials - done)
            yield self._chunk(prep, t, rng, pose)
            done += t

    def _chunk(self, prep: Prepared, t: int, rng: np.random.Generator, pose: bool) -> FloatArray:
        n = prep.n
        delta_t = np.zeros((prep.calibration.shape[1], t))  # (S, t) at the distinct positions
        if prep.calibration.shape[0]:
            xi = rng.standard_normal((prep.calibration.shape[0], t))
            delta_t = prep.calibration_t @ xi
        z = np.zeros((t, 0))
        if prep.random_sigma.size:
            z = rng.standard_normal((t, prep.random_sigma.size))
        errors = assemble_errors(
            prep.errors.reshape(-1),
            t,
            delta_t,
            prep.source,
            prep.target,
            prep.random_sigma,
            z,
            prep.random_target,
        )
        sq = prep.squareness_urad[None, :, :] + (
            self.model.squareness_urad * rng.standard_normal((t, 1, 3))
        )
        u = np.broadcast_to(prep.u_mm, (t, n, 3)).reshape(-1, 3)
        sq_rows = np.broadcast_to(sq, (t, n, 3)).reshape(-1, 3)
        if not pose:
            res = residual_compiled(
                self._axes,
                u,
                errors.reshape(-1, 3, 6),
                sq_rows,
                prep.rotation0,
                prep.translation0_um,
                prep.stylus_mm,
            ).reshape(t, n, 3)
            return self._add_thermal_and_probing(prep, res, rng)
        rot, trans = exact_pose_compiled(self._axes, u, errors.reshape(-1, 3, 6), sq_rows)
        rot = rot.reshape(t, n, 3, 3)
        d_t = trans.reshape(t, n, 3) - prep.translation0_um[None]
        r0 = prep.rotation0

        def rel(i: int, k: int) -> FloatArray:  # (R_true · R_modelᵀ)[i, k], only those needed
            return np.einsum("tnj,nj->tn", rot[..., i, :], r0[:, k, :])

        w = np.empty((t, n, 3))
        w[..., 0] = 0.5 * (rel(2, 1) - rel(1, 2))
        w[..., 1] = 0.5 * (rel(0, 2) - rel(2, 0))
        w[..., 2] = 0.5 * (rel(1, 0) - rel(0, 1))
        return np.concatenate([d_t, 1e6 * w], axis=-1)

    def _add_thermal_and_probing(
        self, prep: Prepared, res: FloatArray, rng: np.random.Generator
    ) -> FloatArray:
        """Add the exact thermal residuals and the probing errors to ``res`` (t, N, 3) µm."""
        t, n = res.shape[0], res.shape[1]
        for k, alpha, d_temp, u_a, u_t in prep.scale:
            e_a = u_a * rng.standard_normal((t, 1))
            e_t = u_t * rng.standard_normal((t, 1))
            res[:, :, k] += (
                ((alpha + e_a) * (d_temp[None, :] + e_t) - alpha * d_temp[None, :])
                * prep.u_mm[None, :, k]
                / 1000.0
            )
        if prep.workpiece is not None:
            alpha, d_temp, lever, u_a, u_t = prep.workpiece
            e_a = u_a * rng.standard_normal((t, 1))
            e_t = u_t * rng.standard_normal((t, 1))
            factor = (alpha + e_a) * (d_temp[None, :] + e_t) - alpha * d_temp[None, :]
            res -= factor[:, :, None] * lever[None, :, :] / 1000.0
        if self.model.probe_um > 0:
            res += self.model.probe_um * rng.standard_normal((t, n, 3))
        return res


def _sampling_factor(features: FloatArray) -> FloatArray:
    """A factor G with G·Gᵀ = F·Fᵀ and as few columns as possible: F (Q, M) itself when the
    process has fewer modes than distinct positions, else the eigen-factor of F·Fᵀ (Q, ≤ Q),
    so a draw at a few positions costs a few normal numbers, not one per mode."""
    q, m = features.shape
    if m <= q:
        return features
    w, v = np.linalg.eigh(features @ features.T)
    keep = w > 1e-12 * max(float(w.max()), 1e-300)
    return v[:, keep] * np.sqrt(w[keep])
