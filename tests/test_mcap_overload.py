"""Overload: records are dropped by the documented policy (frames before answers) with exact
per-topic counts, in ``stats()``, in the file's ``/cmm/counters`` and ``session_end``.

Oracle: what the test logged (it knows every answer it gave) against what the ``mcap``
package's reader finds in the file plus what the file itself says it dropped."""

from __future__ import annotations

import contextlib
import json
import os
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from cmm_comp.daemon.sessionlog.process_writer import McapProcessLogger
from cmm_comp.daemon.sessionlog.writer import SessionWriter

FRAME = (0x181, False, 8, bytes(8), 1_700_000_000.5, "vcan0", False, False, False)
RAW = (0, 1.0, 2.0, 3.0, (1, 1, 1), (True, True, True), "can", (0.0, 0.0, 0.0), None)
T0_NS = 1_700_000_000_000_000_000


def _corrected(seq: int) -> tuple[Any, ...]:
    return (seq, 1, 2, 3, "ok", (0.0, 0.0, 0.0), 50.0, 1, "can", "")


def _flood(lg: Any, n: int) -> dict[str, int]:
    """Log ``n`` readings the way the CAN endpoint does (3 frames in, raw, 4 frames out,
    corrected; a counters record every 500), unpaced; returns what was logged per topic."""
    logged: dict[str, int] = {}

    def log(topic: str, payload: Any, t_ns: int) -> None:
        lg.log(topic, payload, t_ns)
        logged[topic] = logged.get(topic, 0) + 1

    for i in range(n):
        t = T0_NS + i * 1000
        for _ in range(3):
            log("/cmm/can_rx", FRAME, t)
        log("/cmm/raw", (i, *RAW[1:]), t)
        for _ in range(4):
            log("/cmm/can_tx", FRAME, t)
        log("/cmm/corrected", _corrected(i), t)
        if i % 500 == 499:
            log("/cmm/counters", {"counters": {"readings": i + 1}}, t)
    return logged


def _check_accounts(path: Path, logged: dict[str, int], st: Any) -> dict[str, int]:
    """Every logged message is in the file or counted as dropped, per topic, exactly; in
    stats() and in the file's own session_end. Returns the file's drops per topic."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        in_file: dict[str, int] = {}
        seqs: list[int] = []
        counters: list[dict[str, int]] = []
        for _, channel, msg in reader.iter_messages(log_time_order=False):
            in_file[channel.topic] = in_file.get(channel.topic, 0) + 1
            if channel.topic == "/cmm/corrected":
                seqs.append(json.loads(msg.data)["seq"])
            elif channel.topic == "/cmm/counters":
                counters.append(json.loads(msg.data)["counters"])
        f.seek(0)
        end = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["session_end"]
    file_dropped = json.loads(end["dropped_by_topic"])
    for topic, n in logged.items():
        assert in_file.get(topic, 0) + file_dropped.get(topic, 0) == n, topic
        assert in_file.get(topic, 0) + st.dropped_by_topic.get(topic, 0) == n, topic
    assert int(end["dropped"]) == st.dropped == sum(file_dropped.values())
    assert seqs == sorted(seqs)  # drops leave gaps, never reorder
    for c in counters:  # the counters records carry the log's own per-topic drops
        assert c["mcap_dropped"] == sum(v for k, v in c.items() if k.startswith("mcap_dropped_"))
    return file_dropped


def test_process_writer_flood_counts_parent_and_child_drops_in_the_file(tmp_path: Path) -> None:
    path = tmp_path / "flood.mcap"
    n = 6000
    lg = McapProcessLogger(path, queue_size=64, chunk_size=4096)
    logged = _flood(lg, n)
    assert lg.stop(30.0)
    st = lg.stats()
    dropped = _check_accounts(path, logged, st)
    assert st.dropped > 0 and sum(dropped.values()) == st.dropped


def _wait_stopped(pid: int, timeout_s: float = 30.0) -> None:
    """Until process ``pid`` is stopped (state ``T`` in /proc/PID/stat)."""
    import time

    stat = Path(f"/proc/{pid}/stat")
    deadline = time.monotonic() + timeout_s
    while stat.read_text().rsplit(")", 1)[1].split()[0] != "T":
        assert time.monotonic() < deadline, f"process {pid} did not stop on SIGSTOP"
        time.sleep(0.001)


@contextlib.contextmanager
def _held(lg: McapProcessLogger) -> Iterator[None]:
    """The writer child stopped (SIGSTOP, as a starved writer would be) while inside.

    ``kill`` returns once the signal is sent, not once the child has stopped: a child running
    on the other core keeps draining the ring until it takes the signal (seen on a loaded
    2-core machine: a frame refused, a later one taken). So the block starts only when the
    child's state is ``T`` (stopped) in /proc."""
    os.kill(lg.child_pid, signal.SIGSTOP)
    _wait_stopped(lg.child_pid)
    try:
        yield
    finally:
        os.kill(lg.child_pid, signal.SIGCONT)


