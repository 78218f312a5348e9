"""``cmm-comp fleet diagnose``: the trend names exactly the machines and changes that were
injected, and every session's diagnosis equals ``cmm-comp diagnose`` run on its own; on the
embedded LocalCluster and on a real ``dask scheduler`` / ``dask worker`` pair.

Oracles: ``ROOT/fleet-truth.json`` (what the generator injected: the machines, causes, dates and
rates) and the one-by-one ``cmm-comp diagnose`` (no Dask, no store, no streaming).
Every command runs as docs/fleet.md prints it. A run that starts or joins a Dask cluster runs
through the installed ``cmm-comp`` entry point as a subprocess (:func:`cmm`): its worker
processes and their shutdown are part of what is tested, and a cluster in the test process
would leave Dask's process-wide threads behind. The other commands (generate, the one-by-one
diagnosis, a run whose sessions are all stored, errors found before any cluster starts) run in
this process through the CLI's own ``main()`` (:func:`cmm_here`; tests/README.md rule 6).

Clusters: the worked example runs as printed, on the embedded LocalCluster it starts
(``--workers 2``); every other run joins one real cluster started once for this file
(:func:`scheduler`: ``dask scheduler`` and ``dask worker`` as subprocesses on 127.0.0.1, as a
user starts them, docs/fleet.md "The cluster"), so the file starts two clusters instead of six
(a cluster costs ~4 s of CPU before any work, its worker processes importing the diagnosis
again in every run). The tests that use it come last in the file: a cluster ticks while it
waits.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from datetime import date
from pathlib import Path
from typing import Any

import pytest
from doc_commands import cli

CMM = str(Path(sys.executable).parent / "cmm-comp")
DASK = str(Path(sys.executable).parent / "dask")
ENV = {**os.environ, "PYTHONWARNINGS": "ignore"}

pytestmark = pytest.mark.timeout(900)


def cmm(*argv: str, cwd: Path | None = None, check: bool = True) -> subprocess.CompletedProcess:
    """Run ``cmm-comp ARGV`` as a user would; fail the test with its output on a bad exit."""
    proc = subprocess.run(
        [CMM, *argv], capture_output=True, text=True, cwd=cwd, env=ENV, timeout=800
    )
    if check and proc.returncode != 0:
        pytest.fail(f"cmm-comp {' '.join(argv)} → {proc.returncode}\n{proc.stdout}\n{proc.stderr}")
    return proc


def cmm_here(
    *argv: str, cwd: Path | None = None, check: bool = True
) -> subprocess.CompletedProcess:
    """:func:`cmm` in this process (the CLI's ``main()``): for commands that start no cluster."""
    proc = cli(*argv, cwd=cwd)
    if check and proc.returncode != 0:
        pytest.fail(f"cmm-comp {' '.join(argv)} → {proc.returncode}\n{proc.stdout}\n{proc.stderr}")
    return proc


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """4 machines × 12 weekly sessions of 200 points, diagnosed on 2 workers (docs/fleet.md)."""
    work = tmp_path_factory.mktemp("fleet")
    cmm_here("fleet", "generate", "plant", "--machines", "4", "--dates", "12", "--points", "200",
        cwd=work)  # fmt: skip
    proc = cmm("fleet", "diagnose", "plant", "--json", "fleet.json", "--report", "report",
               "--workers", "2", cwd=work)  # fmt: skip
    out = json.loads((work / "fleet.json").read_text())
    truth = json.loads((work / "plant" / "fleet-truth.json").read_text())
    return {"work": work, "out": out, "truth": truth, "stdout": proc.stdout}


def _changing(truth: dict[str, Any]) -> list[dict[str, Any]]:
    """The injected effects that change within the series (a creep, or one that appears after
    the first date); an effect present unchanged from the first date is no change."""
    first = truth["dates"][0]
    return [c for c in truth["changes"] if c["per_day"] or c["start"] > first]


def _matches(change: dict[str, Any], injected: dict[str, Any]) -> bool:
    return change["cause"] == injected["cause"] and all(
        change["keys"].get(k) == v for k, v in injected["keys"].items()
    )


def test_trend_names_exactly_the_injected_changes(fleet: dict[str, Any]) -> None:
    _assert_trend_names_exactly(fleet["out"], fleet["truth"])


def _assert_trend_names_exactly(out: dict[str, Any], truth: dict[str, Any]) -> None:
    assert sorted(out["machines"]) == sorted(truth["machines"])
    assert len(out["sessions"]) == len(truth["machines"]) * len(truth["dates"])
    assert out["failed"] == []
    injected = _changing(truth)
    assert len({c["machine"] for c in injected}) == 2  # the generator's two changing machines
    flagged = {m for m, s in out["machines"].items() if s["changes"]}
    assert flagged == {c["machine"] for c in injected}, {
        m: [c["text"] for c in s["changes"]] for m, s in out["machines"].items()
    }
    for machine, section in out["machines"].items():
        mine = [c for c in injected if c["machine"] == machine]
        for change in section["changes"]:  # every change reported is one injected
            assert any(_matches(change, c) for c in mine), change["text"]
        for c in mine:  # every injected change is reported and named for recalibration
            assert any(_matches(ch, c) for ch in section["changes"]), (machine, c)
            assert any(
                section["trend"][name]["cause"] == c["cause"] for name in section["recalibrate"]
            )
        if not mine:
            assert section["recalibrate"] == []
            assert "nothing to recalibrate" in section["summary"]


def test_appearance_is_dated_and_creep_rate_matches(fleet: dict[str, Any]) -> None:
    _assert_dated_and_rated(fleet["out"], fleet["truth"])


def _assert_dated_and_rated(out: dict[str, Any], truth: dict[str, Any]) -> None:
    for injected in _changing(truth):
        section = out["machines"][injected["machine"]]
        found = [c for c in section["changes"] if _matches(c, injected)]
        if injected["per_day"]:  # squareness creep: the rate of the injected coefficient
            (creep,) = [c for c in found if c["kind"] == "creep"]
            rate = injected["per_day"]["coefficients"][0]  # µrad/day, legendre_0 is the value
            assert abs(creep["rate_per_day"] - rate) < max(4 * creep["u_rate_per_day"], 0.1 * rate)
        else:  # appeared between the last session before the injected date and that date
            (appeared,) = [c for c in found if c["kind"] == "appeared"]
            before, after = (date.fromisoformat(d) for d in appeared["between"])
            assert before < date.fromisoformat(injected["start"]) <= after
            assert f"appeared between {appeared['between'][0]} and" in section["summary"]


def test_constant_effect_is_persistent_not_a_change(fleet: dict[str, Any]) -> None:
    out, truth = fleet["out"], fleet["truth"]
    constant = [c for c in truth["changes"] if c not in _changing(truth)]
    assert constant  # the generator's cmm-03 carries one
    for c in constant:
        section = out["machines"][c["machine"]]
        assert section["changes"] == []
        names = [n for n, e in section["trend"].items() if e["cause"] == c["cause"]]
        assert names and all(n in section["summary"] for n in names)
        assert "extend the model once" in section["summary"]


def _strip(diagnosis: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in diagnosis.items() if k != "elapsed_s"}


def test_sessions_equal_diagnose_run_one_by_one(fleet: dict[str, Any]) -> None:
    work, out = fleet["work"], fleet["out"]
    by_path = {s["path"]: s for s in out["sessions"]}
    # one session of each machine with an effect, and a clean one
    picks = [
        next(p for p in by_path if p.startswith(m) and (by_path[p]["diagnosis"]["effects"] or m == "cmm-01"))
        for m in ("cmm-01", "cmm-02", "cmm-03", "cmm-04")
    ]  # fmt: skip
    for path in picks:
        session = work / "plant" / path
        cmm_here("diagnose", str(session / "machine.toml"), str(session / "measurements.csv"),
            "--json", str(work / "one.json"))  # fmt: skip
        alone = json.loads((work / "one.json").read_text())
        assert by_path[path]["machine"] == path.split("/")[0]
        assert _strip(by_path[path]["diagnosis"]) == _strip(alone), path


def test_dask_missing_says_how_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # ``import distributed`` fails
    (tmp_path / "m" / "2026-01-01").mkdir(parents=True)
    proc = cmm_here("fleet", "diagnose", str(tmp_path), "--json", "o.json", cwd=tmp_path,
                    check=False)  # fmt: skip
    assert proc.returncode == 2
    assert "pip install 'cmm-comp[fleet]'" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_bad_root_and_flags(tmp_path: Path) -> None:
    proc = cmm_here("fleet", "diagnose", str(tmp_path / "nope"), "--json", "o.json", check=False)
    assert proc.returncode == 2 and "no such directory" in proc.stderr
    proc = cmm_here("fleet", "diagnose", str(tmp_path), "--json", "o.json", "--workers", "0",
               check=False)  # fmt: skip
    assert proc.returncode == 2
    assert "no session" in proc.stderr or "--workers 0" in proc.stderr


def test_unreachable_scheduler_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "m" / "2026-01-05").mkdir(parents=True)
    (tmp_path / "m" / "2026-01-05" / "machine.toml").write_text("")
    (tmp_path / "m" / "2026-01-05" / "measurements.csv").write_text("")
    proc = cmm("fleet", "diagnose", str(tmp_path), "--json", str(tmp_path / "o.json"),
               "--scheduler", "tcp://127.0.0.1:9", check=False)  # fmt: skip
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "127.0.0.1:9" in proc.stderr


