"""A dense one-axis calibration with two instruments, simulated from physics (issue 24 tests).

Written apart from the diagnosis code: nothing here imports it. The stage moves back and forth
between two ends at constant speed, resting at targets; a sensor samples it at a fixed rate
whose start is random for each pass (so the positions of all passes together are dense). Two
instruments, each with its own errors:

* **the machine** (what moves the stage): its true position at indicated position x is
  ``x + E(x, dir, t)/1000`` mm with E (µm) a smooth positioning error, a screw's cyclic error
  locked to x (pitch ``screw_mm``, with a second harmonic), a backlash (the carriage lags its
  drive by half the reversal, against the direction of travel) and a thermal expansion about a
  fixed point that grows with an unlogged temperature rise.
* **the reference** (a laser triangulation sensor looking along the axis from ``sensor_mm``):
  it images the target at a detector coordinate u = K/d (d the distance to the target), and its
  interpolation error is periodic in u with period Λ: ε = A(d)·cos(2πu/Λ + φ) + a harmonic. In
  distance the period is then p(d) = Λ·d²/K (the triangulation law), amplitude A(d) varying
  slowly with distance. Its timestamps may be late (``latency_s``): the sample stamped t was
  taken at t − τ; its reading may creep with time (a warm-up, ``reference_drift_um``), the same
at every distance.

The CSV follows docs/formats.md §2 (x, ref_x …, t, dir_x, v_x, state, group); the reference's
reading is written in the axis frame: ``ref_x = sensor_mm − d_read``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MACHINE_TOML = """format = "cmm-machine/1"
name = "two-instruments"
model = "MB1"

[volume]
x = [-22.0, 22.0]
y = [-1.0, 1.0]
z = [-1.0, 1.0]
reference = [0.0, 0.0, 0.0]

[probe]
offset = [0.0, 0.0, 0.0]

[thermal]
reference_C = 20.0
expansion = { x = 0.0, y = 0.0, z = 0.0 }
"""


@dataclass
class Truth:
    """The hidden effects (µm, mm, s) of one session."""

    smooth_um: float = 12.0  # amplitude of the smooth positioning error
    screw_mm: float = 2.0  # the screw's pitch (machine cyclic error, locked to position)
    screw_um: float = 4.0
    reversal_um: float = 40.0  # backlash B
    expansion_um: float = 6.0  # thermal expansion at the ends of the travel, end of session
    fixed_mm: float = -20.0  # where the structure is fixed (the expansion is zero there)
    sensor_mm: float = 80.0  # the triangulation sensor's optical centre, axis frame
    k_mm2: float = 30000.0  # u = K/d: the sensor's triangulation constant (mm²)
    lambda_mm: float = 1.0  # the interpolation error's period in u
    ripple_um: float = 6.0  # its amplitude at the centre of the travel
    latency_s: float = 0.0
    reference_drift_um: float = 0.0  # the sensor's reading creeps over the session (warm-up)
    noise_um: float = 0.5

    def ripple_period_mm(self, x_mm: float) -> float:
        """The local period of the reference's ripple at axis position x (mm)."""
        d = self.sensor_mm - x_mm
        return self.lambda_mm * d * d / self.k_mm2


@dataclass
class Session:
    """A simulated dense record."""

    truth: Truth
    columns: dict[str, np.ndarray] = field(default_factory=dict)

    def write(self, folder: Path) -> tuple[Path, Path]:
        folder.mkdir(parents=True, exist_ok=True)
        machine = folder / "machine.toml"
        machine.write_text(MACHINE_TOML)
        csv = folder / "measurements.csv"
        names = list(self.columns)
        rows = [",".join(names)]
        for i in range(len(self.columns["x"])):
            rows.append(",".join(_cell(self.columns[k][i]) for k in names))
        csv.write_text("\n".join(rows) + "\n")
        return machine, csv


def _cell(v: object) -> str:
    return v if isinstance(v, str) else repr(float(v))  # type: ignore[arg-type]


def _machine_error_um(t: Truth, x: np.ndarray, d: np.ndarray, heat: np.ndarray) -> np.ndarray:
    s = x / 20.0
    smooth = t.smooth_um * (0.6 * s**3 - 0.4 * s**2 + 0.3 * np.sin(2.2 * s))
    w = 2.0 * np.pi / t.screw_mm
    screw = t.screw_um * (np.cos(w * x + 0.4) + 0.3 * np.cos(2 * w * x + 1.1))
    backlash = -d * t.reversal_um / 2.0  # the carriage lags its drive
    expansion = t.expansion_um * heat * (x - t.fixed_mm) / 40.0
    return smooth + screw + backlash + expansion


