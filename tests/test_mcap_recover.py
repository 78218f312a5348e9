"""Recovering MCAP files cut by a crash (``cmm-comp mcap recover``) and writers killed at random
moments: only the last chunk may be lost.

Oracles: the ``mcap`` package's seeking reader (it refuses a cut file and needs the summary the
recovered file must have); the chunk index of the complete original (every chunk that ends
before the cut must come back whole); and the count of messages the writer had reported
flushed before it was killed (real subprocesses, SIGKILL)."""

from __future__ import annotations

import json
import os
import random
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from test_mcap_log import T0_NS, sample

from cmm_comp.cli.main import main
from cmm_comp.cli.sessionlog.recover import recover
from cmm_comp.daemon.sessionlog.process_writer import McapProcessLogger
from cmm_comp.daemon.sessionlog.writer import SessionWriter

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(os.name != "posix", reason="needs POSIX signals")


def _official(path: Path) -> tuple[list[tuple[str, int, dict]], dict[str, dict[str, str]]]:
    """Messages (topic, log_time, payload) and metadata through the seeking reader, which
    needs a complete file (summary, indexes)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        msgs = [
            (c.topic, m.log_time, json.loads(m.data))
            for _, c, m in reader.iter_messages(log_time_order=False)
        ]
        assert summary.statistics.message_count == len(msgs)
        f.seek(0)
        meta = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    return msgs, meta


def test_recover_keeps_every_chunk_before_the_cut(tmp_path: Path, capsys) -> None:
    full = tmp_path / "full.mcap"
    with SessionWriter(full, chunk_size=1500, flush_period_s=10.0) as lg:
        for i in range(400):
            lg.log("/cmm/raw", sample("/cmm/raw", i), T0_NS + i)
            lg.log("/cmm/status", sample("/cmm/status", i), T0_NS + i)
    original, _ = _official(full)
    with open(full, "rb") as f:  # (chunk index, messages in that chunk), in file order
        indexes = make_reader(f).get_summary().chunk_indexes
        f.seek(0)
        records = StreamReader(f, emit_chunks=True).records
        counts = [
            sum(isinstance(r, Message) for r in breakup_chunk(c))
            for c in records
            if isinstance(c, Chunk)
        ]
    chunks = list(zip(sorted(indexes, key=lambda c: c.chunk_start_offset), counts, strict=True))
    assert len(chunks) > 10 and sum(counts) == len(original)
    data = full.read_bytes()
    cut, fixed = tmp_path / "cut.mcap", tmp_path / "fixed.mcap"
    rng = random.Random(12)
    for size in sorted({*rng.sample(range(len(data)), 25), 8, 40, len(data) - 1}):
        cut.write_bytes(data[:size])
        # the seeking reader refuses the cut file (it parses the bytes where the footer should
        # be; when they read as another record's head, e.g. of an uncompressed message index,
        # it runs off the end: struct.error)
        with open(cut, "rb") as f, pytest.raises((McapError, OSError, ValueError, struct.error)):
            make_reader(f).get_summary()
        assert main(["mcap", "recover", str(cut), "-o", str(fixed), "--force"]) == 0, size
        out = capsys.readouterr().out
        got, meta = _official(fixed)
        assert got == original[: len(got)], size  # a prefix, nothing invented
        # every chunk that ends before the cut comes back whole
        whole = [n for c, n in chunks if c.chunk_start_offset + c.chunk_length <= size]
        assert len(got) >= sum(whole), size
        assert f"cut at byte {meta['recovered']['cut_at']} of {size}" in out
        assert f"recovered {len(got)} messages" in out
    # a complete file comes through whole
    assert main(["mcap", "recover", str(full), "-o", str(fixed), "--force"]) == 0
    assert _official(fixed)[0] == original and "nothing was cut" in capsys.readouterr().out


def test_recover_refuses_bad_input_with_one_line(tmp_path: Path, capsys) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    out = tmp_path / "out.mcap"
    assert main(["mcap", "recover", str(junk), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an MCAP file" in err and not out.exists()
    assert main(["mcap", "recover", str(tmp_path / "nope.mcap"), "-o", str(out)]) == 2
    assert "no such file" in capsys.readouterr().err
    good = tmp_path / "good.mcap"
    with SessionWriter(good) as lg:
        lg.log("/cmm/raw", sample("/cmm/raw", 0))
    out.write_bytes(b"keep")
    assert main(["mcap", "recover", str(good), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == b"keep"
    with pytest.raises(ValueError, match="must not be the file being recovered"):
        recover(good, good, overwrite=True)


# Logs /cmm/raw at ~2 kHz through a SessionWriter (only the 0.1 s flush timer cuts chunks) and
# prints the writer's `flushed` count whenever it changes: what a kill must never lose.
SESSION_WRITER = """
import sys, time
from cmm_comp.daemon.sessionlog.writer import SessionWriter
logger = SessionWriter(sys.argv[1], flush_period_s=0.1, chunk_size=16 * 1024 * 1024)
print("ready", flush=True)
last, i, t0 = -1, 0, time.monotonic()
while True:
    logger.log("/cmm/raw", {"seq": i, "x_mm": i * 0.001, "y_mm": 0.0, "z_mm": 0.0})
    i += 1
    flushed = logger.stats().flushed
    if flushed != last:
        print(flushed, flush=True)
        last = flushed
    delay = t0 + i / 2000 - time.monotonic()
    if delay > 0:
        time.sleep(delay)
