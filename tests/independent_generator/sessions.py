"""Session designs: where, when, with which stylus and in which direction points are measured.

Two layouts (:class:`Design`):

* ``random`` - points spread uniformly over the volume, visited in random order (a laser-tracker
  style survey); groups are time blocks of ~10 % of the points; each point has a random probing
  direction (mostly horizontal, some straight down).
* ``iso_lines`` - ISO 10360-2 length lines: 4 space diagonals + 3 axis-parallel lines (more
  random lines when more points are asked for), 5 lengths each, 3 repeats, alternately forward
  and backward along the line, both gauge faces probed along the line; plus an ISO 10360-5
  probing sphere (25 points) so the probing direction varies in azimuth. Groups are lines.

Each with one stylus (straight down) or five (down, ±x, ±y), 1 h or 8 h, 200…2000 points, noise
0.25–1 µm per axis. Directions ``dir_*`` are the sign of the last move of each axis along the
path. Temperatures come from :mod:`.temperatures`.

What a design cannot identify (the benchmark keeps these cases anyway, but see
:func:`periodic_min_period_mm`): a periodic error shorter than ~2.5× the gap between the
positions an axis is sampled at; with a single stylus straight down, a rotation of the last tool
carriage about z has no arm at all, and its other rotations act exactly like straightness of that
axis (the diagnosis may name either; the benchmark accepts a listed alternative).

Units: mm, s, °C, µm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .machines import MachineSpec
from .temperatures import TemperatureField, draw_temperatures

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Design:
    """How a session is measured."""

    layout: str  # "random" | "iso_lines"
    n_points: int
    styli: int  # 1 or 5
    duration_s: float
    noise_um: float  # per axis, 1σ

    @property
    def label(self) -> str:
        return f"{self.layout}/{self.n_points}p/{self.styli}st/{self.duration_s / 3600:.0f}h/{self.noise_um:.2f}um"


@dataclass
class Session:
    """Indicated points and every runtime signal of one session (before errors are added)."""

    design: Design
    q_mm: FloatArray  # (N, 3) indicated
    stylus_mm: FloatArray  # (N, 3)
    t_s: FloatArray  # (N,)
    temps_C: dict[str, FloatArray]  # logged temperatures at the points
    directions: dict[str, FloatArray]  # dir_x … ±1
    normals: FloatArray  # (N, 3) probing directions
    group: NDArray[np.str_]
    field: TemperatureField
    notes: dict[str, object] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.q_mm.shape[0])

    @property
    def noise_rms_3d_um(self) -> float:
        return float(np.sqrt(3.0) * self.design.noise_um)


def draw_design(rng: np.random.Generator) -> Design:
    """A random session design."""
    layout = "random" if rng.random() < 0.55 else "iso_lines"
    n_points = int(rng.choice([200, 700, 2000], p=[0.35, 0.45, 0.2]))
    return Design(
        layout=layout,
        n_points=n_points,
        styli=int(rng.choice([1, 5])),
        duration_s=float(rng.choice([3600.0, 8 * 3600.0])),
        noise_um=round(float(rng.uniform(0.25, 1.0)), 3),
    )


def _styli(rng: np.random.Generator, spec: MachineSpec, count: int) -> FloatArray:
    down = spec.probe_mm.copy()
    if count == 1:
        return down[None, :]
    h = float(rng.uniform(40.0, 150.0))
    zl = float(rng.uniform(60.0, 150.0))
    return np.array(
        [down, [h, 0.0, -zl], [-h, 0.0, -zl], [0.0, h, -zl], [0.0, -h, -zl]], dtype=float
    ).round(1)


def _times(rng: np.random.Generator, n: int, duration_s: float) -> FloatArray:
    gaps = rng.exponential(1.0, n)
    pauses = rng.random(n) < 0.01
    gaps[pauses] += rng.uniform(10.0, 40.0, pauses.sum())
    t = np.cumsum(gaps)
    return (t - t[0]) / (t[-1] - t[0]) * duration_s


def _directions(rng: np.random.Generator, q: FloatArray) -> dict[str, FloatArray]:
    out: dict[str, FloatArray] = {}
    for k, a in enumerate("xyz"):
        d = np.sign(np.diff(q[:, k], prepend=q[0, k] - rng.choice([-1.0, 1.0])))
        for i in range(len(d)):  # an axis that did not move keeps its last direction
            if d[i] == 0:
                d[i] = d[i - 1] if i > 0 else 1.0
        out[f"dir_{a}"] = d
    return out


def _random_normals(rng: np.random.Generator, n: int) -> FloatArray:
    phi = rng.uniform(0.0, 2 * np.pi, n)
    elev = rng.uniform(-0.5, 0.5, n)
    normals = np.column_stack(
        [np.cos(elev) * np.cos(phi), np.cos(elev) * np.sin(phi), np.sin(elev)]
    )
    down = rng.random(n) < 0.2
    normals[down] = [0.0, 0.0, -1.0]
    return normals


def _random_layout(rng: np.random.Generator, spec: MachineSpec, design: Design, styli: FloatArray):
    lo = spec.lower_mm + 0.02 * spec.span_mm
    hi = spec.upper_mm - 0.02 * spec.span_mm
    n = design.n_points
    q = rng.uniform(lo, hi, (n, 3))
    blocks = np.minimum(np.arange(n) * 10 // n, 9)
    group = np.array([f"block-{b}" for b in blocks])
    stylus_index = blocks % len(styli)
    return q, styli[stylus_index], _random_normals(rng, n), group


def _sphere_points(centre: FloatArray, radius: float) -> tuple[FloatArray, FloatArray]:
    """ISO 10360-5 style: pole, 4 at 22.5°, 8 at 45°, 4 at 67.5°, 8 at 90° from the pole."""
    dirs = [np.array([0.0, 0.0, 1.0])]
    for polar_deg, count in ((22.5, 4), (45.0, 8), (67.5, 4), (90.0, 8)):
        th = np.radians(polar_deg)
        for k in range(count):
            ph = 2 * np.pi * k / count + (np.pi / count if count == 4 else 0.0)
            dirs.append(np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)]))
    out = np.array(dirs)
    return centre + radius * out, -out  # probing direction: towards the centre


def _lines(
    rng: np.random.Generator, spec: MachineSpec, n_lines: int
) -> list[tuple[FloatArray, FloatArray]]:
    """(start, end) of the 7 ISO positions, then random lines (face diagonals, random chords)."""
    lo = spec.lower_mm + 0.05 * spec.span_mm
    hi = spec.upper_mm - 0.05 * spec.span_mm
    out: list[tuple[FloatArray, FloatArray]] = []
    for corner in ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)):
        c = np.array(corner, dtype=float)
        out.append((lo + c * (hi - lo), lo + (1 - c) * (hi - lo)))
    for k in range(3):  # axis-parallel, through a random point of the volume
        a = rng.uniform(lo, hi)
        b = a.copy()
        a[k], b[k] = lo[k], hi[k]
        out.append((a, b))
    while len(out) < n_lines:
        a = rng.uniform(lo, hi)
        b = rng.uniform(lo, hi)
        if np.linalg.norm(b - a) > 0.5 * np.linalg.norm(hi - lo) / np.sqrt(3):
            out.append((a, b))
    return out


def _iso_layout(rng: np.random.Generator, spec: MachineSpec, design: Design, styli: FloatArray):
    per_line = 5 * 3 * 2
    n_lines = max(7, int(np.ceil((design.n_points - 25) / per_line)))
    points: list[FloatArray] = []
    normals: list[FloatArray] = []
    groups: list[str] = []
    stylus: list[FloatArray] = []
    for li, (a, b) in enumerate(_lines(rng, spec, n_lines)):
        d = (b - a) / np.linalg.norm(b - a)
        full = float(np.linalg.norm(b - a))
        lengths = np.sort(rng.uniform(0.1, 1.0, 5)) * full
        lengths[-1] = max(lengths[-1], 0.66 * full)
        start = a + d * float(rng.uniform(0.0, 0.02)) * full
        pen = styli[li % len(styli)]
        for rep in range(3):
            order = lengths if rep % 2 == 0 else lengths[::-1]
            for length in order:
                ends = [(start, d), (start + d * min(length, full * 0.98), -d)]
                if rep % 2 == 1:
                    ends = ends[::-1]
                for p, n in ends:
                    points.append(p)
                    normals.append(n)
                    groups.append(f"line-{li}")
                    stylus.append(pen)
    n_sph = 1 if len(styli) == 1 else len(styli)
    centre = spec.lower_mm + rng.uniform(0.3, 0.7, 3) * spec.span_mm
    for s in range(n_sph):
        pts, nrm = _sphere_points(centre, float(rng.uniform(10.0, 15.0)))
        points.extend(pts)
        normals.extend(nrm)
        groups.extend([f"sphere-{s}"] * len(pts))
        stylus.extend([styli[s]] * len(pts))
    return np.array(points), np.array(stylus), np.array(normals), np.array(groups)


def draw_session(
    rng: np.random.Generator, spec: MachineSpec, design: Design | None = None
) -> Session:
    """Points, styli, times, directions and temperatures of a session on ``spec``."""
    design = design or draw_design(rng)
    styli = _styli(rng, spec, design.styli)
    if design.layout == "random":
        q, stylus, normals, group = _random_layout(rng, spec, design, styli)
    elif design.layout == "iso_lines":
        q, stylus, normals, group = _iso_layout(rng, spec, design, styli)
    else:
        raise ValueError(f"unknown layout {design.layout!r}")
    n = q.shape[0]
    t = _times(rng, n, design.duration_s)
    tf = draw_temperatures(rng, design.duration_s)
    sensor_noise = float(rng.uniform(0.002, 0.008))
    temps = {
        name: tf.at(name, t) + rng.normal(0.0, sensor_noise, n)
        for name in ("T_x", "T_y", "T_z", "T_wp", "T_top", "T_bottom", "T_air")
    }
    return Session(
        design=design,
        q_mm=q,
        stylus_mm=np.asarray(stylus, dtype=float),
        t_s=t,
        temps_C=temps,
        directions=_directions(rng, q),
        normals=normals / np.linalg.norm(normals, axis=1, keepdims=True),
        group=group,
        field=tf,
        notes={"temperatures": tf.description, "sensor_noise_C": sensor_noise},
    )


def periodic_min_period_mm(session: Session, axis_index: int, span_mm: float) -> float:
    """Shortest period (mm) the session can resolve on an axis: 2.5× the 90th-percentile gap
    between the distinct positions it samples, and at least 1/40 of the travel."""
    pos = np.unique(np.round(session.q_mm[:, axis_index], 1))
    gaps = np.diff(pos)
    gap = float(np.percentile(gaps, 90)) if gaps.size else span_mm
    return max(span_mm / 40.0, 2.5 * gap)