def _sensor_error_um(t: Truth, dist: np.ndarray) -> np.ndarray:
    u = t.k_mm2 / dist
    d0 = t.sensor_mm
    amp = t.ripple_um * (1.0 + 0.5 * (dist - d0) / d0)  # larger far away
    phase = 2.0 * np.pi * u / t.lambda_mm
    return amp * np.cos(phase + 0.7) + 0.25 * amp * np.cos(2 * phase + 2.0)


def simulate(
    truth: Truth,
    *,
    seed: int = 0,
    passes: int = 10,
    both_directions: bool = True,
    speeds_mm_s: tuple[float, ...] = (0.5,),
    rate_hz: float = 10.0,
    ends_mm: tuple[float, float] = (-20.0, 20.0),
    targets_mm: float = 5.0,
    rest_s: float = 1.5,
) -> Session:
    """A record of ``passes`` passes over the travel (alternating directions, or all in +
    with the returns unrecorded), at the speeds given in turn, resting ``rest_s`` at targets
    every ``targets_mm``; the sensor's samples start at a random phase in every pass."""
    rng = np.random.default_rng(seed)
    lo, hi = ends_mm
    cols: dict[str, list[object]] = {k: [] for k in ("x", "t", "dir_x", "v_x", "state", "group")}
    t0 = 0.0
    for p in range(passes):
        d = 1 if (p % 2 == 0 or not both_directions) else -1
        v = speeds_mm_s[p % len(speeds_mm_s)]
        start, stop = (lo, hi) if d > 0 else (hi, lo)
        stops = np.arange(start, stop + d * 1e-9, d * targets_mm)
        phase = rng.uniform(0.0, 1.0 / rate_hz)
        for a, b in itertools.pairwise(stops):
            # rest at a (its samples at x = a), then move to b at speed v
            n_rest = int(rest_s * rate_hz)
            ts = t0 + phase + np.arange(n_rest) / rate_hz
            cols["x"] += [a] * n_rest
            cols["t"] += list(ts)
            cols["v_x"] += [0.0] * n_rest
            cols["state"] += ["rest"] * n_rest
            t0 += rest_s
            move_s = abs(b - a) / v
            tm = np.arange(phase, move_s, 1.0 / rate_hz)
            cols["x"] += list(a + d * v * tm)
            cols["t"] += list(t0 + tm)
            cols["v_x"] += [d * v] * len(tm)
            cols["state"] += ["steady"] * len(tm)
            t0 += move_s
            cols["dir_x"] += [d] * (n_rest + len(tm))
        cols["group"] += [f"pass-{p}"] * (len(cols["x"]) - len(cols["group"]))
        t0 += 5.0  # turn round (or return unrecorded)
    x = np.asarray(cols["x"], float)
    t = np.asarray(cols["t"], float)
    d = np.asarray(cols["dir_x"], float)
    v = np.asarray(cols["v_x"], float)
    heat = (t - t.min()) / (t.max() - t.min())  # an unlogged temperature rising steadily
    # the reference samples the stage at t − τ: where it was then (the indicated position then
    # is x − v·τ, its error taken there)
    x_then = x - v * truth.latency_s
    true = x_then + _machine_error_um(truth, x_then, d, heat) / 1000.0
    dist = truth.sensor_mm - true
    read = dist + _sensor_error_um(truth, dist) / 1000.0 + truth.reference_drift_um * heat / 1000.0
    read = read + rng.normal(0.0, truth.noise_um, len(x)) / 1000.0
    ref_x = truth.sensor_mm - read
    n = len(x)
    columns: dict[str, np.ndarray] = {
        "x": x,
        "y": np.zeros(n),
        "z": np.zeros(n),
        "ref_x": ref_x,
        "ref_y": np.zeros(n),
        "ref_z": np.zeros(n),
        "t": t,
        "dir_x": d,
        "v_x": v,
        "state": np.asarray(cols["state"]),
        "group": np.asarray(cols["group"]),
    }
    return Session(truth, columns)