"""


def _last_line_reader(proc: subprocess.Popen[str]) -> tuple[list[str], threading.Thread]:
    lines: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line.strip())

    t = threading.Thread(target=read, daemon=True)
    t.start()
    return lines, t


def _check_recovered(cut: Path, fixed: Path, acknowledged: int) -> int:
    report = recover(cut, fixed)
    got, _ = _official(fixed)
    seqs = [p["seq"] for topic, _, p in got if topic == "/cmm/raw"]
    assert seqs == list(range(len(seqs)))  # a prefix, in order
    assert len(seqs) >= acknowledged  # nothing the writer had flushed is lost
    assert report.messages == len(got)
    return len(seqs)


@contextmanager
def session_writer(path: Path) -> Iterator[list[str]]:
    """:data:`SESSION_WRITER` logging to ``path`` in a subprocess; yields its output lines as
    they arrive (a live list); SIGKILLs it on leaving, and checks that this is what ended it."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-c", SESSION_WRITER, str(path)],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    lines, reader = _last_line_reader(proc)
    try:
        yield lines
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        reader.join(10)
        assert proc.stdout is not None
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL


def acknowledged(lines: list[str]) -> int:
    """The writer's last ``flushed`` count (0 before its first flush)."""
    return max((int(x) for x in lines if x.isdigit()), default=0)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_session_writer_killed_at_a_random_moment_loses_only_the_last_chunk(
    tmp_path: Path, seed: int
) -> None:
    path = tmp_path / "killed.mcap"
    with session_writer(path) as lines:
        t0 = time.monotonic()
        while "ready" not in lines and time.monotonic() - t0 < 30:
            time.sleep(0.01)
        assert "ready" in lines, "writer did not start"
        time.sleep(random.Random(seed).uniform(0.3, 1.5))
        t0 = time.monotonic()  # a loaded machine: at least one flush acknowledged first
        while acknowledged(lines) == 0 and time.monotonic() - t0 < 60:
            time.sleep(0.01)
    assert acknowledged(lines) > 0
    _check_recovered(path, tmp_path / "fixed.mcap", acknowledged(lines))


@pytest.mark.parametrize("seed", [4, 5])
def test_process_writer_child_killed_at_a_random_moment_loses_only_the_last_chunk(
    tmp_path: Path, seed: int
) -> None:
    path = tmp_path / "child-killed.mcap"
    errors: list[BaseException] = []
    lg = McapProcessLogger(
        path, flush_period_s=0.1, chunk_size=16 * 1024 * 1024, on_error=errors.append
    )
    deadline = time.monotonic() + random.Random(seed).uniform(0.3, 1.5)
    i = 0
    # until the random moment, and until the child acknowledged a flush (a loaded machine)
    while time.monotonic() < deadline or (lg.stats().flushed == 0 and i < 200_000):
        lg.log("/cmm/raw", {"seq": i, "x_mm": i * 0.001, "y_mm": 0.0, "z_mm": 0.0})
        i += 1
        time.sleep(0.0005)
    acknowledged = lg.stats().flushed  # the child's last report (lags by <= 0.1 s)
    os.kill(lg.child_pid, signal.SIGKILL)
    lg.stop(10.0)
    assert errors and not lg.healthy  # the lost child is reported, never silent
    assert acknowledged > 0
    recovered = _check_recovered(path, tmp_path / "fixed.mcap", acknowledged)
    st = lg.stats()
    # every message is written or counted as lost; what the child wrote after its last report
    # (<= 0.1 s) is counted as lost although the file may hold it: loss is never under-reported
    assert st.written + st.dropped == i and recovered <= i
