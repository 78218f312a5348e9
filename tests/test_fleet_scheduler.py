"""``cmm-comp fleet diagnose --scheduler ADDRESS`` on a real cluster: ``dask scheduler`` and
``dask worker`` started as subprocesses on 127.0.0.1, as a user starts them (docs/fleet.md).

Oracle: the same fleet diagnosed on the embedded LocalCluster (a separate run) and one session
by the one-by-one ``cmm-comp diagnose``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_fleet import ENV, cmm, cmm_here

DASK = str(Path(sys.executable).parent / "dask")
pytestmark = pytest.mark.timeout(900)


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


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[str]:
    """A scheduler on 127.0.0.1 (free port) and one ``dask worker`` process with 2 workers."""
    sched_file = tmp_path / "scheduler.json"
    scheduler = _start(
        [
            DASK,
            "scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--no-dashboard",
            "--scheduler-file",
            str(sched_file),
        ],
        tmp_path / "scheduler.log",
    )
    procs = [scheduler]
    try:
        t0 = time.monotonic()
        while not sched_file.exists() and time.monotonic() - t0 < 120:
            assert scheduler.poll() is None, (tmp_path / "scheduler.log").read_text()
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        procs.append(
            _start(
                [
                    DASK,
                    "worker",
                    address,
                    "--nworkers",
                    "2",
                    "--nthreads",
                    "1",
                    "--no-dashboard",
                    "--local-directory",
                    str(tmp_path / "dask-worker"),
                ],
                tmp_path / "worker.log",
            )
        )
        # a user starts the run once the workers show up: wait for both here, or the run
        # may start (and count its workers) while the second is still registering
        import distributed

        with distributed.Client(address, timeout="30s") as probe:
            probe.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for proc in reversed(procs):
            _stop(proc)


def test_fleet_on_a_real_scheduler_equals_local_cluster(tmp_path: Path, cluster: str) -> None:
    cmm_here(
        "fleet",
        "generate",
        "plant",
        "--machines",
        "3",
        "--dates",
        "4",
        "--points",
        "120",
        cwd=tmp_path,
    )
    proc = cmm(
        "fleet", "diagnose", "plant", "--json", "remote.json", "--scheduler", cluster, cwd=tmp_path
    )
    assert "12 run, 0 stored before, 0 failed" in proc.stdout
    cmm("fleet", "diagnose", "plant", "--json", "local.json", "--workers", "1", cwd=tmp_path)
    remote = json.loads((tmp_path / "remote.json").read_text())
    local = json.loads((tmp_path / "local.json").read_text())
    assert remote["run"]["workers"] == 2

    def strip(out: dict) -> list:
        return [
            {**s, "diagnosis": {k: v for k, v in s["diagnosis"].items() if k != "elapsed_s"}}
            for s in out["sessions"]
        ]

    assert strip(remote) == strip(local)
    assert remote["machines"] == local["machines"]
    session = tmp_path / "plant" / "cmm-02" / "2026-01-26"
    cmm_here(
        "diagnose",
        str(session / "machine.toml"),
        str(session / "measurements.csv"),
        "--json",
        str(tmp_path / "one.json"),
    )
    one = json.loads((tmp_path / "one.json").read_text())
    (mine,) = [s for s in strip(remote) if s["path"] == "cmm-02/2026-01-26"]
    assert mine["diagnosis"] == {k: v for k, v in one.items() if k != "elapsed_s"}


def test_unreachable_scheduler_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "m" / "2026-01-05").mkdir(parents=True)
    (tmp_path / "m" / "2026-01-05" / "machine.toml").write_text("")
    (tmp_path / "m" / "2026-01-05" / "measurements.csv").write_text("")
    proc = cmm(
        "fleet",
        "diagnose",
        str(tmp_path),
        "--json",
        str(tmp_path / "o.json"),
        "--scheduler",
        "tcp://127.0.0.1:9",
        check=False,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "127.0.0.1:9" in proc.stderr
