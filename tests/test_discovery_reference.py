"""The diagnosis tells the machine from the reference instrument (issue 24, "Must show", second
bullet), on a fixed handful of sessions from tests/reference_generator (written apart from the
diagnosis; README there).

The bars of the issue (the first is not met yet, see ``BAR_EXACT``: this test guards the rate
reached, 18/22): ≥ 95 % of the hidden effects named exactly — the identity (cause and its
axis/component; period within 10 %, a ripple's law) as the entry's own cause or one of its
``alternatives``, and the entry's ``source`` the truth's — and no false alarm on sessions where
naming nothing is right (clean ones; a latency in a one-directional session at one speed
without stops, which is a constant offset). The diagnosis runs as a user runs it: the installed
``cmm-comp diagnose MACHINE MEASUREMENTS --json OUT`` in a subprocess, two at a time.

The seeds here are **development seeds** (0–999): they may guide work on the diagnosis. The
held-out figures come from benchmarks/bench_discovery_reference.py (seeds ≥ 1000).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest
from reference_generator.report import misses_text, summary
from reference_generator.runner import find_cli, run_case

# (family, variant, seed): one session per situation the contract separates
CASES = [
    ("ripple_triangulation", "bidirectional-separable", 1),  # reference: the reversal moves it
    ("ripple_triangulation", "bidirectional-unseparable", 1),  # either: r/p near an integer
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
#: Issue 24's bar is ≥ 95 % named exactly; it is **not met yet**: on these development seeds the
#: diagnosis names 18 of 22 exactly (81.8 %, 0 false alarms; 2026-11-27, code of commit efd6ba1 — misses:
#: a reference drift named as the machine's drift twice, a sensor linearity and an unseparable
#: ripple called the reference's in the ``mixed`` session). Re-measured after the fixes of the
#: three discovery cases that had regressed (commit c0ba2ab): the same 18/22, 0 false alarms, the
#: same misses. Until the bar is met the test guards against regression: the rate measured,
#: rounded down. Issue 24 stays open on the bar.
ISSUE_BAR_EXACT = 0.95
BAR_EXACT = 0.80


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    cli = find_cli()
    root = tmp_path_factory.mktemp("reference")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}

    def one(case: tuple[str, str, int]) -> dict[str, Any]:
        family, variant, seed = case
        folder = Path(root) / f"{family}-{variant}-s{seed}"
        return run_case(family, variant, seed, folder, cli=cli, env=env).as_dict()

    with ThreadPoolExecutor(max_workers=2) as pool:
        return list(pool.map(one, CASES))


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
        f"(regression guard {BAR_EXACT:.0%}; issue 24's bar {ISSUE_BAR_EXACT:.0%} not met yet) "
        f"(named, any source: {s['named']}):\n{misses_text(records)}"
    )


@pytest.mark.timeout(600)
def test_no_false_alarm_where_naming_nothing_is_right(records: list[dict[str, Any]]) -> None:
    s = summary(records)
    assert s["sessions_expecting_nothing"] >= 3
    assert not s["false_alarms"], f"false alarms: {s['false_alarms']}\n{misses_text(records)}"
