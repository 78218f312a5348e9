"""The calibration generator (tests/calibration_generator) against physics oracles.

Its own chain against the paper's appendix A.1 (through the independent first-order chain
``tests/independent_generator/chains.py``, checked here term by term against the transcription
``tests/paper_a1.py``), against ``Machine.volumetric_error`` of the machine.toml it writes (the
project's exact model, a cross-check only), and exact vs first order to second order. Then every
data kind against what its instrument physically reports.
"""

from __future__ import annotations

import ast
import copy
import csv
import tomllib
from pathlib import Path

import numpy as np
import pytest
from calibration_generator.case import KINDS, MODELS, build_case, machine_for
from calibration_generator.kinematics import AXES, rotation_matrices
from calibration_generator.laser import (
    LaserDesign,
    LaserNoise,
    laser_runs,
    simulate_run,
    squareness_value_urad,
)
from calibration_generator.machine import COMPONENTS, SQUARENESS, machine_toml
from calibration_generator.multilateration import TracDesign, simulate_trac
from calibration_generator.plate import (
    PlateDesign,
    measure_placement,
    placements,
    plate_side_mm,
    random_plate,
)
from independent_generator.chains import MODELS as CHAIN_MODELS
from independent_generator.chains import chain_error_um
from paper_a1 import CORRECTIONS, PRINTED
from scipy.spatial.transform import Rotation

from cmm_comp.compensation.machine import Machine

