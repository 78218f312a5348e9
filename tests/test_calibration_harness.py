"""The hidden-truth harness (tests/calibration_generator/scoring.py, badinput.py) proves itself.

Fed the true machine and a U written from the truth, it must report coverage 100 % and RMS
difference 0; fed wrong machines it must fail the bars; fed machines drawn around the truth with
a Monte-Carlo U (k = 2) it must count ≈ 95 %. Its rigid-body removal is checked against an
independent Kabsch fit (SVD, scipy), its bad-input check against stand-in CLIs that refuse well
and badly, and against what today's ``cmm-comp`` says of an unknown command.
"""

from __future__ import annotations

import copy
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from calibration_generator.badinput import SENTINEL, check_rejection, make_bad_cases
from calibration_generator.case import KINDS, MODELS, build_case, machine_for
from calibration_generator.oracle import answer_with, montecarlo_u, perturbed, translated
from calibration_generator.scoring import (
    CaseScore,
    bar_failures,
    calibrate_and_score,
    check_report_json,
    cmm_comp_command,
    match_nodes,
    mentioned_lines,
    pooled,
    read_u_csv,
    remove_rigid,
    score_arrays,
)
from calibration_generator.seeds import CI_CASES, fresh_seeds, is_development_seed
from scipy.spatial.transform import Rotation


@pytest.mark.parametrize("kind", KINDS)
def test_the_truth_scores_full_coverage_and_zero_difference(kind: str, tmp_path: Path) -> None:
    model = MODELS[3 * KINDS.index(kind) % 10]
    case = build_case(tmp_path / "case", 31, kind, model)
    score = calibrate_and_score(case, tmp_path / "run", answer_with(case, case.machine, 0.05))
    assert score.ok, score.problems
    assert score.coverage == 1.0 and score.hits == score.values == 648
    assert score.rms_diff_um < 1e-6 and score.rms_ratio < 1e-7
    assert score.csv_vs_machine_um < 1e-6
    # a rigid shift of everything (no data kind sees it) changes nothing
    moved = translated(case.machine, np.array([7.0, -3.0, 2.5]))
    score = calibrate_and_score(case, tmp_path / "moved", answer_with(case, moved, 0.05))
    assert score.ok and score.coverage == 1.0 and score.rms_ratio < 1e-5


def test_wrong_machines_fail(tmp_path: Path) -> None:
    case = build_case(tmp_path / "case", 32, "mixed", "FB2")
    other = machine_for(33, "FB2")  # another machine of the same model
    score = calibrate_and_score(case, tmp_path / "other", answer_with(case, other, 1.0))
    assert score.rms_ratio > 0.5 and score.coverage < 0.5
    assert bar_failures([score])
    # subtly wrong: a pitch of X off by 3 µrad (ΔX grows with z: not rigid) and a squareness
    wrong = copy.deepcopy(case.machine)
    wrong.legendre["ey_x"] = (
        wrong.legendre["ey_x"] + np.r_[3.0, np.zeros(wrong.legendre["ey_x"].size - 1)]
    )
    wrong.squareness_urad = dict(wrong.squareness_urad, alpha=wrong.squareness_urad["alpha"] + 4.0)
    score = calibrate_and_score(case, tmp_path / "subtle", answer_with(case, wrong, 0.5))
    assert score.ok  # the files are fine ...
    assert score.coverage < 0.9 and bar_failures([score])  # ... the numbers are not


def test_monte_carlo_u_gives_the_nominal_coverage(tmp_path: Path) -> None:
    """Machines drawn around the truth, U = 2 × the ensemble's standard deviation of the
    rigid-free difference: coverage ≈ 95.4 % (Gaussian, k = 2); half that U: ≈ 68 %."""
    case = build_case(tmp_path / "case", 34, "plate", "CX1")
    rng = np.random.default_rng(9)
    u = montecarlo_u(case, rng, 0.3, 150)
    scores = []
    for i in range(12):
        m = perturbed(case.machine, rng, 0.3)
        identified = m.error_um(case.nodes_mm, case.stylus_mm)
        scores.append(score_arrays(case.nodes_mm, identified, case.truth_um, u))
        if i == 0:  # once through the files, as a calibrate would write them
            s = calibrate_and_score(case, tmp_path / "file", answer_with(case, m, u))
            assert s.ok and s.hits == scores[0]["hits"]
    coverage = sum(s["hits"] for s in scores) / sum(s["values"] for s in scores)
    assert 0.92 < coverage < 0.985
    tight = 0.0
    for _ in range(6):
        m = perturbed(case.machine, rng, 0.3)
        tight += score_arrays(
            case.nodes_mm, m.error_um(case.nodes_mm, case.stylus_mm), case.truth_um, u / 2
        )["coverage"]
    assert 0.55 < tight / 6 < 0.8


