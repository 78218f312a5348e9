"""Task-specific uncertainty (ISO/TS 15530-4): what the virtual CMM makes of a measurement.

Every task takes the *true* probing points of a perfect artefact (mm; the indicated positions to
µm) and the measurement conditions, draws virtual machines (:class:`.VirtualCMM`) and evaluates
the measurand as the CMM would report it after correction: measured point = true point −
residual. Outputs are errors **true − measured** (the project's sign), µm, or, for flatness, the
flatness the CMM reports for a perfectly flat plane. The number of trials follows JCGM 101 §7.9
(:func:`.adaptive.run_monte_carlo`).

* :func:`point_uncertainty` — U of the corrected position at any points and stylus;
* :func:`length_uncertainty` — a length between two points (gauge block, step gauge);
* :func:`e0_uncertainty` — the ISO 10360-2 E0 test: distribution of E0 = max |length error| over
  all test lengths, and the probability of passing an MPE ``A + L/K``;
* :func:`sphere_uncertainty` — the centre (and radius) of a sphere fitted to N probing points;
* :func:`flatness_uncertainty` — the least-squares flatness of a plane from N points.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .adaptive import McResult, MonteCarloSettings, run_monte_carlo
from .gum import gum_check, residual_covariance, residual_std, signals_at
from .model import UncertaintyModel
from .virtual_cmm import Prepared, VirtualCMM

if TYPE_CHECKING:
    from ..machine import Machine

__all__ = [
    "E0_NDIG",
    "P_PASS_TOLERANCE",
    "PointUncertainty",
    "TaskUncertainty",
    "e0_uncertainty",
    "flatness_uncertainty",
    "length_uncertainty",
    "plane_grid_points",
    "point_uncertainty",
    "sphere_probing_points",
    "sphere_uncertainty",
]

FloatArray = NDArray[np.float64]
ProgressFn = Callable[[int, float], None]
STATUS_DTYPE = "<U22"
#: default significant digits of u(E0): the 97.5 % point of a maximum over 105 lengths needs
#: ~640,000 trials for 2 digits on the NPL-like bridge (≈ 200 s on 2 cores), 1 digit ~20,000
E0_NDIG = 1
#: the pass probability is also stable when twice its run-to-run standard deviation is ≤ this
P_PASS_TOLERANCE = 0.005


@dataclass(frozen=True)
class PointUncertainty:
    """Uncertainty of corrected positions, arrays (N, 3) µm (NaN where ``status`` is not ok).

    ``mean_um`` the residual's mean (≈ 0: the correction is unbiased under the model), ``u_um``
    standard uncertainty, ``U_um`` = 2·u (k = 2), ``low_um``/``high_um`` the probabilistically
    symmetric coverage interval of the residual (true − corrected), ``U95_um`` the half-width
    of the zero-centred interval with the coverage probability. ``status``: ``ok``,
    ``invalid_input`` (not finite) or ``outside_volume``."""

    points_mm: FloatArray
    stylus_mm: FloatArray
    status: NDArray[np.str_]
    mean_um: FloatArray
    u_um: FloatArray
    U_um: FloatArray
    low_um: FloatArray
    high_um: FloatArray
    U95_um: FloatArray
    mc: McResult | None
    model: dict[str, Any] = field(default_factory=dict)
    gum_u_um: FloatArray | None = None
    """First-order (GUM) standard uncertainty (N, 3) µm of the same model, for comparison."""


@dataclass(frozen=True)
class TaskUncertainty:
    """Monte Carlo result of a measurement task: ``outputs`` names (unit µm unless the name
    says otherwise), statistics in ``mc``, the nominal measurand and extras in ``nominal``."""

    task: str
    outputs: tuple[str, ...]
    mc: McResult
    nominal: dict[str, Any]
    model: dict[str, Any] = field(default_factory=dict)
    gum: dict[str, Any] | None = None
    """First-order (GUM) u of the outputs and the JCGM 101 §8 comparison (:func:`.gum.gum_check`);
    None where the measurand is not linear in the residuals (a maximum, a range)."""

    def summary(self) -> dict[str, Any]:
        """JSON-able: per output y, u, U (k = 2), the coverage interval, U95; trials, stability."""
        mc = self.mc
        ratio = mc.ratio if mc.ratio is not None else np.full((4, len(self.outputs)), np.nan)
        stability = np.max(ratio, axis=0)  # worst of y, u, y_low, y_high per output
        return {
            "task": self.task,
            "nominal": self.nominal,
            "outputs": {
                name: {
                    "mean": float(mc.mean[i]),
                    "u": float(mc.u[i]),
                    "U_k2": float(2.0 * mc.u[i]),
                    "interval": [float(mc.low[i]), float(mc.high[i])],
                    "U95_zero_centred": float(mc.U95[i]),
                    "tolerance": float(mc.tolerance[i]) if np.isfinite(mc.tolerance[i]) else None,
                    "stability_2s_over_tolerance": _finite_or_none(stability[i]),
                }
                for i, name in enumerate(self.outputs)
            },
            "monte_carlo": {
                **_mc_info(mc),
                "stopping_rule_outputs": [self.outputs[i] for i in mc.stop_on],
            },
            "gum_first_order": self.gum
            if self.gum is not None
            else "not applicable: the measurand is not linear in the residuals",
            "uncertainty_model": self.model,
        }


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _mc_info(mc: McResult) -> dict[str, Any]:
    return {
        **mc.info(),
        "method": "JCGM 101 Monte Carlo, adaptive per §7.9; virtual CMM after ISO/TS 15530-4",
    }


def _points(points_mm: ArrayLike, what: str) -> FloatArray:
    q = np.asarray(points_mm, dtype=float)
    if q.ndim == 1 and q.shape == (3,):
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != 3 or q.shape[0] == 0:
        raise ValueError(f"{what} must be an (N, 3) array of mm with N ≥ 1, got shape {q.shape}")
    return q


def _check_inside(machine: Machine, q: FloatArray, what: str) -> None:
    bad = ~np.all(np.isfinite(q), axis=1)
    if bad.any():
        raise ValueError(f"{what}: point {int(np.argmax(bad))} is not finite")
    inside = machine.volume.contains(q)
    if not inside.all():
        i = int(np.argmax(~inside))
        raise ValueError(
            f"{what}: point {i} {q[i].tolist()} mm is outside the working volume "
            f"{machine.volume.lower_mm.tolist()}…{machine.volume.upper_mm.tolist()}"
        )


def _residual_runner(
    vcmm: VirtualCMM, prep: Prepared
) -> Callable[[int, np.random.Generator], FloatArray]:
    def draw(m: int, rng: np.random.Generator) -> FloatArray:
        return np.concatenate(list(vcmm.residuals(prep, m, rng)))  # (m, N, 3)

    return draw


def _virtual_task(
    machine: Machine,
    model: UncertaintyModel | None,
    temps_C: Mapping[str, Any] | None,
    inputs: Mapping[str, Any] | None,
    pts: FloatArray,
    stylus_mm: ArrayLike | None,
) -> tuple[VirtualCMM, Prepared, Callable[[int, np.random.Generator], FloatArray]]:
    """A task's virtual CMM, its probing points (mm) prepared, and the draw of M trials'
    residuals (M, N, 3) µm at them."""
    vcmm = VirtualCMM(machine, model, temps_C, inputs)
    prep = vcmm.prepare(pts, stylus_mm)
    return vcmm, prep, _residual_runner(vcmm, prep)


def _gum(
    vcmm: VirtualCMM, pts: FloatArray, stylus: FloatArray, sens: FloatArray, mc: McResult
) -> dict[str, Any]:
    """GUM u of outputs linear in the residuals, ``output_o = Σ sens[o, i, j]·r_ij`` (µm), and
    the JCGM 101 §8 comparison with the Monte Carlo interval."""
    cov = residual_covariance(
        vcmm.machine, pts, stylus, vcmm.temps_C, vcmm.inputs, model=vcmm.model
    )
    u = np.sqrt(np.maximum(np.einsum("oai,aibj,obj->o", sens, cov, sens), 0.0))
    return gum_check(u, mc.low, mc.high, mc.tolerance, 0.0, mc.probability)


# ---------------------------------------------------------------------------- points


def point_uncertainty(
    machine: Machine,
    points_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    rng: np.random.Generator,
    settings: MonteCarloSettings | None = None,
    model: UncertaintyModel | None = None,
    progress: ProgressFn | None = None,
) -> PointUncertainty:
    """U of the corrected position at indicated ``points_mm`` (N, 3) for ``stylus_mm`` ((3,) or
    (N, 3) mm; None: the machine's probe offset) under ``temps_C``/``inputs`` (the sensors'
    readings). Points not finite (``invalid_input``), outside the volume (``outside_volume``) or
    with a temperature / another signal given as NaN (``no_temperature`` / ``missing_input``) get
    that status and NaN; the others one joint Monte Carlo (each point one probing). A signal not
    given at all is the reference, as in the model."""
    q = _points(points_mm, "points")
    n = q.shape[0]
    p = np.broadcast_to(machine.stylus_or_probe(stylus_mm), (n, 3)).astype(float)
    finite = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(p), axis=1)
    inside = np.zeros(n, dtype=bool)
    inside[finite] = machine.volume.contains(q[finite])
    status = np.where(~finite, "invalid_input", np.where(inside, "ok", "outside_volume")).astype(
        STATUS_DTYPE
    )
    for mapping, flag in ((temps_C, "no_temperature"), (inputs, "missing_input")):
        for value in (mapping or {}).values():
            arr = np.broadcast_to(np.asarray(np.nan if value is None else value, float), (n,))
            bad = ~np.isfinite(arr) & (status == "ok")
            status[bad] = flag
    inside = status == "ok"
    nan3 = np.full((n, 3), np.nan)
    out = {k: nan3.copy() for k in ("mean", "u", "low", "high", "U95")}
    vcmm = VirtualCMM(machine, model, signals_at(temps_C, inside, n), signals_at(inputs, inside, n))
    mc = None
    if inside.any():
        prep = vcmm.prepare(q[inside], p[inside])
        base = settings or MonteCarloSettings()
        runner = _residual_runner(vcmm, prep)
        mc = run_monte_carlo(
            lambda m, g: runner(m, g).reshape(m, -1),
            rng,
            base.with_batch_for(prep.n),
            progress,
        )
        for key in out:
            out[key][inside] = getattr(mc, key).reshape(-1, 3)
        gum_u = nan3.copy()
        gum_u[inside] = residual_std(
            machine, q[inside], p[inside], vcmm.temps_C, vcmm.inputs, model=vcmm.model
        )
    else:
        gum_u = nan3.copy()
    return PointUncertainty(
        points_mm=q,
        stylus_mm=p,
        status=status,
        mean_um=out["mean"],
        u_um=out["u"],
        U_um=2.0 * out["u"],
        low_um=out["low"],
        high_um=out["high"],
        U95_um=out["U95"],
        mc=mc,
        model=vcmm.model.describe(),
        gum_u_um=gum_u,
    )


# ---------------------------------------------------------------------------- lengths


def _length_errors_um(true_mm: FloatArray, res: FloatArray) -> FloatArray:
    """(M, P) length errors true − measured, µm, of P lengths whose end points are rows 2i, 2i+1
    of ``true_mm`` (2P, 3); ``res`` (M, 2P, 3) residuals µm (measured = true − residual)."""
    a, b = true_mm[0::2], true_mm[1::2]
    true_len = np.linalg.norm(b - a, axis=1)
    measured = (b - a)[None] - (res[:, 1::2] - res[:, 0::2]) / 1000.0
    return (true_len[None, :] - np.linalg.norm(measured, axis=2)) * 1000.0


def length_uncertainty(
    machine: Machine,
    a_mm: ArrayLike,
    b_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    rng: np.random.Generator,
    settings: MonteCarloSettings | None = None,
    model: UncertaintyModel | None = None,
    progress: ProgressFn | None = None,
) -> TaskUncertainty:
    """Uncertainty of the length between two probed points ``a_mm`` and ``b_mm`` (each probed
    once): output ``length_error_um`` = true − measured length."""
    pts = np.vstack([_points(a_mm, "a"), _points(b_mm, "b")])
    if pts.shape != (2, 3):
        raise ValueError("a and b must be one point each (3 coordinates, mm)")
    _check_inside(machine, pts, "length")
    length = float(np.linalg.norm(pts[1] - pts[0]))
    if length <= 0:
        raise ValueError("a and b are the same point: no length to measure")
    vcmm, prep, runner = _virtual_task(machine, model, temps_C, inputs, pts, stylus_mm)
    mc = run_monte_carlo(lambda m, g: _length_errors_um(pts, runner(m, g)), rng, settings, progress)
    direction = (pts[1] - pts[0]) / length
    sens = np.stack([-direction, direction])[None]  # (1 output, 2 points, 3)
    return TaskUncertainty(
        task="length",
        outputs=("length_error_um",),
        mc=mc,
        nominal={"a_mm": pts[0].tolist(), "b_mm": pts[1].tolist(), "length_mm": length},
        model=vcmm.model.describe(),
        gum=_gum(vcmm, pts, prep.stylus_mm, sens, mc),
    )


def e0_uncertainty(
    machine: Machine,
    pairs_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    mpe: tuple[float, float] | None = None,
    rng: np.random.Generator,
    settings: MonteCarloSettings | None = None,
    model: UncertaintyModel | None = None,
    progress: ProgressFn | None = None,
) -> TaskUncertainty:
    """The ISO 10360-2 E0 test on virtual machines: ``pairs_mm`` (P, 2, 3) the end points of
    every measured length (each probed once: repetitions are separate pairs). Outputs
    ``E0_um`` = max over the P lengths of |length error| and, with ``mpe = (A_um, K)``
    (E0,MPE = A + L/K µm, L in mm), ``E0_over_MPE`` = max |error| / MPE(L); then the trial
    fraction with ratio ≤ 1 is the probability of passing (``nominal["p_pass"]``, with
    ``p_pass_2s`` its numerical uncertainty); then the P length errors ``length_error_um[i]``.

    The adaptive stopping rule watches E0 (and E0/MPE) to ``settings.ndig`` significant digits
    (default :data:`E0_NDIG`) and the pass probability to ±:data:`P_PASS_TOLERANCE`; the
    per-length outputs are reported with the precision that gave (their 2s/δ in the summary).
    Their values are not kept beyond ``keep_values_limit``: E0 and E0/MPE always are."""
    pairs = np.asarray(pairs_mm, dtype=float)
    if pairs.ndim != 3 or pairs.shape[1:] != (2, 3) or pairs.shape[0] == 0:
        raise ValueError(f"pairs must be a (P, 2, 3) array of mm, got shape {pairs.shape}")
    pts = pairs.reshape(-1, 3)
    _check_inside(machine, pts, "E0 test")
    lengths = np.linalg.norm(pairs[:, 1] - pairs[:, 0], axis=1)
    if np.any(lengths <= 0):
        raise ValueError("E0 test: a length has its two end points at the same place")
    mpe_um = None
    if mpe is not None:
        a_um, k = (float(v) for v in mpe)
        if not (np.isfinite(a_um) and np.isfinite(k) and a_um >= 0 and k > 0):
            raise ValueError(f"MPE A + L/K needs A ≥ 0 µm and K > 0, got A={a_um}, K={k}")
        mpe_um = a_um + lengths / k
    vcmm, prep, runner = _virtual_task(machine, model, temps_C, inputs, pts, stylus_mm)
    passes: list[tuple[int, int]] = []  # (passed, trials) per run

    def draw(m: int, g: np.random.Generator) -> FloatArray:
        err = _length_errors_um(pts, runner(m, g))
        cols = [np.abs(err).max(axis=1, keepdims=True)]
        if mpe_um is not None:
            cols.append((np.abs(err) / mpe_um[None, :]).max(axis=1, keepdims=True))
            passes.append((int(np.count_nonzero(cols[-1] <= 1.0)), m))
        return np.concatenate([*cols, err], axis=1)

    base = settings or MonteCarloSettings(ndig=E0_NDIG)
    main = (0,) if mpe_um is None else (0, 1)  # the stopping rule watches E0 (and E0/MPE)

    def pass_ratio() -> float:  # 2s/δ of the pass probability, δ = P_PASS_TOLERANCE
        two_s = _pass_probability(passes)["p_pass_2s"] if mpe_um is not None else None
        return 0.0 if two_s is None else two_s / P_PASS_TOLERANCE

    mc = run_monte_carlo(
        draw, rng, base.with_batch_for(prep.n), progress, stop_on=main, extra_ratio=pass_ratio
    )
    names = ["E0_um", *(["E0_over_MPE"] if mpe_um is not None else [])]
    names += [f"length_error_um[{i}]" for i in range(len(lengths))]
    nominal: dict[str, Any] = {
        "lengths_mm": np.round(lengths, 6).tolist(),
        "n_lengths": len(lengths),
    }
    if mpe_um is not None:
        nominal["mpe"] = {"A_um": float(mpe[0]), "K": float(mpe[1])}  # type: ignore[index]
        nominal.update(_pass_probability(passes))
    return TaskUncertainty(
        task="e0",
        outputs=tuple(names),
        mc=mc,
        nominal=nominal,
        model=vcmm.model.describe(),
    )


def _pass_probability(passes: list[tuple[int, int]]) -> dict[str, Any]:
    """The share of trials that passed (``p_pass``) and twice the standard deviation of its run
    average (``p_pass_2s``, the Monte Carlo's own numerical uncertainty as in JCGM 101 §7.9.4;
    None after a single run)."""
    passed, trials = (np.array(c, dtype=float) for c in zip(*passes, strict=True))
    out: dict[str, Any] = {"p_pass": float(passed.sum() / trials.sum()), "p_pass_2s": None}
    if len(passes) >= 2:
        share = passed / trials
        out["p_pass_2s"] = float(2.0 * share.std(ddof=1) / np.sqrt(len(passes)))
    return out


# ---------------------------------------------------------------------------- sphere


def sphere_probing_points(centre_mm: ArrayLike, radius_mm: float, n: int = 25) -> FloatArray:
    """Probing points on the upper hemisphere: for n = 25 the ISO 10360-5 pattern (the pole;
    4 points 22.5° below it; 8 at 45°; 4 at 67.5°; 8 on the equator, each ring turned), for
    other n (≥ 4) a Fibonacci spiral over the hemisphere. (n, 3) mm."""
    c = np.asarray(centre_mm, dtype=float).reshape(3)
    if not (np.isfinite(radius_mm) and radius_mm > 0):
        raise ValueError(f"sphere radius must be finite and > 0 mm, got {radius_mm}")
    if n < 4:
        raise ValueError(f"a sphere needs at least 4 probing points, got {n}")
    if n == 25:
        rings = [(0.0, 1, 0.0), (22.5, 4, 0.0), (45.0, 8, 22.5), (67.5, 4, 45.0), (90.0, 8, 0.0)]
        dirs = []
        for polar, count, turn in rings:
            for j in range(count):
                az = np.radians(turn + 360.0 * j / count)
                t = np.radians(polar)
                dirs.append([np.sin(t) * np.cos(az), np.sin(t) * np.sin(az), np.cos(t)])
        d = np.array(dirs)
    else:
        i = np.arange(n) + 0.5
        z = 1.0 - i / n  # uniform in z over the hemisphere
        az = np.pi * (1.0 + 5.0**0.5) * i
        r = np.sqrt(1.0 - z * z)
        d = np.c_[r * np.cos(az), r * np.sin(az), z]
    return c + radius_mm * d


def _fit_sphere(
    points: FloatArray, start: tuple[FloatArray, FloatArray], iters: int
) -> tuple[FloatArray, FloatArray]:
    """Least-squares sphere (geometric distances) of (T, N, 3) points by Gauss–Newton from
    ``start`` = (centres (T, 3), radii (T,)): (centres, radii), mm."""
    centre, radius = start[0].copy(), start[1].copy()
    for _ in range(iters):
        d = points - centre[:, None, :]
        dist = np.linalg.norm(d, axis=2)
        f = dist - radius[:, None]
        jac = np.concatenate([-d / dist[..., None], -np.ones((*dist.shape, 1))], axis=2)
        jtj = np.einsum("tni,tnj->tij", jac, jac)
        jtf = np.einsum("tni,tn->ti", jac, f)
        step = np.linalg.solve(jtj, -jtf[..., None])[..., 0]
        centre += step[:, :3]
        radius += step[:, 3]
    return centre, radius


def _reference_sphere(points: FloatArray) -> tuple[FloatArray, float]:
    """Least-squares sphere through points (N, 3): algebraic start, then Gauss–Newton."""
    a = np.c_[2.0 * points, np.ones(len(points))]
    sol, *_ = np.linalg.lstsq(a, np.sum(points**2, axis=1), rcond=None)
    centre = sol[:3]
    radius = float(np.sqrt(max(sol[3] + centre @ centre, 0.0)))
    c, r = _fit_sphere(points[None], (centre[None], np.array([radius])), 8)
    return c[0], float(r[0])


def sphere_uncertainty(
    machine: Machine,
    points_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    rng: np.random.Generator,
    settings: MonteCarloSettings | None = None,
    model: UncertaintyModel | None = None,
    progress: ProgressFn | None = None,
) -> TaskUncertainty:
    """Uncertainty of a sphere's centre (and radius) from N ≥ 4 probing points on a perfect
    sphere (:func:`sphere_probing_points`): least-squares (geometric) fit of the measured points,
    outputs ``centre_x_um``, ``centre_y_um``, ``centre_z_um``, ``radius_um`` = true − measured."""
    pts = _points(points_mm, "sphere points")
    if pts.shape[0] < 4:
        raise ValueError(f"a sphere needs at least 4 probing points, got {pts.shape[0]}")
    _check_inside(machine, pts, "sphere")
    centre, radius = _reference_sphere(pts)
    if not (np.all(np.isfinite(centre)) and np.isfinite(radius) and radius > 0):
        raise ValueError("the sphere points do not define a sphere (all on a plane or a line?)")
    vcmm, prep, runner = _virtual_task(machine, model, temps_C, inputs, pts, stylus_mm)

    def draw(m: int, g: np.random.Generator) -> FloatArray:
        measured = pts[None] - runner(m, g) / 1000.0
        c, r = _fit_sphere(measured, (np.tile(centre, (m, 1)), np.full(m, radius)), 3)
        return np.c_[(centre[None] - c) * 1000.0, (radius - r) * 1000.0]

    mc = run_monte_carlo(draw, rng, settings, progress)
    normals = (pts - centre) / radius
    proj = np.linalg.pinv(np.c_[normals, np.ones(len(pts))])  # outputs = proj · (n_i · r_i)
    sens = proj[:, :, None] * normals[None, :, :]  # (4 outputs, N, 3)
    return TaskUncertainty(
        task="sphere",
        outputs=("centre_x_um", "centre_y_um", "centre_z_um", "radius_um"),
        mc=mc,
        nominal={"centre_mm": centre.tolist(), "radius_mm": radius, "n_points": len(pts)},
        model=vcmm.model.describe(),
        gum=_gum(vcmm, pts, prep.stylus_mm, sens, mc),
    )


# ---------------------------------------------------------------------------- plane


def plane_grid_points(
    origin_mm: ArrayLike, u_mm: ArrayLike, v_mm: ArrayLike, nu: int = 5, nv: int = 5
) -> FloatArray:
    """``nu × nv`` points ``origin + i/(nu−1)·u + j/(nv−1)·v`` on a rectangle (mm), (nu·nv, 3)."""
    if nu < 2 or nv < 2:
        raise ValueError(f"a plane grid needs at least 2 × 2 points, got {nu} × {nv}")
    o, u, v = (np.asarray(a, dtype=float).reshape(3) for a in (origin_mm, u_mm, v_mm))
    s, t = np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 1, nv), indexing="ij")
    return o + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v


def _ls_flatness_um(points: FloatArray) -> FloatArray:
    """Least-squares flatness (max − min deviation from the LS plane), µm, of (T, N, 3) mm."""
    centred = points - points.mean(axis=1, keepdims=True)
    cov = np.einsum("tni,tnj->tij", centred, centred)
    _, vec = np.linalg.eigh(cov)
    normal = vec[:, :, 0]  # eigenvector of the smallest eigenvalue
    dev = np.einsum("tni,ti->tn", centred, normal)
    return (dev.max(axis=1) - dev.min(axis=1)) * 1000.0


def flatness_uncertainty(
    machine: Machine,
    points_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    rng: np.random.Generator,
    settings: MonteCarloSettings | None = None,
    model: UncertaintyModel | None = None,
    progress: ProgressFn | None = None,
) -> TaskUncertainty:
    """The least-squares flatness the CMM reports for a perfectly flat plane probed at
    ``points_mm`` (N ≥ 4, coplanar): output ``flatness_um`` (≥ 0; its mean is the bias a real
    flatness measurement carries, its spread the uncertainty)."""
    pts = _points(points_mm, "plane points")
    if pts.shape[0] < 4:
        raise ValueError(f"a flatness needs at least 4 points, got {pts.shape[0]}")
    _check_inside(machine, pts, "plane")
    centred = pts - pts.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-12):
        raise ValueError("the plane points lie on a line: they do not define a plane")
    form_um = float(_ls_flatness_um(pts[None])[0])
    if form_um > 1e-3:
        raise ValueError(
            f"the plane points are not coplanar (flatness {form_um:.3g} µm): give points of a "
            "perfect plane (the artefact's form is not part of this method)"
        )
    vcmm, _, runner = _virtual_task(machine, model, temps_C, inputs, pts, stylus_mm)

    def draw(m: int, g: np.random.Generator) -> FloatArray:
        return _ls_flatness_um(pts[None] - runner(m, g) / 1000.0)[:, None]

    mc = run_monte_carlo(draw, rng, settings, progress)
    return TaskUncertainty(
        task="flatness",
        outputs=("flatness_um",),
        mc=mc,
        nominal={"n_points": len(pts), "criterion": "least_squares"},
        model=vcmm.model.describe(),
    )