PACKAGE = Path(__file__).parent / "calibration_generator"
QUIET = LaserNoise(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def _project_machine(machine, tmp_path: Path) -> Machine:
    path = tmp_path / f"{machine.name}.toml"
    path.write_text(machine_toml(machine), encoding="utf-8")
    return Machine.from_toml(path)


def _read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8", newline="") as fh:
        return list(csv.DictReader(fh))


def _scaled(machine, factor: float):
    out = copy.deepcopy(machine)
    out.legendre = {k: v * factor for k, v in machine.legendre.items()}
    out.squareness_urad = {k: v * factor for k, v in machine.squareness_urad.items()}
    out.reversal_um = {}
    return out


def _only(machine, keep: dict[str, np.ndarray], squareness: dict[str, float] | None = None):
    """The machine with every table zero except ``keep`` (Legendre coefficients)."""
    out = copy.deepcopy(machine)
    out.legendre = {k: keep.get(k, np.zeros(1)) for k in COMPONENTS}
    out.squareness_urad = {s: (squareness or {}).get(s, 0.0) for s in SQUARENESS}
    out.reversal_um = {}
    return out


def _first_order_um(machine, q, stylus) -> np.ndarray:
    comps = {c: machine.component(c, q[:, AXES.index(c[3])]) for c in COMPONENTS}
    comps.update(machine.squareness_urad)
    return chain_error_um(machine.model, q - machine.reference_mm, stylus, comps)


# ------------------------------------------------------------------------------ independence
def test_generator_imports_nothing_of_the_project_but_the_harness_reader() -> None:
    for path in sorted(PACKAGE.glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        project = [n for n in names if n.split(".")[0] in ("cmm_comp", "compensation", "cli")]
        allowed = ["cmm_comp.compensation.machine"] if path.name == "scoring.py" else []
        assert project == allowed, f"{path.name} imports {project}"


# ------------------------------------------------------------------------------ the chains
@pytest.mark.parametrize("model", sorted(PRINTED))
def test_first_order_chain_is_appendix_a1_term_by_term(model: str) -> None:
    """``independent_generator/chains.py`` vs the printed A.1 (+ the one documented correction)."""
    assert (
        CHAIN_MODELS[model]
        == __import__("calibration_generator.kinematics", fromlist=["MODEL_AXES"]).MODEL_AXES[model]
    )
    rng = np.random.default_rng(sum(map(ord, model)))
    names = [*COMPONENTS, *SQUARENESS]
    for _ in range(3):
        u, p = rng.uniform(-900, 900, 3), rng.uniform(-200, 200, 3)
        env0 = dict.fromkeys([*names, "phi1", "phi2"], 0.0)
        env0.update(
            x=u[0] / 1e3, y=u[1] / 1e3, z=u[2] / 1e3, Xp=p[0] / 1e3, Yp=p[1] / 1e3, Zp=p[2] / 1e3
        )
        for name in names:
            env = dict(env0, **{name: 1.0})
            printed = np.array([eval(e, {}, env) for e in PRINTED[model]])
            for (m, i), term in CORRECTIONS.items():
                if m == model:
                    printed[i] += eval(term, {}, env)
            chain = chain_error_um(model, u[None], p[None], {name: np.ones(1)})[0]
            assert np.allclose(chain, printed, atol=1e-12), f"{model} {name}: {chain} vs {printed}"


def test_the_one_correction_is_what_the_identical_chain_prints() -> None:
    """FH1 and FB2 stack the same axes (tool y, z; table x), so the paper must print the same
    equations for both. It does, except that FH1's ΔX lacks FB2's ``y·Ez(x)``: the correction."""
    assert CHAIN_MODELS["FH1"] == CHAIN_MODELS["FB2"]
    assert CORRECTIONS == {("FH1", 0): "y*ez_x"}
    rng = np.random.default_rng(7)
    names = [*COMPONENTS, *SQUARENESS]
    env = dict(
        zip(
            ["x", "y", "z", "Xp", "Yp", "Zp", *names],
            rng.uniform(-1, 1, 6 + len(names)),
            strict=True,
        )
    )
    for i in range(3):
        fh1 = eval(PRINTED["FH1"][i], {}, dict(env))
        fb2 = eval(PRINTED["FB2"][i], {}, dict(env))
        missing = env["y"] * env["ez_x"] if i == 0 else 0.0
        assert fh1 + missing == pytest.approx(fb2, abs=1e-12)


@pytest.mark.parametrize("model", MODELS)
def test_exact_chain_equals_machine_volumetric_error(model: str, tmp_path: Path) -> None:
    """Cross-check: the generator's chain and the project's model of the machine.toml it writes."""
    rng = np.random.default_rng(sum(map(ord, model)) + 1)
    for seed in (1, 2):
        truth = machine_for(seed, model)
        project = _project_machine(truth, tmp_path)
        q = rng.uniform(truth.lower_mm, truth.upper_mm, (300, 3))
        stylus = rng.uniform(-250.0, 250.0, (300, 3))
        got = truth.error_um(q, stylus)
        want = project.volumetric_error(q, stylus_mm=stylus)
        assert np.abs(got - want).max() < 1e-6, model
        assert np.abs(want).max() > 1.0


@pytest.mark.parametrize("model", MODELS)
def test_exact_minus_first_order_is_second_order(model: str) -> None:
    truth = machine_for(11, model)
    rng = np.random.default_rng(5)
    q = rng.uniform(truth.lower_mm, truth.upper_mm, (200, 3))
    stylus = rng.uniform(-250.0, 250.0, (200, 3))
    gaps = []
    for factor in (40.0, 20.0):  # blown up so the second order stands above rounding
        m = _scaled(truth, factor)
        first, exact = _first_order_um(m, q, stylus), m.error_um(q, stylus)
        assert np.abs(exact - first).max() < 1e-3 * np.abs(exact).max()
        gaps.append(np.abs(exact - first).max())
    assert gaps[0] / gaps[1] == pytest.approx(4.0, rel=0.05)


def test_rotation_is_scipy_intrinsic_xyz() -> None:
    a = np.random.default_rng(0).uniform(-3e5, 3e5, (50, 3))  # µrad, large on purpose
    want = Rotation.from_euler("XYZ", a * 1e-6).as_matrix()
    assert np.allclose(rotation_matrices(a), want, atol=1e-14)


def test_machines_are_of_realistic_size() -> None:
    for seed in range(20):
        m = machine_for(seed, MODELS[seed % 10])
        nodes = np.random.default_rng(seed).uniform(m.lower_mm, m.upper_mm, (400, 3))
        err = m.error_um(nodes)
        assert 1.0 < np.sqrt(np.mean(err**2)) < 100.0
        for c in COMPONENTS:
            k = AXES.index(c[3])
            v = m.component(c, np.linspace(m.lower_mm[k], m.upper_mm[k], 101))
            limit = 15.0 if c[0] == "e" else 60.0
            assert np.ptp(v) < limit and np.ptp(v) > 0.1, (c, np.ptp(v))
        assert all(abs(v) <= 30.0 for v in m.squareness_urad.values())


# ------------------------------------------------------------------------------ laser
def test_laser_linear_run_is_the_optics_error_relative_to_its_first_row() -> None:
    """Noise-free: the first-order chain at the optic, minus the first row, plus ±h reversal."""
    truth = machine_for(3, "FB2")
    rng = np.random.default_rng(1)
    for k, axis in enumerate(AXES):
        line = (truth.lower_mm + truth.upper_mm) / 2
        optic = np.array([60.0, -40.0, -120.0])
        targets = np.linspace(truth.lower_mm[k] + 5, truth.upper_mm[k] - 5, 9)
        run = simulate_run(truth, rng, axis, "linear_um", 1, line, optic, targets, 2, QUIET)
        pos = np.array([r["position_mm"] for r in run.rows])
        direction = np.array([r["direction"] for r in run.rows])
        value = np.array([r["value"] for r in run.rows])
        q = np.tile(line, (pos.size, 1))
        q[:, k] = pos
        e = _first_order_um(truth, q, optic)[:, k] + direction * truth.reversal_um[axis]
        assert value[0] == 0.0
        assert np.allclose(value, e - e[0], atol=2e-3)
        back = direction < 0  # same target, opposite direction: the reversal 2h
        fwd_at = {p: v for p, v, d in zip(pos, value, direction, strict=True) if d > 0}
        gap = np.array([fwd_at[p] - v for p, v in zip(pos[back], value[back], strict=True)])
        assert np.allclose(gap, 2 * truth.reversal_um[axis], atol=1e-4)


@pytest.mark.parametrize("model", ["MH2", "FH1", "CX1"])
def test_straightness_run_is_the_optics_error_without_its_line_per_pass(model: str) -> None:
    truth = machine_for(12, model)
    rng = np.random.default_rng(3)
    for k, axis in enumerate(AXES):
        line = truth.lower_mm + 0.7 * (truth.upper_mm - truth.lower_mm)
        optic = np.array([-90.0, 120.0, -200.0])
        targets = np.linspace(truth.lower_mm[k], truth.upper_mm[k], 8)
        for d in (a for a in AXES if a != axis):
            q_name = f"straightness_{d}_um"
            run = simulate_run(truth, rng, axis, q_name, 1, line, optic, targets, 2, QUIET)
            pos = np.array([r["position_mm"] for r in run.rows])
            val = np.array([r["value"] for r in run.rows])
            q = np.tile(line, (pos.size, 1))
            q[:, k] = pos
            e = _first_order_um(truth, q, optic)[:, AXES.index(d)]
            for p in range(4):  # 2 cycles × 2 directions, 8 rows each
                sl = slice(8 * p, 8 * p + 8)
                want = e[sl] - np.polyval(np.polyfit(pos[sl], e[sl], 1), pos[sl])
                assert np.allclose(val[sl], want, atol=2e-3), (axis, d, p)
            assert np.ptp(val) > 0.05  # not trivially zero


@pytest.mark.parametrize("model", ["MB1", "CY1"])
def test_laser_straightness_and_angles(model: str) -> None:
    truth = machine_for(4, model)
    rng = np.random.default_rng(2)
    runs = laser_runs(truth, rng, LaserDesign(targets=9, cycles=2), LaserNoise())
    assert len(runs) == 21
    for run in runs:
        rows = run.rows
        if run.quantity == "squareness_urad":
            continue
        pos = np.array([r["position_mm"] for r in rows])
        val = np.array([r["value"] for r in rows])
        direction = np.array([r["direction"] for r in rows])
        assert set(direction) == {-1, 1}
        passes = np.cumsum(np.r_[0, np.diff(direction) != 0])
        for p in np.unique(passes):
            step = np.diff(pos[passes == p]) * direction[passes == p][0]
            assert np.all(step > 0), "positions strictly monotonic in the pass direction"
            if run.quantity.startswith("straightness"):
                slope, icpt = np.polyfit(pos[passes == p], val[passes == p], 1)
                assert abs(slope) < 1e-9 and abs(icpt) < 1e-7
    # noise-free angles: the carriage's own angular table, relative to the first row
    for axis in AXES:
        k = AXES.index(axis)
        line = truth.lower_mm + 0.4 * (truth.upper_mm - truth.lower_mm)
        targets = np.linspace(truth.lower_mm[k], truth.upper_mm[k], 7)
        for quantity, comp in {
            "x": {"roll_urad": "ex", "pitch_urad": "ey", "yaw_urad": "ez"},
            "y": {"roll_urad": "ey", "pitch_urad": "ex", "yaw_urad": "ez"},
            "z": {"roll_urad": "ez", "pitch_urad": "ey", "yaw_urad": "ex"},
        }[axis].items():
            run = simulate_run(truth, rng, axis, quantity, 1, line, np.zeros(3), targets, 1, QUIET)
            pos = np.array([r["position_mm"] for r in run.rows])
            val = np.array([r["value"] for r in run.rows])
            table = truth.component(f"{comp}_{axis}", pos)
            assert np.allclose(val, table - table[0], atol=2e-4), (model, axis, quantity)


@pytest.mark.parametrize("model", MODELS)
def test_squareness_reading_is_the_squareness_minus_the_straightness_slopes(model: str) -> None:
    """Only squareness: the reading is α/β1/β2 itself. Squareness + straightness of the two axes:
    minus the sum of the tables' least-squares slopes over the travel (first order)."""
    truth = machine_for(6, model)
    sq = {"alpha": 12.0, "beta1": -7.0, "beta2": 4.0}
    pure = _only(truth, {}, sq)
    crossing = (truth.lower_mm + truth.upper_mm) / 2
    for plane, name in (("xy", "alpha"), ("xz", "beta1"), ("yz", "beta2")):
        got = squareness_value_urad(pure, plane, crossing, np.array([30.0, -20.0, -100.0]))
        assert got == pytest.approx(sq[name], abs=1e-4)  # α·β2 products: 1e-4 µrad
    bent = {c: truth.legendre[c] for c in ("dy_x", "dx_y", "dz_x", "dx_z", "dz_y", "dy_z")}
    m = _only(truth, bent, sq)
    for plane, name in (("xy", "alpha"), ("xz", "beta1"), ("yz", "beta2")):
        a, b = plane
        slopes = 0.0
        for moving, other in ((a, b), (b, a)):
            k = AXES.index(moving)
            s = np.linspace(truth.lower_mm[k], truth.upper_mm[k], 201)
            slopes += np.polyfit(s, m.component(f"d{other}_{moving}", s), 1)[0] * 1000.0
        got = squareness_value_urad(m, plane, crossing, np.zeros(3))
        assert got == pytest.approx(sq[name] - slopes, abs=1e-3), (plane, got, slopes)


# ------------------------------------------------------------------------------ plate
@pytest.mark.parametrize("model", ["MB2", "FH1", "CX1"])
def test_plate_centres_are_the_posed_balls_minus_the_machine_error(
    model: str, tmp_path: Path
) -> None:
    truth = machine_for(8, model)
    project = _project_machine(truth, tmp_path)  # the oracle: the project's model, not our chain
    rng = np.random.default_rng(3)
    design = PlateDesign(probe_um=0.0)
    side = plate_side_mm(truth, design)
    plate = random_plate(rng, side, design)
    poses = placements(rng, truth, side, design)
    assert len(poses) >= 6 and {p.plane for p in poses} == {"XY", "XZ", "YZ"}
    assert {p.orientation_deg for p in poses} == {0.0, 90.0}
    assert len(set(plate.ids)) == len(plate.ids)
    dev = np.abs(plate.true_mm - plate.calibrated_mm) * 1000.0 / plate.u_um[:, None]
    assert 0.5 < np.sqrt(np.mean(dev**2)) < 1.5  # the certificate is off by its own u
    for pose in poses:
        assert np.allclose(pose.rotation @ pose.rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(pose.rotation) == pytest.approx(1.0)
        stylus = truth.probe_mm
        q = measure_placement(truth, rng, plate, pose, stylus, 0.0)
        assert np.all(q >= truth.lower_mm) and np.all(q <= truth.upper_mm)
        placed = (pose.rotation @ plate.true_mm.T).T + pose.translation_mm
        tip = q + project.volumetric_error(q, stylus_mm=stylus) / 1000.0
        assert np.abs(tip - placed).max() < 1e-9


def _ball_reach(truth, plan: str, planes: tuple[str, ...], seed: int):
    """(placements, reach per axis as a fraction of the travel, per-end gaps (mm)) of the
    placed true ball centres — brute force over every ball of every placement."""
    design = PlateDesign(planes=planes, plan=plan)
    rng = np.random.default_rng(seed)
    side = plate_side_mm(truth, design)
    plate = random_plate(rng, side, design)
    poses = placements(rng, truth, side, design)
    balls = np.concatenate([(p.rotation @ plate.true_mm.T).T + p.translation_mm for p in poses])
    lo, hi = truth.lower_mm, truth.upper_mm
    assert np.all(balls >= lo) and np.all(balls <= hi)  # every ball inside the travel
    gaps = np.stack([balls.min(0) - lo, hi - balls.max(0)])
    return poses, (balls.max(0) - balls.min(0)) / (hi - lo), gaps


@pytest.mark.parametrize("model", MODELS)
def test_full_reach_plate_plan_reaches_the_ends_of_every_axis(model: str) -> None:
    """The default plan (the PTB practice): over 8 machines per model the placed ball centres
    reach within 2.5 % of both ends of every axis that lies in one of the planes (≤ 5 % of the
    travel unreached), ≥ 4 placements, two planes, two orientations; the reach-limited variant
    is kept and reaches less (it is the plan a single or two-position layout gives)."""
    limited_worst = 1.0
    for k in range(8):
        truth = machine_for(2000 + k, model)
        span = truth.upper_mm - truth.lower_mm
        for planes in (("XY", "XZ", "YZ"), ("XY", "XZ"), ("XY", "YZ")):
            poses, reach, gaps = _ball_reach(truth, "full_reach", planes, k)
            assert len(poses) >= 4 and len({p.plane for p in poses}) >= 2
            assert {p.orientation_deg for p in poses} == {0.0, 90.0}
            axes = sorted({"XYZ".index(c) for p in planes for c in p})
            assert np.all(reach[axes] >= 0.95), (model, k, planes, reach)
            assert np.all(gaps[:, axes] <= 0.025 * span[axes] + 1e-6), (model, k, planes, gaps)
            _, reach_lim, _ = _ball_reach(truth, "reach_limited", planes, k)
            limited_worst = min(limited_worst, float(reach_lim[axes].min()))
    assert limited_worst < 0.95  # the variant leaves part of some axis unreached


def test_one_position_reaching_both_ends_is_pushed_to_them() -> None:
    """With a 15 % margin a plate of 80 % of the shortest travel reaches both ends of that axis
    from one central position: each end ball still lies within the margin of its end."""
    for k, model in enumerate(MODELS):
        truth = machine_for(3000 + k, model)
        span = truth.upper_mm - truth.lower_mm
        design = PlateDesign(reach_margin=0.15)
        rng = np.random.default_rng(k)
        side = plate_side_mm(truth, design)
        plate = random_plate(rng, side, design)
        poses = placements(rng, truth, side, design)
        balls = np.concatenate([(p.rotation @ plate.true_mm.T).T + p.translation_mm for p in poses])
        assert np.all(balls.min(0) - truth.lower_mm <= 0.15 * span + 1e-6), model
        assert np.all(truth.upper_mm - balls.max(0) <= 0.15 * span + 1e-6), model


def test_plate_plan_is_checked() -> None:
    with pytest.raises(ValueError, match="plate plan"):
        PlateDesign(plan="everywhere")


# ------------------------------------------------------------------------------ multilateration
@pytest.mark.parametrize("model", ["MH2", "FB1", "CY1"])
def test_multilateration_lengths_are_distance_plus_dead_path(model: str, tmp_path: Path) -> None:
    truth = machine_for(9, model)
    project = _project_machine(truth, tmp_path)
    quiet = TracDesign(stations=5, length_um=0.0, length_um_per_m=0.0, repeat_um=0.0)
    trac = simulate_trac(truth, np.random.default_rng(4), truth.probe_mm, quiet)
    rows = np.array(trac.rows)
    station, point = rows[:, 0].astype(int), rows[:, 1].astype(int)
    q, length = rows[:, 2:5], rows[:, 5]
    assert np.allclose(q, trac.program_mm[point - 1])  # one program, the same at every station
    inputs = {f"dir_{a}": trac.directions[a][point - 1] for a in AXES}
    p_true = q + project.volumetric_error(q, stylus_mm=truth.probe_mm, inputs=inputs) / 1000.0
    for s in range(1, 6):
        m = station == s
        assert m.sum() >= 4
        dead = length[m] - np.linalg.norm(p_true[m] - trac.stations_mm[s - 1], axis=1)
        assert np.allclose(dead, trac.dead_path_mm[s - 1], atol=1e-9)
    assert np.all(np.abs(trac.guesses_mm - trac.stations_mm) <= 50.0)
    # the reversal: each axis' last direction of travel along the program
    for k, a in enumerate(AXES):
        moved = np.diff(trac.program_mm[:, k])
        assert np.array_equal(trac.directions[a][1:][moved != 0], np.sign(moved[moved != 0]))


# ------------------------------------------------------------------------------ files
@pytest.mark.parametrize("kind", KINDS)
def test_written_case_is_in_the_issue_formats(kind: str, tmp_path: Path) -> None:
    case = build_case(tmp_path / kind, 21, kind, MODELS[KINDS.index(kind) * 2])
    plan = tomllib.loads(case.plan.read_text(encoding="utf-8"))
    assert plan["model"] == case.model and plan["reference_C"] == 20.0
    assert set(plan) <= {
        "model",
        "reference_C",
        "volume",
        "probe",
        "laser",
        "plate",
        "multilateration",
    }
    assert plan["probe"]["offset"] == case.stylus_mm.tolist()
    for entry in plan.get("laser", []):
        text = (case.directory / entry["file"]).read_text(encoding="utf-8").splitlines()
        body = [line for line in text if not line.startswith("#")]
        assert body[0] == (
            "axis,quantity,position_mm,value,direction,run,line_x_mm,line_y_mm,line_z_mm,"
            "optic_offset_x_mm,optic_offset_y_mm,optic_offset_z_mm"
        )
        rows = list(csv.DictReader(body))
        firsts = {}
        for r in rows:
            firsts.setdefault(r["run"], r)
            if r["quantity"] == "squareness_urad":
                assert r["axis"] in ("xy", "xz", "yz") and r["position_mm"] == ""
            assert np.isfinite(float(r["value"])) and r["direction"] in ("1", "-1")
        assert all(
            float(r["value"]) == 0.0
            for r in firsts.values()
            if r["quantity"].endswith(("linear_um", "urad")) and r["quantity"] != "squareness_urad"
        )
    for entry in plan.get("plate", []):
        balls = tomllib.loads((case.directory / entry["balls"]).read_text(encoding="utf-8"))["ball"]
        assert {"id", "u_mm", "v_mm", "w_mm", "u_um"} == set(balls[0])
        rows = _read_csv(case.directory / entry["file"])
        assert list(rows[0]) == ["placement", "ball", "x", "y", "z"]
        assert len({r["placement"] for r in rows}) >= 4
        assert {int(r["ball"]) for r in rows} == {b["id"] for b in balls}
    for entry in plan.get("multilateration", []):
        rows = _read_csv(case.directory / entry["file"])
        assert list(rows[0]) == ["station", "point", "x", "y", "z", "length_mm"]
        stations = list(dict.fromkeys(r["station"] for r in rows))
        assert len(stations) >= 4 and len(entry["station_guess_mm"]) == len(stations)
        assert len(rows) >= 200
    vol = np.array([plan["volume"][a] for a in AXES])
    assert np.allclose(vol[:, 0], case.machine.lower_mm) and np.allclose(
        vol[:, 1], case.machine.upper_mm
    )


def test_truth_grid_is_the_contract_grid_at_the_probe(tmp_path: Path) -> None:
    case = build_case(tmp_path / "c", 22, "laser", "MH1")
    project = Machine.from_toml(case.directory / "truth" / "machine.toml")
    assert case.nodes_mm.shape == (216, 3)
    for corner in (
        np.array(np.meshgrid(*zip(case.machine.lower_mm, case.machine.upper_mm, strict=True)))
        .reshape(3, -1)
        .T
    ):
        assert np.any(np.all(np.isclose(case.nodes_mm, corner), axis=1))
    want = project.volumetric_error(case.nodes_mm, stylus_mm=project.probe.offset_mm)
    assert np.abs(case.truth_um - want).max() < 1e-6
    rows = _read_csv(case.directory / "truth" / "truth_grid.csv")
    assert np.allclose(
        [[float(r[c]) for c in ("ex_um", "ey_um", "ez_um")] for r in rows], case.truth_um
    )


def test_one_seed_is_one_machine_for_every_kind(tmp_path: Path) -> None:
    a = build_case(tmp_path / "a", 5, "laser", "FB1").machine
    b = build_case(tmp_path / "b", 5, "plate", "FB1").machine
    assert all(np.array_equal(a.legendre[c], b.legendre[c]) for c in COMPONENTS)
    c = build_case(tmp_path / "c", 6, "plate", "FB1").machine
    assert not np.array_equal(a.legendre["dx_x"], c.legendre["dx_x"])
