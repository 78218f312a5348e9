"""A small, independent simulator of calibration data for the identification tests
(tests/test_calibration_*.py, benchmarks/bench_calibrate*.py): random machines of any of the ten
models, and the three data kinds written as the files docs/formats.md §10 describes.

Independent of ``compensation.calibration``: the truth is the public machine API only
(``Machine.volumetric_error``, ``Machine.pose_error``), the readings are computed here from the
contract's definitions (relative linear/angle runs, straightness with the least-squares line
removed per pass, squareness as the angle between least-squares lines of the true paths, plate
centres where the true tip is on the placed ball, lengths from unknown stations with dead
paths), and written with the csv module. Units: mm, µm, µrad.
"""

from __future__ import annotations

import csv
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cmm_comp.compensation import Machine, ParametricErrors
from cmm_comp.compensation.parametric_errors import TABLE_COMPONENTS

MODELS = ("MB1", "MB2", "FB1", "FB2", "MH1", "MH2", "FH1", "FH2", "CX1", "CY1")
LASER_HEADER = [  # the contract (docs/formats.md §10.2), restated: the oracle does not read the code's
    "axis",
    "quantity",
    "position_mm",
    "value",
    "direction",
    "run",
    "line_x_mm",
    "line_y_mm",
    "line_z_mm",
    "optic_offset_x_mm",
    "optic_offset_y_mm",
    "optic_offset_z_mm",
]
ANGLES = {
    "x": {"roll": 0, "pitch": 1, "yaw": 2},
    "y": {"roll": 1, "pitch": 0, "yaw": 2},
    "z": {"roll": 2, "pitch": 1, "yaw": 0},
}


@dataclass(frozen=True)
class Setup:
    """A simulated calibration: volume (lower, upper) mm, the calibration stylus, noise σ."""

    lower: np.ndarray
    upper: np.ndarray
    stylus: np.ndarray
    noise_linear_um: float = 0.2
    noise_angle_urad: float = 0.2
    noise_probe_um: float = 0.3
    noise_length_um: float = 0.3


def random_machine(
    rng: np.random.Generator, model: str, setup: Setup, scale: float = 1.0, wave: bool = True
) -> Machine:
    """Smooth random errors: per table a cubic (plus, with ``wave``, one sinusoid of random
    period), tabulated at 41 points; linear errors up to ~10 µm, angles ~10 µrad, squareness
    ~20 µrad."""
    tables = {}
    for name in TABLE_COMPONENTS:
        k = "xyz".index(name[-1])
        lo, hi = setup.lower[k], setup.upper[k]
        q = np.linspace(lo, hi, 41)
        s = (q - lo) / (hi - lo)
        amp = (4.0 if name[0] == "d" else 5.0) * scale
        poly = rng.normal(0, amp, 3)
        period = rng.uniform(0.4, 1.5)
        v = (
            poly[0] * s
            + poly[1] * s**2
            + poly[2] * s**3
            + (rng.normal(0, amp / 3) if wave else 0.0)
            * np.sin(2 * np.pi * s / period + rng.uniform(0, 2 * np.pi))
        )
        if name[0] == "e":
            v = v + rng.normal(0, amp)
        tables[name] = (q, v)
    errors = ParametricErrors.from_tables(tables, squareness_urad=rng.normal(0, 15.0 * scale, 3))
    volume = tuple(zip(setup.lower, setup.upper, strict=True))
    return Machine.from_parts(model=model, volume=volume, errors=errors, probe=setup.stylus)