def test_rigid_removal_agrees_with_an_independent_kabsch_fit() -> None:
    rng = np.random.default_rng(2)
    nodes = rng.uniform([-200, 0, 50], [900, 1500, 700], (216, 3))
    shape = rng.normal(0.0, 3.0, nodes.shape)  # µm, not rigid
    rot = Rotation.from_rotvec(rng.normal(0, 20e-6, 3))  # 20 µrad
    shift_um = rng.normal(0.0, 10.0, 3)
    moved = rot.apply(nodes - nodes.mean(0)) + nodes.mean(0) - nodes
    field = shape + moved * 1000.0 + shift_um
    mine, _ = remove_rigid(nodes, field)
    # Kabsch: the rotation and translation carrying the nodes onto nodes + field, by SVD
    a, b = nodes, nodes + field / 1000.0
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    kabsch = (b - ((a - ca) @ r.T + cb)) * 1000.0
    assert np.abs(mine - kabsch).max() < 2e-3  # second order: (26 µrad)² × 1 m = 0.7 nm
    assert np.abs(mine).max() > 1.0  # the non-rigid part stays
    only_rigid, _ = remove_rigid(nodes, moved * 1000.0 + shift_um)
    assert np.abs(only_rigid).max() < 1e-3  # second order of 20 µrad over a metre


def test_report_checks_catch_what_the_contract_asks(tmp_path: Path) -> None:
    case = build_case(tmp_path / "case", 35, "multilateration", "MB1")
    run = tmp_path / "run"
    run.mkdir()
    answer_with(case, case.machine, 0.1)(case.plan, run / "out.toml", run / "report")
    report = run / "report"
    assert check_report_json(report / "calibration.json", case) == []
    doc = json.loads((report / "calibration.json").read_text())
    for change, word in (
        (lambda d: d.update(gauge=[]), "gauge"),
        (lambda d: d.update(gauge=["the scale of X"]), "rigid"),
        (lambda d: d.pop("condition"), "condition"),
        (lambda d: d.update(model="MB2"), "model"),
        (lambda d: d.update(datasets=d["datasets"][:-1]), "datasets"),
        (lambda d: d["squareness"]["alpha"].pop("u_urad"), "squareness"),
    ):
        broken = copy.deepcopy(doc)
        change(broken)
        (report / "calibration.json").write_text(json.dumps(broken))
        problems = check_report_json(report / "calibration.json", case)
        assert problems and any(word in p for p in problems), (word, problems)
    nodes, err, u = read_u_csv(report / "volumetric_u.csv")
    assert nodes.shape == err.shape == u.shape == (216, 3)
    with pytest.raises(ValueError, match="not the plan's grid"):
        match_nodes(case.nodes_mm, nodes + np.array([0.0, 0.0, 5.0]))
    with pytest.raises(ValueError, match="expected 216"):
        match_nodes(case.nodes_mm, nodes[:-1])
    text = (report / "volumetric_u.csv").read_text().replace("Uy_um", "Uy")
    (report / "volumetric_u.csv").write_text(text)
    with pytest.raises(ValueError, match="Uy_um"):
        read_u_csv(report / "volumetric_u.csv")


def test_bars_and_pooling() -> None:
    def s(hits: int, ratio: float) -> CaseScore:
        return CaseScore(1, "laser", "MB1", 0, 1.0, hits / 100, hits, 100, 1.0, 10.0, ratio)

    assert bar_failures([s(95, 0.05), s(93, 0.1)]) == []
    assert any("coverage" in f for f in bar_failures([s(100, 0.05), s(99, 0.1)]))  # too wide U
    assert any("coverage" in f for f in bar_failures([s(80, 0.05), s(85, 0.1)]))
    assert any("RMS" in f for f in bar_failures([s(95, 0.25), s(95, 0.1)]))
    failed = CaseScore(2, "plate", "FB1", 1, 1.0, problems=["calibrate exited 1"])
    assert bar_failures([s(95, 0.05), failed])
    p = pooled([s(95, 0.05), s(91, 0.3), failed])
    assert p["coverage"] == pytest.approx(0.93) and p["failed"] == 1
    assert p["rms_ratio_within_bar"] == 1


