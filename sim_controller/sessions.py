"""Simulated verification sessions: where, when and how a CMM is measured, and the readings.

A session (:func:`plan_session`) is a few hours of measuring artefact lines (one ``group`` each:
axis-parallel lines, face and space diagonals at random places in the working volume), each line
traversed forward then backward (so every axis is approached from both directions), with one of
several styli per line, probing directions varied point by point (mostly horizontal at every
azimuth, some vertical), and temperatures that drift smoothly and independently enough that
thermal causes can be told apart: each sensor is a shared drift plus its own slow component, all
crossing the reference temperature, with ``T_top − T_bottom`` a separate slow signal.

:func:`measure_session` adds what a true machine does plus reference/probing noise, giving a
:class:`compensation.formats.measurements.Measurements` (docs/formats.md §2).
Units: mm, µm, °C, s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmm_comp.compensation.formats.measurements import Measurements
from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.thermal import AIR, BOTTOM, SCALE_ROLES, TOP, WORKPIECE

__all__ = ["SessionPlan", "measure_session", "plan_session"]

#: Line directions of the artefact (unnormalised): axes, face diagonals, space diagonals.
_LINE_DIRECTIONS = np.array(
    [
        [1, 0, 0],
        [0, 1, 0],
        [0, 0, 1],
        [1, 1, 0],
        [1, -1, 0],
        [1, 0, 1],
        [0, 1, 1],
        [1, 1, 1],
        [1, -1, 1],
        [-1, 1, 1],
        [1, 1, -1],
    ],
    dtype=float,
)


@dataclass
class SessionPlan:
    """Everything about a session except the readings: a Measurements with reference = indicated."""

    data: Measurements
    reference_C: float


def _smooth_signal(
    rng: np.random.Generator, t_s: np.ndarray, amplitude_C: float, periods_s: tuple[float, float]
) -> np.ndarray:
    """Sum of three slow sinusoids with random periods in ``periods_s`` and random phases."""
    out = np.zeros_like(t_s)
    for _ in range(3):
        period = rng.uniform(*periods_s)
        out += rng.uniform(0.3, 1.0) * np.sin(2 * np.pi * t_s / period + rng.uniform(0, 2 * np.pi))
    return amplitude_C * out / 1.5


def _temperatures(
    rng: np.random.Generator, t_s: np.ndarray, reference_C: float
) -> dict[str, np.ndarray]:
    shared = _smooth_signal(rng, t_s, 0.8, (5400.0, 20000.0))
    temps: dict[str, np.ndarray] = {}
    for name in (*SCALE_ROLES, AIR, WORKPIECE):
        own = _smooth_signal(rng, t_s, 0.7, (2400.0, 14000.0))
        temps[name] = reference_C + rng.uniform(-0.3, 0.3) + shared + own
    gradient = _smooth_signal(rng, t_s, 0.6, (3600.0, 14000.0)) + rng.uniform(-0.2, 0.2)
    middle = reference_C + shared + _smooth_signal(rng, t_s, 0.3, (3600.0, 14000.0))
    temps[TOP] = middle + gradient / 2
    temps[BOTTOM] = middle - gradient / 2
    return temps


def _line(
    rng: np.random.Generator, lower: np.ndarray, upper: np.ndarray, stations: int
) -> np.ndarray:
    """Station positions (stations, 3) of one artefact line inside the volume (5 % margin)."""
    span = upper - lower
    lo, hi = lower + 0.05 * span, upper - 0.05 * span
    d = _LINE_DIRECTIONS[rng.integers(len(_LINE_DIRECTIONS))].copy()
    d *= rng.choice([-1.0, 1.0])
    # longest segment along d through a random point, clipped to the box
    p0 = rng.uniform(lo, hi)
    with np.errstate(divide="ignore"):
        t_hi = np.min(np.where(d > 0, (hi - p0) / d, np.where(d < 0, (lo - p0) / d, np.inf)))
        t_lo = np.max(np.where(d > 0, (lo - p0) / d, np.where(d < 0, (hi - p0) / d, -np.inf)))
    s = np.linspace(t_lo, t_hi, stations)
    pts = p0 + s[:, None] * d
    pts += (
        rng.normal(0.0, 0.002, pts.shape) * span
    )  # the artefact's balls are not exactly on a line
    return np.clip(pts, lower, upper)


def _normals(rng: np.random.Generator, n: int) -> np.ndarray:
    """Probing directions: 75 % horizontal at random azimuth, 25 % random on the sphere."""
    out = np.zeros((n, 3))
    horizontal = rng.random(n) < 0.75
    phi = rng.uniform(0, 2 * np.pi, n)
    out[:, 0], out[:, 1] = np.cos(phi), np.sin(phi)
    sphere = rng.normal(size=(n, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    out[~horizontal] = sphere[~horizontal]
    return out


def plan_session(
    machine: Machine,
    rng: np.random.Generator,
    *,
    n_points: int = 700,
    hours: float = 4.0,
    points_per_line: int = 36,
) -> SessionPlan:
    """Plan a session on ``machine``'s volume: lines of ``points_per_line`` points (forward then
    backward over half as many stations), ``n_points`` in all over ``hours`` hours."""
    lower, upper = machine.volume.lower_mm, machine.volume.upper_mm
    stations = points_per_line // 2
    n_lines = max(2, round(n_points / (2 * stations)))
    base = np.asarray(machine.probe.offset_mm, dtype=float)
    styli = [
        base + np.array(o) for o in ((0, 0, 0), (40, 0, 0), (-40, 0, 0), (0, 40, 0), (0, -40, 0))
    ]
    pts, stylus, dirs, group = [], [], [], []
    for g in range(n_lines):
        line = _line(rng, lower, upper, stations)
        path = np.vstack([line, line[::-1]])
        step = np.diff(np.vstack([path[:1] - (path[1] - path[0]), path]), axis=0)
        d = np.sign(step)
        d[d == 0] = rng.choice([-1.0, 1.0], size=int(np.sum(d == 0)))
        pts.append(path)
        dirs.append(d)
        stylus.append(np.broadcast_to(styli[rng.integers(len(styli))], path.shape))
        group.extend([f"line{g:02d}"] * len(path))
    q = np.vstack(pts)
    n = len(q)
    t_s = np.sort(rng.uniform(0.0, hours * 3600.0, n))
    t_s = np.linspace(0.0, hours * 3600.0, n) * 0.5 + t_s * 0.5  # even pace, with jitter
    t_s = np.maximum.accumulate(t_s)
    ref_c = machine.thermal.reference_C
    dir_arr = np.vstack(dirs)
    data = Measurements(
        indicated_mm=q,
        reference_mm=q.copy(),
        t_s=t_s,
        temps_C=_temperatures(rng, t_s, ref_c),
        directions={f"dir_{a}": dir_arr[:, k] for k, a in enumerate("xyz")},
        normals=_normals(rng, n),
        stylus_mm=np.vstack(stylus).astype(float),
        group=np.asarray(group, dtype=str),
        source="<simulated session>",
    )
    return SessionPlan(data=data, reference_C=ref_c)


def true_error_um(machine: Machine, data: Measurements) -> np.ndarray:
    """(N, 3) µm: what ``machine`` (the truth) makes the indicated positions wrong by."""
    return machine.volumetric_error(
        data.indicated_mm,
        data.stylus(machine.probe.offset_mm.tolist()),
        data.temps_C,
        inputs=data.inputs(),
    )


def measure_session(
    machine: Machine, plan: SessionPlan, noise_um: float, rng: np.random.Generator
) -> Measurements:
    """Readings of ``plan`` on the true ``machine``: reference = indicated + error + noise
    (Gaussian, ``noise_um`` per axis: reference instrument and probing repeatability)."""
    d = plan.data
    err = true_error_um(machine, d) + rng.normal(0.0, noise_um, (d.n, 3))
    out = d.subset(slice(None))
    out.reference_mm = d.indicated_mm + err / 1000.0
    return out