def test_policy_frames_take_half_the_ring_answers_all_of_it(tmp_path: Path) -> None:
    """The policy itself, without a race: the child is held, so frames are refused once the
    ring is half full, answers are still taken until it is full; every refusal is counted."""
    path = tmp_path / "q.mcap"
    lg = McapProcessLogger(path, queue_size=64)
    with _held(lg):
        frames = [lg.log("/cmm/can_rx", FRAME, T0_NS + i) for i in range(2000)]
        answers = [lg.log("/cmm/corrected", _corrected(i), T0_NS + i) for i in range(2000)]
    assert lg.stop(10.0)
    k, m = sum(frames), sum(answers)
    assert frames == [True] * k + [False] * (2000 - k) and 0 < k < 2000
    assert answers == [True] * m + [False] * (2000 - m) and 0 < m < 2000
    logged = {"/cmm/can_rx": 2000, "/cmm/corrected": 2000}
    st = lg.stats()
    assert st.dropped_by_topic == {"/cmm/can_rx": 2000 - k, "/cmm/corrected": 2000 - m}
    assert st.written_by_topic == {"/cmm/can_rx": k, "/cmm/corrected": m}
    _check_accounts(path, logged, st)


def _flood_batched(lg: Any, n: int, batch: int = 16) -> dict[str, int]:
    """As :func:`_flood`, with one ``log_many`` per topic per ``batch`` readings (what the CAN
    endpoint does per wake-up)."""
    logged: dict[str, int] = {}

    def log_many(topic: str, payloads: list[Any], t_ns: int) -> None:
        lg.log_many(topic, payloads, t_ns)
        logged[topic] = logged.get(topic, 0) + len(payloads)

    for start in range(0, n, batch):
        seqs = range(start, min(n, start + batch))
        t = T0_NS + start * 1000
        log_many("/cmm/can_rx", [FRAME] * (3 * len(seqs)), t)
        log_many("/cmm/can_tx", [FRAME] * (4 * len(seqs)), t)
        log_many("/cmm/raw", [(i, *RAW[1:]) for i in seqs], t)
        log_many("/cmm/corrected", [_corrected(i) for i in seqs], t)
    return logged


def test_log_many_flood_counts_exactly(tmp_path: Path) -> None:
    path = tmp_path / "p.mcap"
    lg = McapProcessLogger(path, queue_size=64, chunk_size=4096)
    logged = _flood_batched(lg, 4000)
    assert lg.stop(30.0)
    st = lg.stats()
    dropped = _check_accounts(path, logged, st)
    assert st.dropped > 0 and sum(dropped.values()) == st.dropped


def test_log_many_takes_a_batch_whole_or_not_at_all(tmp_path: Path) -> None:
    """A held child: batches of frames are refused once the ring is half full, batches of
    answers still taken after that; a batch is never cut; drops are counted per message."""
    path = tmp_path / "q.mcap"
    lg = McapProcessLogger(path, queue_size=64)
    with _held(lg):
        frames = [lg.log_many("/cmm/can_rx", [FRAME] * 8, T0_NS) for _ in range(500)]
        answers = [
            lg.log_many("/cmm/corrected", [_corrected(8 * i + j) for j in range(8)], T0_NS + 1)
            for i in range(500)
        ]
        assert lg.log_many("/cmm/corrected", [], T0_NS + 2) == 0
    assert lg.stop(10.0)
    assert lg.log_many("/cmm/raw", [RAW], T0_NS + 3) == 0  # after stop: dropped, counted
    assert set(frames) == {0, 8} and set(answers) == {0, 8}
    k, m = frames.count(8), answers.count(8)
    assert frames == [8] * k + [0] * (500 - k) and answers == [8] * m + [0] * (500 - m)
    st = lg.stats()
    assert st.dropped_by_topic == {
        "/cmm/can_rx": 8 * (500 - k), "/cmm/corrected": 8 * (500 - m), "/cmm/raw": 1
    }  # fmt: skip
    assert st.written_by_topic == {"/cmm/can_rx": 8 * k, "/cmm/corrected": 8 * m}
    with open(path, "rb") as f:
        seqs = [
            json.loads(msg.data)["seq"]
            for _, ch, msg in make_reader(f).iter_messages()
            if ch.topic == "/cmm/corrected"
        ]
    assert seqs == list(range(8 * m))


def test_message_of_an_unknown_topic_from_the_ring_becomes_an_error_record(
    tmp_path: Path,
) -> None:
    lg = SessionWriter(tmp_path / "u.mcap")
    lg.write("/cmm/nope", {"a": 1}, T0_NS)
    lg.write("/cmm/raw", RAW, T0_NS + 1)
    assert lg.stop(10.0)
    st = lg.stats()
    assert st.encode_errors_by_topic == {"/cmm/nope": 1}
    assert st.written_by_topic == {"/cmm/raw": 1, "/cmm/log_error": 1}
