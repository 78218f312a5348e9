"""Issue 27's bars on hidden truth: ``cmm-comp calibrate`` on cases it was never shown.

The cases come from ``tests/calibration_generator`` (written apart from the identification, see its
README): a random machine of each of the ten models, data of one kind in turn (laser runs alone,
a ball plate alone, multilateration alone, all three mixed), development seeds ``CI_CASES``. The
CLI runs as a user types it (``cmm-comp calibrate PLAN -o OUT --report DIR``, a subprocess), and
the harness scores what it wrote (``calibration_generator/scoring.py``):

* every case: the run succeeds, its files follow the contract (``volumetric_u.csv`` on the
  plan's grid, ``calibration.json``'s keys, the gauge freedoms reported), and the RMS difference
  of identified vs true volumetric error at the calibration stylus, after the best rigid-body
  motion, is ≤ 20 % of the true error's rigid-body-free RMS;
* pooled over the cases: the fraction of (node, component) with |difference| ≤ U is 90–98 %.

The bad inputs the issue names get one clear error naming file, line and field, and nothing is
written. ``benchmarks/bench_calibration_truth.py`` measures the same on ≥ 50 fresh machines
(through the installed script, a subprocess; ``tests/test_calibration_harness.py`` runs that
path once).

Power of the CI sample: ten machines (one per model, the four kinds in turn) and 6 × 6 × 6 × 3 =
648 (node, component) values each. Each case fails on its own when its RMS difference passes
20 % (a per-case claim, no sampling); the pooled coverage over 6,480 values — correlated within
a machine, so worth ≈ 10 machines — fails a U that is ≈ 1.5× too small (coverage ≈ 80 %) or
≈ 1.5× too large (≈ 99.5 %); the 90–98 % bar to a percent is the benchmark's (50 machines).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from calibration_generator.badinput import BadCase, check_rejection, make_bad_cases
from calibration_generator.case import build_case
from calibration_generator.scoring import (
    RMS_RATIO_BAR,
    CaseScore,
    bar_failures,
    calibrate_and_score,
    pooled,
)
from calibration_generator.seeds import CI_CASES
from doc_commands import cli

Scored = Callable[[int, str, str], CaseScore]


def run_cli(plan: Path, out_toml: Path, report_dir: Path) -> tuple[int, str, str]:
    """``cmm-comp calibrate PLAN -o OUT --report DIR --no-figures`` in this process (the
    harness' contract: exit code, stdout, stderr). The scoring reads the report's
    ``volumetric_u.csv`` and ``calibration.json``, never its PNGs, and drawing them was about
    half of these cases' CPU; tests/test_readme.py checks the figures of a calibration (the
    README's line, drawn once)."""
    proc = cli("calibrate", plan, "-o", out_toml, "--report", report_dir, "--no-figures")
    return proc.returncode, proc.stdout, proc.stderr


@pytest.fixture(scope="module")
def scored(tmp_path_factory: pytest.TempPathFactory) -> Scored:
    """Calibrate and score a case once per module (the pooled test reuses the per-case runs)."""
    root = tmp_path_factory.mktemp("hidden_truth")
    cache: dict[tuple[int, str, str], CaseScore] = {}

    def get(seed: int, model: str, kind: str) -> CaseScore:
        key = (seed, model, kind)
        if key not in cache:
            name = f"{kind}-{model}-{seed}"
            case = build_case(root / name, seed, kind, model)
            cache[key] = calibrate_and_score(case, root / f"run-{name}", run_cli)
        return cache[key]

    return get


@pytest.mark.timeout(600)
@pytest.mark.parametrize(("seed", "model", "kind"), CI_CASES)
def test_identified_error_is_within_the_rms_bar(
    scored: Scored, seed: int, model: str, kind: str
) -> None:
    s = scored(seed, model, kind)
    assert s.ok, f"{kind} {model} seed {seed}: {s.problems}"
    assert s.rms_ratio <= RMS_RATIO_BAR, (
        f"{kind} {model} seed {seed}: RMS difference {s.rms_diff_um:.3f} µm = "
        f"{100 * s.rms_ratio:.1f} % of the true {s.rms_true_um:.3f} µm (bar 20 %); "
        f"coverage {100 * s.coverage:.1f} %, median U {s.median_U_um:.3f} µm"
    )


@pytest.mark.timeout(1800)
def test_pooled_coverage_is_within_90_to_98_percent(scored: Scored) -> None:
    scores = [scored(*c) for c in CI_CASES]
    failures = bar_failures(scores)
    assert not failures, f"{pooled(scores)}\n" + "\n".join(failures)


# ------------------------------------------------------------------------------ bad input
@pytest.fixture(scope="module")
def bad_cases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, BadCase]:
    return {b.name: b for b in make_bad_cases(tmp_path_factory.mktemp("bad_input"))}


BAD_NAMES = [
    "station_with_3_points",
    "duplicate_ball_id",
    "non_monotonic_run",
    "nan_laser_value",
    "nan_trac_length_mm",
    "missing_file",
]


def test_bad_names_are_the_built_cases(bad_cases: dict[str, BadCase]) -> None:
    assert sorted(bad_cases) == sorted(BAD_NAMES)


@pytest.mark.parametrize("name", BAD_NAMES)
def test_bad_input_gets_one_clear_error_and_nothing_written(
    bad_cases: dict[str, BadCase], name: str, tmp_path: Path
) -> None:
    problems = check_rejection(bad_cases[name], tmp_path, run_cli)
    assert not problems, f"{name}: " + "; ".join(problems)


@pytest.mark.timeout(600)
def test_the_plan_the_bad_cases_start_from_is_valid(
    bad_cases: dict[str, BadCase], tmp_path: Path
) -> None:
    """Each bad case is this plan with one defect: it must calibrate (exit 0) untouched. With
    ``--no-figures`` the report is whole but for its PNGs, and its page links none."""
    template = bad_cases["missing_file"].plan.parent.parent / "template" / "calibration.toml"
    rc, _, stderr = run_cli(template, tmp_path / "out.toml", tmp_path / "report")
    assert rc == 0, stderr
    assert (tmp_path / "out.toml").is_file() and (
        tmp_path / "report" / "volumetric_u.csv"
    ).is_file()
    report = tmp_path / "report"
    assert sorted(p.name for p in report.iterdir()) == [
        "calibration.json",
        "index.html",
        "volumetric_u.csv",
    ]
    page = (report / "index.html").read_text()
    assert "<img" not in page and "errors.png not drawn, --no-figures" in page
