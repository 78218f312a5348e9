"""Write the worked example of docs/calibration.md: a small but complete calibration plan with
all three data kinds (laser runs, a ball plate in four placements, multilateration from four
stations), measured on a simulated moving-bridge machine whose errors are known
(``truth.toml``), with noise, unknown plate poses, station positions known to ±30 mm and dead
paths. Reproducible: a fixed seed; running it again rewrites the same files.

    python examples/calibration/generate.py [OUTDIR]      # default: examples/calibration

Files: ``calibration.toml`` (the plan), ``laser.csv``, ``plate.toml``, ``plate.csv``,
``trac.csv`` and ``truth.toml`` (the machine that "was measured"; a real calibration has none).
Units: mm, µm, µrad.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from cmm_comp.compensation import Machine, ParametricErrors
from cmm_comp.compensation.calibration import (
    load_datasets,
    read_plan,
    simulate_laser,
    simulate_multilateration,
    simulate_plate,
)
from cmm_comp.compensation.calibration.laser import COLUMNS as LASER_COLUMNS
from cmm_comp.compensation.calibration.laser import LaserData

HERE = Path(__file__).resolve().parent
SEED = 27
VOLUME = ((0.0, 800.0), (0.0, 600.0), (0.0, 400.0))
STYLUS = (0.0, 0.0, -100.0)
STATIONS = np.array(
    [[50.0, 50.0, -60.0], [750.0, 60.0, -60.0], [740.0, 560.0, -50.0], [60.0, 550.0, -60.0]]
)

PLAN = """\
# A calibration plan (docs/calibration.md): every data kind once.
model = "MB1"
name = "example-bridge"
reference_C = 20.0

[volume]
x = [0.0, 800.0]
y = [0.0, 600.0]
z = [0.0, 400.0]
steps = [6, 6, 6]

[probe]
offset = [0.0, 0.0, -100.0]      # the calibration stylus: U is given for it

[fit]
basis = "spline"
nodes = 11

[[laser]]
file = "laser.csv"

[[plate]]
balls = "plate.toml"
file = "plate.csv"
stylus_mm = [0.0, 0.0, -100.0]

[[multilateration]]
file = "trac.csv"
stylus_mm = [0.0, 0.0, -100.0]
station_guess_mm = {guesses}
"""


def truth_machine() -> Machine:
    """The simulated machine: smooth errors of a few µm and µrad (polynomials in mm)."""
    poly = {
        "dx_x": [0.0, 4e-3, -3e-6],
        "dy_x": [0.0, 0.0, 6e-6, -6e-9],
        "dz_x": [0.0, 0.0, -4e-6],
        "ex_x": [1.0, 3e-3],
        "ey_x": [-0.5, 2e-3, -3e-6],
        "ez_x": [0.8, -4e-3, 4e-6],
        "dy_y": [0.0, -3e-3, 2e-6],
        "dx_y": [0.0, 0.0, 5e-6],
        "dz_y": [0.0, 0.0, -6e-6, 5e-9],
        "ex_y": [0.3, 2e-3, -3e-6],
        "ey_y": [-1.0, -2e-3],
        "ez_y": [0.5, 3e-3, -4e-6],
        "dz_z": [0.0, 5e-3, -4e-6],
        "dx_z": [0.0, 0.0, 8e-6],
        "dy_z": [0.0, 0.0, -7e-6],
        "ex_z": [0.4, -3e-3],
        "ey_z": [-0.3, 4e-3, -5e-6],
        "ez_z": [0.2, 2e-3],
    }
    errors = ParametricErrors.from_polynomials(poly, squareness_urad=(6.0, -4.0, 3.0))
    return Machine.from_parts(
        model="MB1", volume=VOLUME, errors=errors, probe=STYLUS, name="example-truth"
    )


def laser_rows() -> list[list[object]]:
    """Runs through the middle of the volume, optic at the stylus, two bidirectional cycles."""
    rows: list[list[object]] = []
    centre = [400.0, 300.0, 200.0]
    quantities = {
        "x": [
            "linear_um",
            "straightness_y_um",
            "straightness_z_um",
            "pitch_urad",
            "yaw_urad",
            "roll_urad",
        ],
        "y": [
            "linear_um",
            "straightness_x_um",
            "straightness_z_um",
            "pitch_urad",
            "yaw_urad",
            "roll_urad",
        ],
        "z": [
            "linear_um",
            "straightness_x_um",
            "straightness_y_um",
            "pitch_urad",
            "yaw_urad",
            "roll_urad",
        ],
    }
    for k, axis in enumerate("xyz"):
        targets = np.linspace(VOLUME[k][0], VOLUME[k][1], 17)
        for quantity in quantities[axis]:
            run = f"{axis}-{quantity.split('_')[0]}{quantity.split('_')[1] if 'straight' in quantity else ''}"
            for _ in range(2):
                for direction, pos in ((1, targets), (-1, targets[::-1])):
                    for p in pos:
                        rows.append(
                            [
                                axis,
                                quantity,
                                round(float(p), 3),
                                0.0,
                                direction,
                                run,
                                *centre,
                                *STYLUS,
                            ]
                        )
    for pair, crossing in (
        ("xy", [400.0, 300.0, 200.0]),
        ("xz", [400.0, 300.0, 200.0]),
        ("yz", [400.0, 300.0, 200.0]),
    ):
        rows.append([pair, "squareness_urad", "", 0.0, "", f"sq-{pair}", *crossing, *STYLUS])
    return rows


def plate_balls() -> str:
    lines = ["# 400 mm ball plate, 5 x 5 balls, calibrated centres in the plate frame"]
    j = 0
    for v in range(5):
        for u in range(5):
            j += 1
            lines += [
                "[[ball]]",
                f"id = {j}",
                f"u_mm = {100.0 * u:.1f}",
                f"v_mm = {100.0 * v:.1f}",
                "w_mm = 0.0",
                "u_um = 0.2",
                "",
            ]
    return "\n".join(lines)


def plate_poses() -> list[tuple[np.ndarray, np.ndarray]]:
    """Four placements: flat low, flat high turned 90°, upright in XZ, upright in YZ."""
    rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    xz = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    yz = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return [
        (np.eye(3), np.array([200.0, 100.0, 30.0])),
        (rz, np.array([600.0, 100.0, 330.0])),
        (xz, np.array([200.0, 450.0, 0.0])),
        (yz, np.array([650.0, 100.0, 0.0])),
    ]


def write_csv(path: Path, header: list[str], rows: list[list[object]], comment: str) -> None:
    with path.open("w", newline="", encoding="utf-8") as fh:
        fh.write(f"# {comment}\n")
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def simulated_laser_rows(laser: LaserData) -> list[list[object]]:
    """The laser CSV's rows of the simulated runs (squareness: no position, no direction)."""
    rows: list[list[object]] = []
    for run in laser.runs:
        for i in range(run.n):
            pos = "" if run.kind == "squareness" else f"{run.position_mm[i]:.3f}"
            direction = "" if run.kind == "squareness" else int(run.direction[i])
            axis = "xyz"[run.axis] + ("xyz"[run.component] if run.kind == "squareness" else "")
            rows.append(
                [
                    axis,
                    run.quantity,
                    pos,
                    f"{run.value[i]:.4f}",
                    direction,
                    run.run,
                    *run.points_mm[i],
                    *run.optic_mm,
                ]
            )
    return rows