def _write(path: Path, header: list[str], rows: list[list[object]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as fh:
        fh.write("# simulated by tests/calibration_sim.py\n")
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def rotation_urad(machine: Machine, q: np.ndarray) -> np.ndarray:
    r = machine.pose_error(q).rotation
    return (
        1e6
        * 0.5
        * np.stack(
            [r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1
        )
    )


def laser_file(
    machine: Machine,
    setup: Setup,
    rng: np.random.Generator,
    path: Path,
    targets: int = 21,
    cycles: int = 2,
) -> None:
    """Runs of every quantity through the middle of the volume, optic at the stylus."""
    centre = 0.5 * (setup.lower + setup.upper)
    optic = setup.stylus
    rows: list[list[object]] = []
    for k, axis in enumerate("xyz"):
        pos = np.linspace(setup.lower[k], setup.upper[k], targets)
        order = []
        for _ in range(cycles):
            order += [(p, 1) for p in pos] + [(p, -1) for p in pos[::-1]]
        q = np.repeat(centre[None], len(order), 0)
        q[:, k] = [p for p, _ in order]
        d = np.array([s for _, s in order], dtype=float)
        err = machine.volumetric_error(q, optic, inputs={f"dir_{axis}": d})
        # the table's own angle (its eI_J's sign): R_work_stylus turns by minus it
        rot = rotation_urad(machine, q) * (-1.0 if axis in machine.chain.workpiece else 1.0)
        quantities = {"linear_um": err[:, k]}
        for j in range(3):
            if j != k:
                quantities[f"straightness_{'xyz'[j]}_um"] = err[:, j]
        for name, j in ANGLES[axis].items():
            quantities[f"{name}_urad"] = rot[:, j]
        for quantity, values in quantities.items():
            noise = setup.noise_angle_urad if quantity.endswith("urad") else setup.noise_linear_um
            v = values + rng.normal(0, noise, len(values))
            if quantity.startswith("straightness"):
                out = v.copy()
                n = len(pos)
                for start in range(0, len(order), n):
                    sl = slice(start, start + n)
                    out[sl] = v[sl] - np.polyval(np.polyfit(q[sl, k], v[sl], 1), q[sl, k])
                v = out
            else:
                v = v - v[0]
            run = f"{axis}-{quantity}"
            for i in range(len(order)):
                rows.append(
                    [
                        axis,
                        quantity,
                        f"{q[i, k]:.4f}",
                        f"{v[i]:.5f}",
                        int(d[i]),
                        run,
                        *centre,
                        *optic,
                    ]
                )
    for a, b in ((0, 1), (0, 2), (1, 2)):
        rows.append(
            [
                f"{'xyz'[a]}{'xyz'[b]}",
                "squareness_urad",
                "",
                f"{squareness(machine, setup, a, b, centre) + rng.normal(0, 0.5):.5f}",
                "",
                f"sq-{a}{b}",
                *centre,
                *optic,
            ]
        )
    _write(path, LASER_HEADER, rows)


def squareness(machine: Machine, setup: Setup, a: int, b: int, centre: np.ndarray) -> float:
    """Angle between least-squares lines of the true optic paths along a and b, minus 90°."""
    dirs = []
    for axis in (a, b):
        q = np.repeat(centre[None], 101, 0)
        q[:, axis] = np.linspace(setup.lower[axis], setup.upper[axis], 101)
        true = q + machine.volumetric_error(q, setup.stylus) / 1000.0
        coef = np.polyfit(q[:, axis], true, 1)[0]
        dirs.append(coef / np.linalg.norm(coef))
    return float((np.arccos(np.clip(dirs[0] @ dirs[1], -1, 1)) - np.pi / 2) * 1e6)


def plate_files(
    machine: Machine, setup: Setup, rng: np.random.Generator, folder: Path, size: float = 400.0
) -> None:
    """A 5 × 5 plate of ``size`` mm (at most 80 % of the smallest travel) in four placements:
    flat low, flat high turned 90°, upright in x–z, upright in y–z; each pose disturbed by a
    few mrad and up to 1 mm (unknown to the fit)."""
    size = min(size, 0.8 * float(np.min(setup.upper - setup.lower)))
    n = 5
    pitch = size / (n - 1)
    lines = []
    for j in range(n * n):
        lines += [
            "[[ball]]",
            f"id = {j + 1}",
            f"u_mm = {pitch * (j % n)}",
            f"v_mm = {pitch * (j // n)}",
            "w_mm = 0.0",
            "u_um = 0.1",
            "",
        ]
    (folder / "plate.toml").write_text("\n".join(lines), encoding="utf-8")
    lo, hi = setup.lower, setup.upper
    mid = 0.5 * (lo + hi)
    flat = np.eye(3)
    turned = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    xz = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    yz = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    half = size / 2
    poses = [
        (flat, np.array([mid[0] - half, mid[1] - half, lo[2] + 0.1 * (hi[2] - lo[2])])),
        (turned, np.array([mid[0] + half, mid[1] - half, lo[2] + 0.8 * (hi[2] - lo[2])])),
        (xz, np.array([mid[0] - half, mid[1], mid[2] - half])),
        (yz, np.array([mid[0], mid[1] - half, mid[2] - half])),
    ]
    rows = []
    for k, (r0, t) in enumerate(poses):
        tilt = rng.uniform(-2e-3, 2e-3, 3)
        r = _rodrigues(tilt) @ r0
        t = t + rng.uniform(-1.0, 1.0, 3)
        corners = np.array([[0, 0, 0], [size, 0, 0], [0, size, 0], [size, size, 0]]) @ r.T + t
        margin = 0.02 * (hi - lo) + 2.0  # every ball inside the volume, whatever the pose
        t = (
            t
            + np.maximum(0.0, lo + margin - corners.min(0))
            - np.maximum(0.0, corners.max(0) - hi + margin)
        )
        for j in range(n * n):
            b = np.array([pitch * (j % n), pitch * (j // n), 0.0])
            target = r @ b + t
            q = target.copy()
            for _ in range(6):
                q = target - machine.volumetric_error(q[None], setup.stylus)[0] / 1000.0
            q = q + rng.normal(0, setup.noise_probe_um, 3) / 1000.0
            rows.append([f"P{k + 1}", j + 1, *(f"{v:.6f}" for v in q)])
    _write(folder / "plate.csv", ["placement", "ball", "x", "y", "z"], rows)


def _rodrigues(v: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(v))
    if a == 0:
        return np.eye(3)
    k = v / a
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx


def trac_file(
    machine: Machine,
    setup: Setup,
    rng: np.random.Generator,
    path: Path,
    stations: int = 5,
    points: int = 60,
) -> np.ndarray:
    """Lengths from ``stations`` stations (below and beside the volume) to ``points`` random
    points; returns the station guesses (true ± 30 mm)."""
    lo, hi = setup.lower, setup.upper
    span = hi - lo
    corners = np.array(
        [
            [0.05, 0.05, -0.15],
            [0.95, 0.05, -0.15],
            [0.95, 0.95, -0.15],
            [0.05, 0.95, -0.15],
            [0.5, -0.2, 0.5],
            [0.5, 1.2, 0.5],
        ]
    )
    true_s = lo + corners[:stations] * span
    pts = lo + rng.uniform(0.02, 0.98, (points, 3)) * span
    true = pts + machine.volumetric_error(pts, setup.stylus) / 1000.0
    rows = []
    for s in range(stations):
        dead = rng.uniform(-300, 300)
        length = np.linalg.norm(true - true_s[s], axis=1) + dead
        length += rng.normal(0, setup.noise_length_um, points) / 1000.0
        for i in range(points):
            rows.append([f"S{s + 1}", i + 1, *(f"{v:.4f}" for v in pts[i]), f"{length[i]:.7f}"])
    _write(path, ["station", "point", "x", "y", "z", "length_mm"], rows)
    return true_s + rng.uniform(-30, 30, true_s.shape)


def write_plan(
    folder: Path,
    model: str,
    setup: Setup,
    kinds: tuple[str, ...],
    guesses: np.ndarray | None,
    nodes: int = 11,
) -> Path:
    """The plan naming the files written for ``kinds``."""
    vol = "\n".join(f"{a} = [{setup.lower[k]}, {setup.upper[k]}]" for k, a in enumerate("xyz"))
    text = [
        f'model = "{model}"',
        "",
        "[volume]",
        vol,
        "steps = [6, 6, 6]",
        "",
        "[probe]",
        f"offset = {list(map(float, setup.stylus))}",
        "",
        "[fit]",
        f"nodes = {nodes}",
        "",
    ]
    if "laser" in kinds:
        text += [
            "[[laser]]",
            'file = "laser.csv"',
            f"u_linear_um = {setup.noise_linear_um}",
            f"u_straightness_um = {setup.noise_linear_um}",
            f"u_angle_urad = {setup.noise_angle_urad}",
            "u_squareness_urad = 0.5",
            "",
        ]
    if "plate" in kinds:
        text += [
            "[[plate]]",
            'balls = "plate.toml"',
            'file = "plate.csv"',
            f"stylus_mm = {list(map(float, setup.stylus))}",
            f"probe_um = {setup.noise_probe_um}",
            "",
        ]
    if "multilateration" in kinds:
        assert guesses is not None
        g = "[" + ", ".join("[" + ", ".join(f"{v:.3f}" for v in s) + "]" for s in guesses) + "]"
        text += [
            "[[multilateration]]",
            'file = "trac.csv"',
            f"stylus_mm = {list(map(float, setup.stylus))}",
            f"station_guess_mm = {g}",
            f"u_um = {setup.noise_length_um}",
            "",
        ]
    path = folder / "calibration.toml"
    path.write_text("\n".join(text), encoding="utf-8")
    return path


def simulate(
    folder: Path,
    model: str,
    setup: Setup,
    kinds: tuple[str, ...],
    rng: np.random.Generator,
    nodes: int = 11,
    wave: bool = True,
) -> tuple[Machine, Path]:
    """A random machine and the plan with its simulated data files for ``kinds``."""
    machine = random_machine(rng, model, setup, wave=wave)
    guesses = None
    if "laser" in kinds:
        laser_file(machine, setup, rng, folder / "laser.csv")
    if "plate" in kinds:
        plate_files(machine, setup, rng, folder)
    if "multilateration" in kinds:
        guesses = trac_file(machine, setup, rng, folder / "trac.csv")
    return machine, write_plan(folder, model, setup, kinds, guesses, nodes)


def rigid_free(points_mm: np.ndarray, field_um: np.ndarray) -> np.ndarray:
    """``field_um`` (N, 3) less its least-squares rigid motion over ``points_mm`` (N, 3)."""
    c = (points_mm - points_mm.mean(0)) / 1000.0
    b = np.zeros((points_mm.shape[0], 3, 6))
    for k in range(3):
        b[:, k, k] = 1.0
    b[:, 1, 3], b[:, 2, 3] = -c[:, 2], c[:, 1]
    b[:, 0, 4], b[:, 2, 4] = c[:, 2], -c[:, 0]
    b[:, 0, 5], b[:, 1, 5] = -c[:, 1], c[:, 0]
    b = b.reshape(-1, 6)
    v = np.asarray(field_um, dtype=float).reshape(-1)
    return (v - b @ np.linalg.lstsq(b, v, rcond=None)[0]).reshape(-1, 3)


def compare(machine: Machine, volumetric_csv: Path) -> dict[str, float]:
    """Identified vs true volumetric error on the CSV's grid at the stylus, rigid-body motion
    removed (least squares): RMS difference as % of the truth's RMS, and the fraction of
    (node, component) within the file's U."""
    data = np.loadtxt(volumetric_csv, delimiter=",", skiprows=1)
    q, e, u = data[:, :3], data[:, 3:6], data[:, 6:9]
    true = machine.volumetric_error(q, machine.probe.offset_mm)
    diff = rigid_free(q, e - true)
    truth = rigid_free(q, true)
    return {
        "rms_percent": float(100 * np.sqrt(np.mean(diff**2)) / np.sqrt(np.mean(truth**2))),
        "coverage": float(np.mean(np.abs(diff) <= u)),
        "rms_diff_um": float(np.sqrt(np.mean(diff**2))),
        "rms_truth_um": float(np.sqrt(np.mean(truth**2))),
    }


def run_cli(
    args: list[str], folder: Path, timeout_s: float = 900.0
) -> subprocess.CompletedProcess[str]:
    """``cmm-comp ARGS`` in ``folder``, as a user runs it (a subprocess), output captured."""
    return subprocess.run(
        [sys.executable, "-m", "cmm_comp.cli", *args],
        cwd=folder,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )
