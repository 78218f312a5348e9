"""A calibration case: a random true machine, data of one kind (or mixed), the plan, the truth.

``build_case(directory, seed, kind, model)`` writes::

    directory/calibration.toml      the plan (the issue's format, the contract's keys)
    directory/laser*.csv            laser runs        (kind laser, mixed)
    directory/plate.toml, plate.csv a ball plate       (kind plate, mixed)
    directory/trac*.csv             multilateration   (kind multilateration, mixed)
    directory/truth/machine.toml    the hidden true machine (docs/formats.md §1)
    directory/truth/truth_grid.csv  x,y,z,ex_um,ey_um,ez_um: the true error on the contract's grid
                                    (6 × 6 × 6 nodes of [volume], corners included) at [probe] offset
    directory/truth/case.json       seed, kind, model, stations, dead paths, plate poses …

The machine depends only on (seed, model), so one seed gives the same machine to every kind (paired
comparisons); the data depend on (seed, kind). Nothing of cmm-comp is imported.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .kinematics import AXES, MODEL_AXES
from .laser import HEADER as LASER_HEADER
from .laser import LaserDesign, LaserNoise, Run, laser_runs
from .machine import TrueMachine, grid_nodes, machine_toml, random_machine
from .multilateration import Trac, TracDesign, simulate_trac
from .plate import (
    PlateDesign,
    measure_placement,
    placements,
    plate_side_mm,
    plate_toml,
    random_plate,
)

FloatArray = NDArray[np.float64]

KINDS = ("laser", "plate", "multilateration", "mixed")
MODELS = tuple(MODEL_AXES)
GRID_STEPS = (6, 6, 6)


@dataclass
class Case:
    """A written case: where its plan is, and the truth to score against."""

    seed: int
    kind: str
    model: str
    directory: Path
    plan: Path
    machine: TrueMachine
    nodes_mm: FloatArray
    truth_um: FloatArray
    datasets: list[dict[str, str]] = field(default_factory=list)  # {"kind", "file"}

    @property
    def stylus_mm(self) -> FloatArray:
        return self.machine.probe_mm


def machine_for(seed: int, model: str) -> TrueMachine:
    """The true machine of a seed and model (the same for every kind)."""
    rng = np.random.default_rng([seed, MODELS.index(model), 0])
    return random_machine(rng, model, name=f"calgen-{model.lower()}-{seed}")


def _fmt(v: Any, digits: int) -> str:
    return v if isinstance(v, str) else f"{v:.{digits}f}"


def write_laser(path: Path, runs: list[Run], note: str) -> None:
    """``laser.csv``: leading comment lines, the issue's header, rows in the order measured."""
    digits = {"position_mm": 3, "value": 4}
    with path.open("w", newline="", encoding="utf-8") as fh:
        fh.write(f"# laser interferometer runs, {note}\n# values are errors, true - indicated\n")
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(LASER_HEADER)
        for run in runs:
            for row in run.rows:
                w.writerow(
                    [
                        row[h] if isinstance(row[h], str | int) else _fmt(row[h], digits.get(h, 3))
                        for h in LASER_HEADER
                    ]
                )


def write_plate(
    directory: Path,
    machine: TrueMachine,
    rng: np.random.Generator,
    design: PlateDesign,
    stylus_mm: FloatArray,
    note: str,
) -> dict[str, Any]:
    """``plate.toml`` + ``plate.csv``; returns the hidden poses."""
    side = plate_side_mm(machine, design)
    plate = random_plate(rng, side, design)
    (directory / "plate.toml").write_text(plate_toml(plate, note), encoding="utf-8")
    poses = placements(rng, machine, side, design)
    with (directory / "plate.csv").open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["placement", "ball", "x", "y", "z"])
        for k, pose in enumerate(poses, start=1):
            q = measure_placement(machine, rng, plate, pose, stylus_mm, design.probe_um)
            for i in rng.permutation(len(plate.ids)):
                w.writerow([k, plate.ids[i], *(f"{v:.6f}" for v in q[i])])
    return {
        "side_mm": side,
        "placements": [
            {
                "plane": p.plane,
                "orientation_deg": p.orientation_deg,
                "rotation": p.rotation.tolist(),
                "translation_mm": p.translation_mm.tolist(),
            }
            for p in poses
        ],
    }


def write_trac(path: Path, trac: Trac) -> None:
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["station", "point", "x", "y", "z", "length_mm"])
        for s, p, x, y, z, length in trac.rows:
            w.writerow([s, p, f"{x:.3f}", f"{y:.3f}", f"{z:.3f}", f"{length:.6f}"])


def _vec(v: FloatArray) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def plan_toml(machine: TrueMachine, sets: list[dict[str, Any]], note: str) -> str:
    """The plan: model, reference_C, [volume], [probe], the data sets (paths relative)."""
    lines = [f"# calibration plan, {note}", f'model = "{machine.model}"', "reference_C = 20.0", ""]
    lines.append("[volume]")
    for k, a in enumerate(AXES):
        lines.append(f"{a} = [{float(machine.lower_mm[k])!r}, {float(machine.upper_mm[k])!r}]")
    lines += ["", "[probe]", f"offset = {_vec(machine.probe_mm)}"]
    for s in sets:
        lines += ["", f"[[{s['kind']}]]"]
        if s["kind"] == "plate":
            lines.append(f'balls = "{s["balls"]}"')
        lines.append(f'file = "{s["file"]}"')
        if "stylus_mm" in s:
            lines.append(f"stylus_mm = {_vec(s['stylus_mm'])}")
        if "station_guess_mm" in s:
            guesses = ", ".join(_vec(g) for g in s["station_guess_mm"])
            lines.append(f"station_guess_mm = [{guesses}]")
    return "\n".join(lines) + "\n"


