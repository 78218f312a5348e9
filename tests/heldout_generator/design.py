"""Session designs: where, when and how a verification session probes the machine.

* ``random``: points drawn uniformly in the volume (3 % margin), visited in random order, each
  probed on a surface whose normal points anywhere a vertical stylus can reach (n_z ≥ −0.3).
* ``lines``: ISO 10360-2 style: a step gauge set up along 7 lines (the 4 space diagonals and one
  line parallel to each axis; 11 with the 4 face diagonals when there are ≥ 1500 points), its
  faces probed front and back (normals ± the line direction), passes forward and backward,
  repeated; ``group`` = artefact position.

Each point is approached from a pre-probe point 5 mm out along the surface normal, so the logged
``dir_<axis>`` is the sign of the last move of that axis (≥ 0.1 mm) and the distance travelled since
the axis last reversed is known (a hysteresis needs it). With 5 styli (a star: the vertical one
and four horizontal ones ±x, ±y) each point uses the stylus a programmer would pick for its normal.
Times run over the session with a pause at every artefact set-up; temperatures are logged at each
point.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from .environment import Environment, logged_temperatures, make_environment
from .machine import MODELS, RandomMachine

FloatArray = NDArray[np.float64]

CLEARANCE_MM = 5.0
MIN_MOVE_MM = 0.1


@dataclass(frozen=True)
class SessionDesign:
    """How the session is run; the default is the outside check's design (issue 11)."""

    model: str = "MB1"
    layout: str = "random"  # random | lines
    n_points: int = 700
    duration_h: float = 4.0
    styli: int = 1  # 1 | 5
    noise_um: float = 0.25  # σ per axis of the reference instrument + probing

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"design model {self.model!r} unknown; allowed: {', '.join(MODELS)}")
        if self.layout not in ("random", "lines"):
            raise ValueError(f"design layout must be 'random' or 'lines', got {self.layout!r}")
        if not (isinstance(self.n_points, int) and 50 <= self.n_points <= 20000):
            raise ValueError(
                f"design n_points must be an integer in 50…20000, got {self.n_points!r}"
            )
        if not (np.isfinite(self.duration_h) and 0.1 <= self.duration_h <= 48):
            raise ValueError(f"design duration_h must be in 0.1…48 h, got {self.duration_h!r}")
        if self.styli not in (1, 5):
            raise ValueError(f"design styli must be 1 or 5, got {self.styli!r}")
        if not (np.isfinite(self.noise_um) and 0.01 <= self.noise_um <= 10):
            raise ValueError(f"design noise_um must be in 0.01…10 µm, got {self.noise_um!r}")

    @property
    def noise_rms_3d_um(self) -> float:
        """3-D RMS of the noise, µm: σ·√3."""
        return float(self.noise_um * np.sqrt(3.0))

    def label(self) -> str:
        return (
            f"{self.model}/{self.layout}/{self.n_points}pt/{self.duration_h:g}h/"
            f"{self.styli}st/σ{self.noise_um:.2f}"
        )


def default_design() -> SessionDesign:
    """The outside check's session: moving bridge, 700 random points, 4 h, one stylus, 0.25 µm."""
    return SessionDesign()


def random_design(rng: np.random.Generator) -> SessionDesign:
    """A variant: any of the ten models, any layout, 1 or 5 styli, 1–8 h, 200–2000 points."""
    return replace(
        default_design(),
        model=str(rng.choice(MODELS)),
        layout=str(rng.choice(["random", "lines"])),
        n_points=int(rng.choice([200, 700, 2000], p=[0.3, 0.4, 0.3])),
        duration_h=float(rng.choice([1.0, 4.0, 8.0])),
        styli=int(rng.choice([1, 5])),
        noise_um=float(np.round(rng.uniform(0.25, 1.0), 2)),
    )


@dataclass
class Session:
    """The points of one session and everything logged with them (plus the true environment)."""

    design: SessionDesign
    q_mm: FloatArray  # (N, 3) indicated stylus-tip positions
    stylus_mm: FloatArray  # (N, 3)
    stylus_id: NDArray[np.int64]  # (N,) 0 = the machine's default stylus
    t_s: FloatArray  # (N,)
    normals: FloatArray  # (N, 3) unit probing normals (surface → probe)
    dirs: FloatArray  # (N, 3) ±1, last direction of travel of each axis
    run_mm: FloatArray  # (N, 3) distance each axis travelled since it last reversed
    group: list[str] | None
    temps_C: dict[str, FloatArray]  # logged
    env: Environment

    @property
    def n(self) -> int:
        return int(self.q_mm.shape[0])


def _random_normals(rng: np.random.Generator, n: int) -> FloatArray:
    nz = rng.uniform(-0.3, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - nz**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), nz], axis=1)


