"""McapProcessLogger: the MCAP writer in a child process. Round trip of every topic, counters,
complete files after stop(), errors from the child reaching the parent, drops when the queue is
full, the file finished by the child when the parent is SIGKILLed, and the daemon's session
log (the removed ``[mcap] writer`` keys). Real processes and files throughout."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest
from mcap.reader import make_reader
from test_daemon_support import ROOT, base_config, channel, send_temps
from test_mcap_log import T0_NS, sample, without_log_counters

from cmm_comp.cli.sessionlog.reader import read_messages
from cmm_comp.daemon.config import ConfigError, add_override_flags, config_from_dict, load_config
from cmm_comp.daemon.service import DaemonService
from cmm_comp.daemon.sessionlog.process_writer import McapProcessLogger
from cmm_comp.protocol.session_topics import TOPIC_SCHEMAS, check_message, stamp_from_ns
from cmm_comp.sim_controller.controller import CanController, RawReading

pytestmark = pytest.mark.skipif(os.name != "posix", reason="needs POSIX processes and signals")


def _gone(pid: int) -> bool:
    """True when ``pid`` has exited (reaped, or a zombie of a non-reaping init)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def _thread_policies(pid: int) -> list[int]:
    """Scheduling policy of each thread of ``pid`` (main thread first; 0 normal, 5 SCHED_IDLE):
    field 41 of /proc/PID/task/TID/stat."""
    tids = sorted(int(t) for t in os.listdir(f"/proc/{pid}/task"))
    tids.sort(key=lambda t: t != pid)
    out = []
    for tid in tids:
        with open(f"/proc/{pid}/task/{tid}/stat") as f:
            out.append(int(f.read().rsplit(")", 1)[1].split()[38]))
    return out