def _reflector_offsets(rng: np.random.Generator, machine: TrueMachine) -> list[FloatArray]:
    """The probe offset, and half the time a second reflector offset beside it."""
    offsets = [machine.probe_mm]
    if rng.random() < 0.5:
        side = np.zeros(3)
        side[int(rng.integers(0, 2))] = rng.choice([-1.0, 1.0]) * rng.uniform(80.0, 150.0)
        offsets.append(np.round(machine.probe_mm + side, 1))
    return offsets


def _write_data(
    directory: Path,
    machine: TrueMachine,
    rng: np.random.Generator,
    kind: str,
    note: str,
    plate_plan: str = "full_reach",
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    sets: list[dict[str, Any]] = []
    hidden: dict[str, Any] = {}
    if kind in ("laser", "mixed"):
        runs = laser_runs(machine, rng, LaserDesign(targets=15, cycles=2), LaserNoise())
        n_files = 1 if kind == "mixed" else int(rng.integers(1, 3))
        cut = len(runs) // 2
        parts = [runs] if n_files == 1 else [runs[:cut], runs[cut:]]
        for i, part in enumerate(parts):
            name = "laser.csv" if n_files == 1 else f"laser_{i + 1}.csv"
            write_laser(directory / name, part, note)
            sets.append({"kind": "laser", "file": name})
    if kind in ("plate", "mixed"):
        planes: tuple[str, ...] = ("XY", "XZ", "YZ")
        if kind == "mixed":
            planes = ("XY", str(rng.choice(["XZ", "YZ"])))
        design = PlateDesign(planes=planes, plan=plate_plan)
        hidden["plate"] = write_plate(directory, machine, rng, design, machine.probe_mm, note)
        sets.append(
            {
                "kind": "plate",
                "balls": "plate.toml",
                "file": "plate.csv",
                "stylus_mm": machine.probe_mm,
            }
        )
    if kind in ("multilateration", "mixed"):
        offsets = [machine.probe_mm] if kind == "mixed" else _reflector_offsets(rng, machine)
        hidden["multilateration"] = []
        for i, stylus in enumerate(offsets):
            n_st = 4 if kind == "mixed" or i > 0 else int(rng.integers(4, 7))
            trac = simulate_trac(machine, rng, stylus, TracDesign(stations=n_st))
            name = "trac.csv" if i == 0 else f"trac_{i + 1}.csv"
            write_trac(directory / name, trac)
            sets.append(
                {
                    "kind": "multilateration",
                    "file": name,
                    "stylus_mm": stylus,
                    "station_guess_mm": trac.guesses_mm,
                }
            )
            hidden["multilateration"].append(
                {
                    "file": name,
                    "stations_mm": trac.stations_mm.tolist(),
                    "dead_path_mm": trac.dead_path_mm.tolist(),
                    "rows": len(trac.rows),
                }
            )
    return sets, hidden


def build_case(
    directory: Path, seed: int, kind: str, model: str, plate_plan: str = "full_reach"
) -> Case:
    """Write one case into ``directory`` (created) and return it. ``plate_plan``: how the ball
    plate is laid out (``plate.PLATE_PLANS``; the lab's full-reach plan by default)."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; allowed: {KINDS}")
    directory = Path(directory)
    (directory / "truth").mkdir(parents=True, exist_ok=True)
    machine = machine_for(seed, model)
    note = f"generated by tests/calibration_generator, seed {seed}, {kind}, {model}"
    rng = np.random.default_rng([seed, MODELS.index(model), 1 + KINDS.index(kind)])
    sets, hidden = _write_data(directory, machine, rng, kind, note, plate_plan)
    plan = directory / "calibration.toml"
    plan.write_text(plan_toml(machine, sets, note), encoding="utf-8")
    nodes = grid_nodes(machine.lower_mm, machine.upper_mm, GRID_STEPS)
    truth = machine.error_um(nodes, machine.probe_mm)
    (directory / "truth" / "machine.toml").write_text(machine_toml(machine, note), encoding="utf-8")
    write_grid_csv(directory / "truth" / "truth_grid.csv", nodes, truth)
    info = {
        "seed": seed,
        "kind": kind,
        "model": model,
        "plate_plan": plate_plan if kind in ("plate", "mixed") else None,
        "hidden": hidden,
        "datasets": [{"kind": s["kind"], "file": s["file"]} for s in sets],
    }
    (directory / "truth" / "case.json").write_text(json.dumps(info, indent=1), encoding="utf-8")
    return Case(
        seed=seed,
        kind=kind,
        model=model,
        directory=directory,
        plan=plan,
        machine=machine,
        nodes_mm=nodes,
        truth_um=truth,
        datasets=[{"kind": s["kind"], "file": s["file"]} for s in sets],
    )


def write_grid_csv(
    path: Path, nodes_mm: FloatArray, error_um: FloatArray, u_um: FloatArray | None = None
) -> None:
    """``x,y,z,ex_um,ey_um,ez_um`` (+ ``Ux_um,Uy_um,Uz_um`` when U is given) on grid nodes."""
    header = ["x", "y", "z", "ex_um", "ey_um", "ez_um"]
    if u_um is not None:
        header += ["Ux_um", "Uy_um", "Uz_um"]
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for i in range(nodes_mm.shape[0]):
            row = [repr(float(v)) for v in nodes_mm[i]] + [repr(float(v)) for v in error_um[i]]
            if u_um is not None:
                row += [repr(float(v)) for v in u_um[i]]
            w.writerow(row)