# ------------------------------------------------------------------ a real cluster


def _start(argv: list[str], log: Path) -> subprocess.Popen:
    with open(log, "wb") as fh:
        return subprocess.Popen(
            argv, stdout=fh, stderr=subprocess.STDOUT, env=ENV, start_new_session=True
        )


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the group this test started
            proc.wait(timeout=10)


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A scheduler on 127.0.0.1 (free port) and one ``dask worker`` process with 2 workers of
    one thread (docs/fleet.md "The cluster"), for every test of this file that names it."""
    tmp = tmp_path_factory.mktemp("dask")
    sched_file = tmp / "scheduler.json"
    argv = [DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
            "--scheduler-file", str(sched_file)]  # fmt: skip
    procs = [_start(argv, tmp / "scheduler.log")]
    try:
        t0 = time.monotonic()
        while not sched_file.exists() and time.monotonic() - t0 < 120:
            assert procs[0].poll() is None, (tmp / "scheduler.log").read_text()
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        argv = [DASK, "worker", address, "--nworkers", "2", "--nthreads", "1", "--no-dashboard",
                "--local-directory", str(tmp / "dask-worker")]  # fmt: skip
        procs.append(_start(argv, tmp / "worker.log"))
        # a user starts the run once the workers show up: wait for both here, or the run
        # may start (and count its workers) while the second is still registering
        import distributed

        with distributed.Client(address, timeout="30s") as probe:
            probe.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for proc in reversed(procs):
            _stop(proc)


def test_second_fleet_on_a_real_scheduler_names_exactly_the_injected_changes(
    tmp_path: Path, scheduler: str
) -> None:
    """Another fleet than the worked example's: other noise and points (seed 1), five machines
    (the reversal on cmm-05, two clean machines), the reversal on another date; diagnosed on
    the real scheduler with its two worker processes. Its sessions' diagnoses (one of each
    changing machine and a clean one) equal the one-by-one ``cmm-comp diagnose``."""
    cmm_here("fleet", "generate", "plant", "--machines", "5", "--dates", "12", "--points", "200",
        "--seed", "1", "--start", "2026-04-06", cwd=tmp_path)  # fmt: skip
    proc = cmm("fleet", "diagnose", "plant", "--json", "fleet.json", "--scheduler", scheduler,
               cwd=tmp_path)  # fmt: skip
    assert "60 run, 0 stored before, 0 failed" in proc.stdout
    out = json.loads((tmp_path / "fleet.json").read_text())
    truth = json.loads((tmp_path / "plant" / "fleet-truth.json").read_text())
    assert out["run"]["workers"] == 2
    assert {c["machine"] for c in _changing(truth)} == {"cmm-02", "cmm-05"}
    _assert_trend_names_exactly(out, truth)
    _assert_dated_and_rated(out, truth)
    by_path = {s["path"]: s for s in out["sessions"]}
    changing = sorted({c["machine"] for c in _changing(truth)})
    clean = next(m for m in sorted(truth["machines"]) if m not in changing)
    # each changing machine's last session (its change there) and a clean machine's first
    picks = [f"{m}/{truth['dates'][-1]}" for m in changing] + [f"{clean}/{truth['dates'][0]}"]
    for path in picks:
        session = tmp_path / "plant" / path
        cmm_here("diagnose", str(session / "machine.toml"), str(session / "measurements.csv"),
            "--json", str(tmp_path / "one.json"))  # fmt: skip
        alone = json.loads((tmp_path / "one.json").read_text())
        assert _strip(by_path[path]["diagnosis"]) == _strip(alone), path


def test_report_and_rerun_skips_finished_sessions(fleet: dict[str, Any], scheduler: str) -> None:
    work = fleet["work"]
    report = work / "report"
    assert (report / "index.html").is_file() and (report / "fleet-trends.png").is_file()
    assert (report / "fleet-trends.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    run = fleet["out"]["run"]
    assert run["sessions_run"] == 48 and run["stored_before"] == 0
    # again: nothing to run; the same sessions and machines
    # (all stored: no cluster starts)
    again = cmm_here(
        "fleet", "diagnose", "plant", "--json", "fleet.json", "--workers", "2", cwd=work
    )
    assert "0 run, 48 stored before, 0 failed" in again.stdout
    second = json.loads((work / "fleet.json").read_text())
    assert second["sessions"] == fleet["out"]["sessions"]
    assert second["machines"] == fleet["out"]["machines"]
    # one input changed: exactly that session runs again
    csv = work / "plant" / "cmm-01" / "2026-01-12" / "measurements.csv"
    original = csv.read_text()
    try:
        csv.write_text(original.replace("line00", "line00a", 1))
        third = cmm("fleet", "diagnose", "plant", "--json", "fleet.json", "--scheduler",
                    scheduler, cwd=work)  # fmt: skip
        assert "1 run, 47 stored before, 0 failed" in third.stdout
    finally:
        csv.write_text(original)


def test_bad_session_is_reported_and_the_rest_completes(
    tmp_path: Path, fleet: dict[str, Any], scheduler: str
) -> None:
    plant = tmp_path / "plant"
    for machine in ("cmm-01", "cmm-04"):  # the first 4 sessions of two machines
        for session in sorted((fleet["work"] / "plant" / machine).iterdir())[:4]:
            shutil.copytree(session, plant / machine / session.name)
    bad = plant / "cmm-04" / "2026-01-19" / "measurements.csv"
    lines = bad.read_text().splitlines()
    lines[5] = lines[5].replace(",", ",abc,", 1)
    bad.write_text("\n".join(lines) + "\n")
    (plant / "cmm-01" / "notes").mkdir()  # no session files: not a session
    (plant / "cmm-01" / "2026-13-01").mkdir()
    (plant / "cmm-01" / "2026-13-01" / "machine.toml").write_text("")
    proc = cmm("fleet", "diagnose", str(plant), "--json", str(tmp_path / "out.json"),
               "--scheduler", scheduler, check=False)  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    out = json.loads((tmp_path / "out.json").read_text())
    failed = {f["path"]: f["error"] for f in out["failed"]}
    assert set(failed) == {"cmm-04/2026-01-19", "cmm-01/2026-13-01"}
    assert "measurements.csv missing" in failed["cmm-01/2026-13-01"]
    # the same one-line message as the one-by-one command
    alone = cmm_here("diagnose", str(bad.parent / "machine.toml"), str(bad), "--json",
                str(tmp_path / "x.json"), check=False)  # fmt: skip
    assert alone.returncode == 2
    assert failed["cmm-04/2026-01-19"] in alone.stderr
    assert "cmm-04/2026-01-19" in proc.stderr and "line " in failed["cmm-04/2026-01-19"]
    assert len(out["sessions"]) == 4 + 3  # the rest completed
    assert not (tmp_path / "x.json").exists()