def _line_points(
    rng: np.random.Generator, machine: RandomMachine, n_points: int
) -> tuple[FloatArray, FloatArray, list[str]]:
    lo = machine.lower_mm + 0.05 * machine.span_mm
    hi = machine.upper_mm - 0.05 * machine.span_mm
    lines: list[tuple[FloatArray, FloatArray]] = []
    for corner in ([0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]):
        c = np.array(corner, dtype=float)
        lines.append((lo + c * (hi - lo), lo + (1 - c[0], 1 - c[1], 1) * (hi - lo)))
    for k in range(3):
        a = lo + rng.uniform(0.2, 0.8, 3) * (hi - lo)
        b = a.copy()
        a[k], b[k] = lo[k], hi[k]
        lines.append((a, b))
    if n_points >= 1500:
        for k in range(3):
            a, b = lo.copy(), hi.copy()
            a[k] = b[k] = lo[k] + rng.uniform(0.3, 0.7) * (hi[k] - lo[k])
            lines.append((a, b))
        lines.append((np.array([lo[0], hi[1], lo[2]]), np.array([hi[0], lo[1], lo[2]])))
    per_line = n_points // len(lines)
    stations = int(np.clip(per_line // 6, 5, 21))
    points, normals, groups = [], [], []
    for index, (a, b) in enumerate(lines):
        d = (b - a) / np.linalg.norm(b - a)
        fractions = np.linspace(0.0, 1.0, stations)
        count = per_line + (1 if index < n_points - per_line * len(lines) else 0)
        k = 0
        forward = True
        while k < count:
            for f in fractions if forward else fractions[::-1]:
                if k >= count:
                    break
                face = 1.0 if k % 2 == 0 else -1.0  # front and back faces of a gauge block
                points.append(a + f * (b - a) + face * 0.5 * d)
                normals.append(face * d)
                groups.append(f"P{index + 1}")
                k += 1
            forward = not forward
    return np.array(points), np.array(normals), groups


def _moves(
    q: FloatArray, normals: FloatArray, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray]:
    """Direction of the last move (±1) and run since the last reversal (mm), per point and axis."""
    n = q.shape[0]
    dirs = np.empty((n, 3))
    run = np.empty((n, 3))
    state_dir = rng.choice([-1.0, 1.0], 3)
    state_run = np.full(3, 100.0)
    prev = q[0] + rng.uniform(-100, 100, 3)
    for i in range(n):
        pre = q[i] + CLEARANCE_MM * normals[i]
        for move in (pre - prev, q[i] - pre):
            for k in range(3):
                if abs(move[k]) < MIN_MOVE_MM:
                    continue
                s = np.sign(move[k])
                if s == state_dir[k]:
                    state_run[k] += abs(move[k])
                else:
                    state_dir[k] = s
                    state_run[k] = abs(move[k])
        dirs[i] = state_dir
        run[i] = state_run
        prev = q[i]
    return dirs, run


def _styli(
    rng: np.random.Generator, machine: RandomMachine, normals: FloatArray, count: int
) -> tuple[FloatArray, NDArray[np.int64]]:
    n = normals.shape[0]
    base = machine.stylus_mm
    if count == 1:
        return np.broadcast_to(base, (n, 3)).copy(), np.zeros(n, dtype=np.int64)
    arm = float(np.round(rng.uniform(30.0, 60.0)))
    lateral = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float)
    offsets = np.vstack([base, base + arm * lateral])
    # a horizontal stylus pointing along s probes faces whose normal points against s
    score = normals @ lateral.T  # (N, 4)
    lateral_choice = 1 + np.argmin(score, axis=1)
    use_vertical = np.abs(normals[:, 2]) > 0.7
    ids = np.where(use_vertical, 0, lateral_choice).astype(np.int64)
    return offsets[ids], ids


def _times(
    rng: np.random.Generator, n: int, duration_s: float, group: list[str] | None
) -> FloatArray:
    dt = rng.uniform(0.7, 1.3, n)
    if group is not None:
        new = np.array([i > 0 and group[i] != group[i - 1] for i in range(n)])
        dt[new] += 10.0  # setting the artefact up at its next position
    t = np.cumsum(dt) - dt[0]
    return np.round(t / t[-1] * duration_s * 0.98 + 0.01 * duration_s, 1)


def make_session(
    rng: np.random.Generator,
    design: SessionDesign,
    machine: RandomMachine,
    *,
    activity: float = 1.0,
) -> Session:
    """Draw the session's points, times, styli and environment for ``machine``."""
    if design.layout == "random":
        margin = 0.03 * machine.span_mm
        q = (
            machine.lower_mm
            + margin
            + rng.uniform(0, 1, (design.n_points, 3)) * (machine.span_mm - 2 * margin)
        )
        normals = _random_normals(rng, design.n_points)
        group: list[str] | None = None
    else:
        q, normals, group = _line_points(rng, machine, design.n_points)
    q = np.round(q, 4)
    stylus, ids = _styli(rng, machine, normals, design.styli)
    dirs, run = _moves(q, normals, rng)
    duration_s = design.duration_h * 3600.0
    t = _times(rng, q.shape[0], duration_s, group)
    env = make_environment(rng, duration_s, activity=activity)
    temps = logged_temperatures(rng, env, t)
    return Session(
        design=design,
        q_mm=q,
        stylus_mm=stylus,
        stylus_id=ids,
        t_s=t,
        normals=normals,
        dirs=dirs,
        run_mm=run,
        group=group,
        temps_C=temps,
        env=env,
    )


def with_environment(rng: np.random.Generator, session: Session, activity: float) -> Session:
    """The same session in a livelier (or quieter) room: new temperatures, same points."""
    env = make_environment(rng, session.design.duration_h * 3600.0, activity=activity)
    return replace(session, env=env, temps_C=logged_temperatures(rng, env, session.t_s))
