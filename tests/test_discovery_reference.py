"""The diagnosis tells the machine from the reference instrument (issue 24, "Must show", second
bullet), on a fixed handful of sessions from tests/reference_generator (written apart from the
diagnosis; README there).

The bars of the issue: ≥ 95 % of the hidden effects named exactly — the identity (cause and
its axis/component; period within 10 %, a ripple's law) as the entry's own cause or one of its
``alternatives``, and the entry's ``source`` the truth's — and no false alarm on sessions where
naming nothing is right (clean ones; a latency in a one-directional session at one speed
without stops, which is a constant offset). The diagnosis runs in this process, as
``cmm-comp diagnose`` runs it (:func:`cmm_comp.cli.diagnosis.run_diagnosis` on the files the
generator wrote, its JSON through a strict round trip), each session once per module: the CLI's
own process boundary is tested elsewhere (tests/test_cli*.py, the ESS test).

The seeds here are **development seeds** (0–999): they guided the work on the diagnosis, and
the rate on them is no evidence of generality. The held-out figures come from
benchmarks/bench_discovery_reference.py (seeds ≥ 1000). What this handful still detects: one
session per situation the contract separates, so a regression that loses two hidden effects
(22 → 20 of 22 named exactly falls below the bar) or names anything on a quiet session fails.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from reference_generator import Run, draw_case, score_diagnosis, write_case
from reference_generator.report import misses_text, summary

from cmm_comp.cli.diagnosis import run_diagnosis

# (family, variant, seed): one session per situation the contract separates
CASES = [
    ("ripple_triangulation", "bidirectional-separable", 1),  # reference: the reversal moves it
    ("ripple_triangulation", "bidirectional-unseparable", 1),  # either: no reversal
    ("ripple_triangulation", "one-directional", 1),  # either
    ("ripple_constant", "bidirectional-separable", 2),
    ("periodic", "bidirectional-separable", 1),  # machine: a scale's interpolation error
    ("periodic", "one-directional", 1),  # either
    ("latency", "bidirectional-rest", 1),  # reference: zero at rest
    ("latency", "bidirectional-one-speed", 1),  # either: a reversal
    ("latency", "one-directional-one-speed", 1),  # nothing: a constant offset
    ("reversal", "bidirectional-rest", 1),  # machine
    ("smooth", "bidirectional", 1),  # either
    ("smooth_reference", "one-directional", 1),  # either
    ("thermal_drift", "bidirectional", 1),  # machine: depends on position
    ("reference_scale", "bidirectional", 1),  # either
    ("reference_drift", "one-directional", 1),  # either: the same at every position
    ("mixed", "bidirectional", 1),  # the ESS record's situation
    ("clean", "bidirectional", 1),
    ("clean", "one-directional", 1),
]
#: Issue 24's bar: ≥ 95 % named exactly. On these development seeds the diagnosis names 22 of
#: 22 exactly (0 false alarms; 2026-12-05, under the generator's separability truth rule λ ≥ 25).
#: Under the first rule (r/p ≥ 0.2 of a period) it was 21/22: the ``mixed`` session's ripple
#: (r/p = 0.075 from an integer) was `either` by that rule; its λ ≈ 1200 makes it the reference's,
#: as the diagnosis names it and as the ESS record's (r/p ≈ 0.06–0.12) must be by issue 24.
ISSUE_BAR_EXACT = 0.95
BAR_EXACT = ISSUE_BAR_EXACT


def _diagnose(case: tuple[str, str, int], root: Path) -> dict[str, Any]:
    """One session, as ``cmm-comp diagnose MACHINE MEASUREMENTS --json OUT`` runs it, in this
    process; a refused session is a record with exit code 2 and the message."""
    family, variant, seed = case
    drawn = draw_case(family, variant, seed)
    machine, meas = write_case(drawn, root / f"{family}-{variant}-s{seed}")
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        diagnosis = run_diagnosis(machine, meas, warn=lambda _msg: None)
    except (OSError, ValueError) as exc:
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        return Run(drawn, None, 2, wall, cpu, str(exc)[-800:], None).as_dict()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    output = json.loads(json.dumps(diagnosis.to_json(), allow_nan=False))  # standard JSON only
    score = score_diagnosis(drawn.hidden, output)
    return Run(drawn, output, 0, wall, cpu, "", score).as_dict()


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    root = tmp_path_factory.mktemp("reference")
    return [_diagnose(case, root) for case in CASES]


@pytest.mark.timeout(600)
def test_every_session_is_diagnosed(records: list[dict[str, Any]]) -> None:
    failed = [(r["case"], r["exit_code"], r["stderr_tail"]) for r in records if r["exit_code"]]
    assert not failed, failed


@pytest.mark.timeout(600)
def test_hidden_effects_named_exactly_with_their_source(records: list[dict[str, Any]]) -> None:
    s = summary(records)
    assert s["hidden_effects"] >= 20
    assert s["rate_named_exactly"] >= BAR_EXACT, (
        f"named exactly {s['named_exactly']}/{s['hidden_effects']} "
        f"(issue 24's bar {ISSUE_BAR_EXACT:.0%}) "
        f"(named, any source: {s['named']}):\n{misses_text(records)}"
    )


@pytest.mark.timeout(600)
def test_no_false_alarm_where_naming_nothing_is_right(records: list[dict[str, Any]]) -> None:
    s = summary(records)
    assert s["sessions_expecting_nothing"] >= 3
    assert not s["false_alarms"], f"false alarms: {s['false_alarms']}\n{misses_text(records)}"


@pytest.mark.timeout(600)
def test_no_machine_cyclic_error_where_none_is_hidden(records: list[dict[str, Any]]) -> None:
    """A machine's cyclic error (`periodic`, source machine) named where the session hides none
    is the leftover of a coordinate gone wrong: before the reading's coordinate was computed
    without the sensor's own named ripple, `ripple_triangulation/bidirectional-separable/s1`
    named two (0.15–0.19 µm at 0.078 and 0.0042 mm) beside its 8.6 µm triangulation ripple —
    the end stops' coordinate carried the ripple's value there (up to its amplitude)."""
    bad = [
        (r["case"], e)
        for r in records
        if r["score"] is not None
        for e in r["score"]["spurious"]
        if e.startswith("periodic(") and e.endswith("/machine")
    ]
    assert not bad, bad