def test_seeds_policy() -> None:
    seeds = fresh_seeds(60)
    assert len(set(seeds)) == 60 and not any(is_development_seed(x) for x in seeds)
    assert all(is_development_seed(seed) for seed, _, _ in CI_CASES)
    assert sorted(m for _, m, _ in CI_CASES) == sorted(MODELS)
    assert {k for _, _, k in CI_CASES} == set(KINDS)


# ------------------------------------------------------------------------------ bad input
def test_line_mentions_are_parsed() -> None:
    assert mentioned_lines("trac.csv: line 7, column 'station'") == {7}
    assert mentioned_lines("trac.csv: lines 7-9: station 4 has 3 points") == {7, 8, 9}
    assert mentioned_lines("plate.toml: ball[3].id: duplicate") == set()


def test_a_toml_defect_may_be_named_by_its_array_entry(bad_cases) -> None:
    dup = next(b for b in bad_cases if b.name == "duplicate_ball_id")
    assert dup.names_the_place("plate.toml: ball[5].id: duplicate id 17 (also ball[2])")
    assert dup.names_the_place(f"plate.toml: line {min(dup.lines)}: id: duplicate")
    assert not dup.names_the_place("plate.toml: ball[4].id: duplicate id 17")
    assert not dup.names_the_place("plate.toml: duplicate ball id 17")


@pytest.fixture(scope="module")
def bad_cases(tmp_path_factory: pytest.TempPathFactory):
    return make_bad_cases(tmp_path_factory.mktemp("bad"))


def test_the_rejection_check_accepts_a_good_refusal_and_catches_bad_ones(
    bad_cases, tmp_path: Path
) -> None:
    for i, bad in enumerate(bad_cases):
        line = f"line {min(bad.lines)}, " if bad.lines else ""
        field = {
            "station": "station",
            r"\bid\b": "ball[5].id",
            "position_mm": "position_mm",
            r"\bfile\b": "plate[0].file",
        }
        word = field.get(bad.field_pattern, bad.field_pattern.replace(r"\b", ""))
        good_msg = f"cmm-comp: error: {bad.file}: {line}{word}: bad {' '.join(bad.also)}"

        def refuse(
            plan: Path, out: Path, report: Path, msg: str = good_msg
        ) -> tuple[int, str, str]:
            return 2, "", msg + "\n"

        assert check_rejection(bad, tmp_path / f"ok{i}", refuse) == [], bad.name

        def sloppy(plan: Path, out: Path, report: Path) -> tuple[int, str, str]:
            out.write_text("half")
            report.mkdir()
            return 1, "", "Traceback (most recent call last):\nValueError: nan\n"

        problems = check_rejection(bad, tmp_path / f"bad{i}", sloppy)
        assert len(problems) >= 5, problems
    wrong_line = bad_cases[0]
    msg = f"cmm-comp: error: {wrong_line.file}: line 1, column 'station': too few points"
    problems = check_rejection(wrong_line, tmp_path / "wl", lambda p, o, r: (2, "", msg))
    assert any("names no line" in p for p in problems)


def test_todays_cli_does_not_pass_the_rejection_check(bad_cases, tmp_path: Path) -> None:
    """Without ``calibrate``, argparse exits 2 with one error line: the check must still fail
    it (no file, line or field named), so a missing command is never mistaken for a refusal."""
    bad = bad_cases[1]
    proc = subprocess.run(
        [*cmm_comp_command(), "frobnicate", str(bad.plan)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    problems = check_rejection(
        bad, tmp_path / "w", lambda p, o, r: (proc.returncode, proc.stdout, proc.stderr)
    )
    assert any(bad.file in p for p in problems)
    assert (tmp_path / "w" / "out.toml").read_bytes() == SENTINEL
    shutil.rmtree(tmp_path / "w")
