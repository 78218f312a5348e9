"""A real writer process killed with SIGKILL or stopped with SIGTERM (Linux/POSIX)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader

from cmm_comp.cli.sessionlog.reader import read_messages

ROOT = Path(__file__).resolve().parents[1]
FLUSH_PERIOD_S = 0.2
RATE_HZ = 1000

# Logs /cmm/raw at a steady rate with log_time = wall clock; chunk_size is large, so only the
# flush timer cuts chunks. Prints "ready" once the file is open.
WRITER = """
import signal, sys, time
from cmm_comp.daemon.sessionlog.writer import SessionWriter
path, flush_s, rate, mode = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
logger = SessionWriter(path, flush_period_s=flush_s, chunk_size=16 * 1024 * 1024)
term = []
if mode == "term":  # the writer writes in this thread: the handler only asks, the loop stops
    signal.signal(signal.SIGTERM, lambda signum, frame: term.append(signum))
print("ready", flush=True)
t0 = time.monotonic()
i = 0
reported = 0
while not term:
    logger.log("/cmm/raw", {"seq": i, "x_mm": i * 0.001, "y_mm": 0.0, "z_mm": 0.0})
    i += 1
    flushed = logger.stats().flushed  # written before the last flush to the OS
    if flushed != reported:
        print(flushed, flush=True)
        reported = flushed
    delay = t0 + i / rate - time.monotonic()
    if delay > 0:
        time.sleep(delay)
ok = logger.stop(5.0)
sys.exit(0 if ok and logger.error is None else 3)
"""

pytestmark = pytest.mark.skipif(os.name != "posix", reason="needs POSIX signals")


def _start(path: Path, mode: str) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(path), str(FLUSH_PERIOD_S), str(RATE_HZ), mode],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if line.strip() != "ready":
        proc.kill()
        proc.wait(5)
        pytest.fail(f"writer did not start: {line!r}")
    return proc


def test_sigkill_loses_only_what_was_not_flushed(tmp_path: Path) -> None:
    """Causality, not a clock: the writer prints how many messages it had flushed to the OS;
    once that passes 500 the test kills it. Every flushed message must be in the cut file
    (the flush timer bounds how much is unflushed: ``flush_period_s``)."""
    path = tmp_path / "killed.mcap"
    proc = _start(path, "kill")
    flushed = 0
    try:
        assert proc.stdout is not None
        while flushed < 500:
            line = proc.stdout.readline()
            assert line, "the writer ended before it flushed 500 messages"
            flushed = int(line)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(5)
        assert proc.stdout is not None
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL

    with open(path, "rb") as f, pytest.raises(McapError):
        make_reader(f).get_summary()  # the seeking reader cannot open a cut file...

    res = read_messages(path)  # ...the stream reader reads up to the break
    assert res.truncated and res.error is not None
    seqs = [m.payload["seq"] for m in res.messages]
    assert seqs == list(range(len(seqs)))  # no gaps: everything before the break is there
    assert len(seqs) >= flushed  # nothing the writer had flushed is lost
    assert dict(res.metadata)["session"]["pid"] == str(proc.pid)


def test_sigterm_finishes_the_file(tmp_path: Path) -> None:
    path = tmp_path / "term.mcap"
    proc = _start(path, "term")
    flushed = 0
    try:
        assert proc.stdout is not None
        while flushed < 200:  # the writer has flushed 200 messages: no clock involved
            line = proc.stdout.readline()
            assert line, "the writer ended before it flushed 200 messages"
            flushed = int(line)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
        assert proc.stdout is not None
        proc.stdout.close()
    assert proc.returncode == 0

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.chunk_indexes
    res = read_messages(path)
    assert not res.truncated and res.error is None
    seqs = [m.payload["seq"] for m in res.messages]
    assert seqs == list(range(len(seqs))) and len(seqs) >= flushed
    assert summary.statistics is not None and summary.statistics.message_count == len(seqs)
    assert dict(res.metadata)["session_end"]["dropped"] == "0"