def _wait_for(pred, timeout_s: float = 5.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if pred():
            return True
        time.sleep(0.01)
    return False


def _reaped(pid: int) -> bool:
    return not Path(f"/proc/{pid}").exists()


def test_every_topic_round_trips_and_the_file_is_complete(tmp_path: Path) -> None:
    path = tmp_path / "one.mcap"
    sent = []
    with McapProcessLogger(
        path, flush_period_s=0.05, chunk_size=2048, metadata={"machine": "demo"}
    ) as logger:
        assert logger.healthy and logger.files == (path,)
        for i in range(50):
            for topic in TOPIC_SCHEMAS:
                t_ns = T0_NS + (i * len(TOPIC_SCHEMAS) + len(sent) % 9) * 1000
                payload = sample(topic, i)
                assert logger.log(topic, payload, log_time_ns=t_ns)
                sent.append((topic, t_ns, {**payload, "stamp": stamp_from_ns(t_ns)}))
        with pytest.raises(KeyError):
            logger.log("/cmm/nope", {})
    assert logger.stop(1.0) and logger.error is None and not logger.healthy
    st = logger.stats()
    assert (st.enqueued, st.written, st.dropped, st.encode_errors) == (len(sent), len(sent), 0, 0)
    assert st.queue_len == 0 and st.files == (path,)
    assert _reaped(logger.child_pid)  # joined: no zombie left behind

    with open(path, "rb") as f:  # the seeking reader needs the summary: stop() wrote it
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == len(sent) and summary.chunk_indexes
        got = [
            (c.topic, m.log_time, without_log_counters(c.topic, json.loads(m.data)))
            for _, c, m in reader.iter_messages(log_time_order=False)
        ]
    assert got == sent
    for topic, _, payload in got:
        check_message(topic, payload)
    res = read_messages(path)
    assert not res.truncated and res.error is None
    assert [
        (m.topic, m.log_time_ns, without_log_counters(m.topic, m.payload)) for m in res.messages
    ] == sent
    meta = dict(res.metadata)
    assert meta["session"]["pid"] == str(os.getpid())  # the parent's, as with the thread logger
    assert meta["session"]["writer_pid"] == str(logger.child_pid)
    assert meta["session"]["machine"] == "demo"
    assert meta["session_end"]["written"] == str(len(sent))
    assert logger.log("/cmm/raw", sample("/cmm/raw", 0)) is False  # after stop: counted
    assert logger.stats().dropped == 1


def test_rolling_directory_keeps_every_seq_in_order(tmp_path: Path) -> None:
    n = 3000
    with McapProcessLogger(tmp_path, roll_bytes=20_000, chunk_size=4096) as logger:
        for i in range(n):
            logger.log("/cmm/raw", sample("/cmm/raw", i))
    st = logger.stats()
    assert st.written == n and st.dropped == 0 and len(st.files) >= 3
    assert logger.files == st.files and all(p.parent == tmp_path for p in st.files)
    res = read_messages(tmp_path)
    assert res.files == st.files and not res.truncated
    assert [m.payload["seq"] for m in res.messages] == list(range(n))


def test_constructor_errors_raise_in_the_callers_thread(tmp_path: Path) -> None:
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a directory")
    with pytest.raises(NotADirectoryError):
        McapProcessLogger(blocker / "x.mcap")
    existing = tmp_path / "exists.mcap"
    existing.write_bytes(b"keep me")
    with McapProcessLogger(existing) as lg:  # never overwrites, never refuses: rotates
        pass
    assert existing.read_bytes() == b"keep me"
    assert lg.files == (tmp_path / "exists.1.mcap",)
    with pytest.raises(ValueError, match="rolling needs a directory"):
        McapProcessLogger(tmp_path / "one.mcap", roll_s=1.0)
    with pytest.raises(ValueError, match="queue_size"):
        McapProcessLogger(tmp_path / "q.mcap", queue_size=0)


def test_write_failure_and_encode_errors_reach_on_error(tmp_path: Path) -> None:
    seen: list[BaseException] = []
    got_error = threading.Event()

    def on_error(exc: BaseException) -> None:
        seen.append(exc)
        got_error.set()

    target = tmp_path / "logs"
    logger = McapProcessLogger(target, roll_s=0.05, flush_period_s=0.02, on_error=on_error)
    shutil.rmtree(target)  # the next roll cannot create its file
    t_end = time.monotonic() + 5.0
    i = 0
    while not got_error.is_set() and time.monotonic() < t_end:
        logger.log("/cmm/raw", sample("/cmm/raw", i))
        i += 1
        time.sleep(0.002)
    assert got_error.is_set(), "the child's write error never reached on_error"
    assert logger.stop(5.0)
    assert isinstance(seen[0], FileNotFoundError) and logger.error is seen[0]
    assert not logger.healthy
    assert logger.log("/cmm/raw", sample("/cmm/raw", 1)) is False
    st = logger.stats()
    assert st.written + st.dropped == i + 1  # every message is written or counted
    assert _reaped(logger.child_pid)

    seen.clear()
    with McapProcessLogger(tmp_path / "nan.mcap", on_error=seen.append) as lg2:
        lg2.log("/cmm/raw", {"seq": 0, "x_mm": float("nan"), "y_mm": 0.0, "z_mm": 0.0})
        lg2.log("/cmm/raw", sample("/cmm/raw", 1))
    st2 = lg2.stats()
    assert (st2.encode_errors, st2.written, st2.dropped) == (1, 1, 1)
    assert isinstance(seen[0], ValueError) and "not JSON-encodable" in str(seen[0])


def test_hot_path_drops_and_counts_when_the_queue_is_full(tmp_path: Path) -> None:
    """Causality, not a clock: the writer child is stopped (SIGSTOP) while the test logs 20k
    messages; had ``log()`` waited for it even once, the loop could not end before SIGCONT."""
    n = 20_000
    logger = McapProcessLogger(tmp_path / "q.mcap", queue_size=100)
    os.kill(logger.child_pid, signal.SIGSTOP)
    try:
        ok = sum(logger.log("/cmm/raw", sample("/cmm/raw", i)) for i in range(n))
    finally:
        os.kill(logger.child_pid, signal.SIGCONT)
    assert logger.stop(30.0)
    st = logger.stats()
    assert ok < n  # a stopped child takes at most the queue and a socket buffer
    assert st.dropped > 0 and st.enqueued == ok and st.written + st.dropped == n
    res = read_messages(tmp_path / "q.mcap")
    assert len(res.messages) == st.written and not res.truncated
    seqs = [m.payload["seq"] for m in res.messages]
    assert seqs == sorted(seqs)  # drops leave gaps, never reorder


# A parent that logs /cmm/raw at 1 kHz through a McapProcessLogger until it is SIGKILLed.
PARENT = """
import sys, time
from cmm_comp.daemon.sessionlog.process_writer import McapProcessLogger
path, rate = sys.argv[1], float(sys.argv[2])
logger = McapProcessLogger(path, flush_period_s=0.2, chunk_size=16 * 1024 * 1024)
print(logger.child_pid, flush=True)
t0 = time.monotonic()
i = 0
reported = 0
while True:
    logger.log("/cmm/raw", {"seq": i, "x_mm": i * 0.001, "y_mm": 0.0, "z_mm": 0.0})
    i += 1
    written = logger.stats().written  # what the child reported written
    if written != reported:
        print(written, flush=True)
        reported = written
    delay = t0 + i / rate - time.monotonic()
    if delay > 0:
        time.sleep(delay)
"""


def test_child_finishes_the_file_when_the_parent_is_sigkilled(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    rate_hz = 1000
    proc = subprocess.Popen(
        [sys.executable, "-c", PARENT, str(path), str(rate_hz)],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        cwd=ROOT,
    )
    assert proc.stdout is not None
    child_pid = 0
    written = 0
    try:
        line = proc.stdout.readline()
        child_pid = int(line)
        while written < 500:  # the child has written 500 (reported): no clock involved
            line = proc.stdout.readline()
            assert line, "the parent ended before its child wrote 500 messages"
            written = int(line)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(5)
        proc.stdout.close()
        t_end = time.monotonic() + 10.0
        while child_pid and not _gone(child_pid) and time.monotonic() < t_end:
            time.sleep(0.02)
        if child_pid and not _gone(child_pid):
            os.kill(child_pid, signal.SIGKILL)
            pytest.fail("the writer child did not exit after its parent was killed")
    assert proc.returncode == -signal.SIGKILL

    with open(path, "rb") as f:  # complete: the child wrote summary and indexes
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.chunk_indexes and summary.statistics is not None
    res = read_messages(path)
    assert not res.truncated and res.error is None
    seqs = [m.payload["seq"] for m in res.messages]
    assert seqs == list(range(len(seqs))) and len(seqs) >= written
    assert summary.statistics.message_count == len(seqs)
    meta = dict(res.metadata)
    assert meta["session"]["pid"] == str(proc.pid) and meta["session_end"]["dropped"] == "0"


def test_removed_writer_keys_load_with_a_note_or_fail_naming_the_key() -> None:
    """``[mcap] writer`` and ``writer_priority`` were removed (the writer always runs in a child
    process at SCHED_IDLE): a file giving the old default loads and says to delete the line,
    any other value is an error naming the key; the flags are gone."""
    default = config_from_dict({}).mcap
    assert not hasattr(default, "writer") and not hasattr(default, "writer_priority")
    cfg = config_from_dict({"mcap": {"writer": "process", "writer_priority": "idle"}}, "x.toml")
    assert len(cfg.notes) == 2 and all("delete the line" in n for n in cfg.notes)
    assert cfg.notes[0].startswith("x.toml: mcap.writer is no longer a setting")
    with pytest.raises(ConfigError, match=r"x\.toml: mcap\.writer = 'thread' was removed"):
        config_from_dict({"mcap": {"writer": "thread"}}, "x.toml")
    with pytest.raises(ConfigError, match=r"mcap\.writer_priority = 'normal' was removed"):
        config_from_dict({"mcap": {"writer_priority": "normal"}}, "x.toml")
    assert default.compression == "zstd"
    with pytest.raises(ConfigError, match=r"mcap\.compression = 'gzip'; allowed: zstd, lz4, none"):
        config_from_dict({"mcap": {"compression": "gzip"}}, "x.toml")
    ap = argparse.ArgumentParser()
    add_override_flags(ap)
    with pytest.raises(SystemExit):
        ap.parse_args(["--mcap-writer", "thread"])
    assert load_config(None, ap.parse_args(["--mcap-compression", "lz4"])).mcap.compression == "lz4"


def test_daemon_with_the_process_writer_logs_the_session(tmp_path: Path) -> None:
    cfg = base_config(channel())
    cfg.metrics.enabled = False
    cfg.mcap.path = str(tmp_path / "session.mcap")
    cfg.check()
    n = 20
    with DaemonService(cfg, events_stream=None) as d:
        assert isinstance(d.logger, McapProcessLogger)
        if hasattr(os, "SCHED_IDLE"):  # the writer never competes with the reply path
            assert _wait_for(lambda: _thread_policies(d.logger.child_pid).count(5) == 1)
            policies = _thread_policies(d.logger.child_pid)
            assert policies[0] == 0  # the child's main thread (it reads the pipe) stays normal
        bus = can.Bus(interface="virtual", channel=cfg.can.channel)
        try:
            with CanController(bus, answer_timeout_s=2.0) as ctl:
                send_temps(ctl)
                time.sleep(0.05)
                rs = [RawReading(i, (400.0 + i, 500.0, 200.0)) for i in range(n)]
                answers = ctl.stream(rs, 0, in_flight=1)
        finally:
            bus.shutdown()
    assert [a.status for a in answers] == ["ok"] * n
    assert d.logger.stats().dropped == 0 and d.logger.error is None
    assert _reaped(d.logger.child_pid)
    res = read_messages(cfg.mcap.path)
    assert not res.truncated
    topics = {m.topic for m in res.messages}
    assert {"/cmm/raw", "/cmm/corrected", "/cmm/status", "/cmm/can_rx"} <= topics
    corrected = [m.payload for m in res.messages if m.topic == "/cmm/corrected"]
    assert [p["seq"] for p in corrected] == list(range(n))
    # the logged answers are the ones the controller decoded from the bus (to the nm)
    for p, a in zip(corrected, answers, strict=True):
        assert a.corrected_mm is not None and p["status"] == a.status
        assert (p["x_mm"], p["y_mm"], p["z_mm"]) == pytest.approx(a.corrected_mm, abs=1e-9)
    raw = [m.payload for m in res.messages if m.topic == "/cmm/raw"]
    assert [(p["x_mm"], p["y_mm"], p["z_mm"]) for p in raw] == [r.indicated_mm for r in rs]
    for m in res.messages:
        check_message(m.topic, m.payload)
    if hasattr(os, "SCHED_IDLE"):
        assert dict(res.metadata)["session"]["writer_priority"] == "idle"


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_daemon_mcap_compression_setting(tmp_path: Path, compression: str) -> None:
    cfg = base_config(channel())
    cfg.metrics.enabled = False
    cfg.mcap.path = str(tmp_path / "session.mcap")
    cfg.mcap.compression = compression
    cfg.check()
    with DaemonService(cfg, events_stream=None):
        bus = can.Bus(interface="virtual", channel=cfg.can.channel)
        try:
            with CanController(bus, answer_timeout_s=2.0) as ctl:
                send_temps(ctl)
                time.sleep(0.05)
                assert ctl.exchange(RawReading(1, (400.0, 500.0, 200.0))).status == "ok"
        finally:
            bus.shutdown()
    with open(cfg.mcap.path, "rb") as f:  # the chunks say how they are compressed
        chunks = [r for r in make_reader(f).get_summary().chunk_indexes]
    assert chunks and {c.compression for c in chunks} == {"" if compression == "none" else "lz4"}
    res = read_messages(cfg.mcap.path)
    assert [m.payload["seq"] for m in res.messages if m.topic == "/cmm/corrected"] == [1]


def test_the_writer_child_tunes_malloc_to_give_memory_back() -> None:
    """glibc's mallopt accepts the child's settings (fixed mmap threshold, two arenas); run in
    a fresh interpreter so this test process keeps its own malloc settings."""
    code = (
        "import platform\n"
        "from cmm_comp.daemon.sessionlog.process_writer import tune_malloc\n"
        "print(tune_malloc(), platform.libc_ver()[0])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    ).stdout.split()
    assert out[0] == "True" or out[1:] != ["glibc"]