def main(out: Path) -> None:
    rng = np.random.default_rng(SEED)
    out.mkdir(parents=True, exist_ok=True)
    truth = truth_machine()
    truth.to_toml(out / "truth.toml")
    guesses = STATIONS + rng.uniform(-30.0, 30.0, STATIONS.shape)
    (out / "calibration.toml").write_text(
        PLAN.format(
            guesses="["
            + ", ".join("[" + ", ".join(f"{v:.1f}" for v in g) + "]" for g in guesses)
            + "]"
        ),
        encoding="utf-8",
    )
    laser_header = list(LASER_COLUMNS)
    write_csv(out / "laser.csv", laser_header, laser_rows(), "laser runs (values filled below)")
    (out / "plate.toml").write_text(plate_balls(), encoding="utf-8")
    poses = plate_poses()
    plate_rows = []
    for k, (r, t) in enumerate(poses):
        for j in range(25):
            b = np.array([100.0 * (j % 5), 100.0 * (j // 5), 0.0])
            plate_rows.append([f"P{k + 1}", j + 1, *(r @ b + t).round(4)])
    write_csv(out / "plate.csv", ["placement", "ball", "x", "y", "z"], plate_rows, "plate")
    grid = np.stack(
        np.meshgrid(
            np.linspace(50, 750, 4), np.linspace(50, 550, 4), np.linspace(20, 380, 3), indexing="ij"
        ),
        -1,
    ).reshape(-1, 3)
    trac_rows = [
        [f"S{s + 1}", i + 1, *p, ""] for s in range(len(STATIONS)) for i, p in enumerate(grid)
    ]
    write_csv(out / "trac.csv", ["station", "point", "x", "y", "z", "length_mm"], trac_rows, "trac")

    plan = read_plan(out / "calibration.toml")
    data = load_datasets(plan, need_values=False)
    # perfect air compensation (no per-run scale error): the data as first published
    laser = simulate_laser(truth, data[0].data, rng, scale_ppm=0.0)  # type: ignore[arg-type]
    plate = simulate_plate(truth, data[1].data, poses, rng)  # type: ignore[arg-type]
    dead = rng.uniform(-300.0, 300.0, len(STATIONS))
    trac = simulate_multilateration(truth, data[2].data, STATIONS, dead, rng)  # type: ignore[arg-type]
    write_csv(
        out / "laser.csv",
        laser_header,
        simulated_laser_rows(laser),
        "laser interferometer runs: error = true - indicated, um / urad",
    )
    write_csv(
        out / "plate.csv",
        ["placement", "ball", "x", "y", "z"],
        [
            [
                plate.placements[plate.placement[i]],
                plate.ball_ids[plate.ball[i]],
                *(f"{v:.5f}" for v in plate.q_mm[i]),
            ]
            for i in range(plate.n)
        ],
        "measured ball centres, indicated machine coordinates, mm",
    )
    write_csv(
        out / "trac.csv",
        ["station", "point", "x", "y", "z", "length_mm"],
        [
            [
                trac.stations[trac.station[i]],
                trac_rows[i][1],
                *trac.q_mm[i],
                f"{trac.length_mm[i]:.6f}",
            ]
            for i in range(trac.n)
        ],
        "tracking interferometer lengths (dead path unknown), mm",
    )


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
