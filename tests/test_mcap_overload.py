"""Overload: records are dropped by the documented policy (frames before answers) with exact
per-topic counts, in ``stats()``, in the file's ``/cmm/counters`` and ``session_end``.

Oracle: what the test logged (it knows every answer it gave) against what the ``mcap``
package's reader finds in the file plus what the file itself says it dropped."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from test_mcap_log import SlowStream

from cmm_comp.daemon.sessionlog.logger import LOW_PRIORITY_TOPICS
from cmm_comp.daemon.sessionlog.process_writer import McapProcessLogger
from cmm_comp.daemon.sessionlog.thread_writer import McapLogger

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


def test_thread_writer_slow_sink_flood_drops_frames_first_and_counts_exactly(
    tmp_path: Path,
) -> None:
    path = tmp_path / "slow.mcap"
    n = 4000
    lg = McapLogger(
        path,
        queue_size=400,
        chunk_size=4096,
        flush_period_s=0.02,
        opener=lambda p: SlowStream(p, delay_s=0.002),
    )
    logged = _flood(lg, n)
    assert lg.stop(30.0)
    st = lg.stats()
    dropped = _check_accounts(path, logged, st)
    frames_lost = sum(dropped.get(t, 0) for t in LOW_PRIORITY_TOPICS) / (7 * n)
    answers_lost = dropped.get("/cmm/corrected", 0) / n
    assert frames_lost > 0.1  # the flood did overload the writer...
    assert answers_lost < frames_lost  # ...and frames went first


def test_process_writer_flood_counts_parent_and_child_drops_in_the_file(tmp_path: Path) -> None:
    path = tmp_path / "flood.mcap"
    n = 6000
    lg = McapProcessLogger(path, queue_size=64, chunk_size=4096)
    logged = _flood(lg, n)
    assert lg.stop(30.0)
    st = lg.stats()
    dropped = _check_accounts(path, logged, st)
    assert st.dropped > 0 and sum(dropped.values()) == st.dropped


def test_policy_frames_take_half_the_queue_answers_all_of_it(tmp_path: Path) -> None:
    """The policy itself, without a race: the writer thread is held (as a starved writer
    would be), so a queue of 10 takes 5 frames, then only answers, up to 10."""
    release = threading.Event()
    lg = McapLogger(tmp_path / "q.mcap", queue_size=10, writer_setup=release.wait)
    frames = [lg.log("/cmm/can_rx", FRAME, T0_NS + i) for i in range(8)]
    answers = [lg.log("/cmm/corrected", _corrected(i), T0_NS + 100 + i) for i in range(8)]
    release.set()
    assert lg.stop(10.0)
    assert frames == [True] * 5 + [False] * 3
    assert answers == [True] * 5 + [False] * 3
    st = lg.stats()
    assert st.dropped_by_topic == {"/cmm/can_rx": 3, "/cmm/corrected": 3}
    assert st.written_by_topic == {"/cmm/can_rx": 5, "/cmm/corrected": 5}


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


def test_log_many_flood_counts_exactly_for_both_writers(tmp_path: Path) -> None:
    slow = McapLogger(
        tmp_path / "t.mcap",
        queue_size=400,
        chunk_size=4096,
        flush_period_s=0.02,
        opener=lambda p: SlowStream(p, delay_s=0.002),
    )
    proc = McapProcessLogger(tmp_path / "p.mcap", queue_size=64, chunk_size=4096)
    for lg, path in ((slow, tmp_path / "t.mcap"), (proc, tmp_path / "p.mcap")):
        logged = _flood_batched(lg, 4000)
        assert lg.stop(30.0)
        st = lg.stats()
        dropped = _check_accounts(path, logged, st)
        assert st.dropped > 0 and sum(dropped.values()) == st.dropped


def test_log_many_takes_what_log_would_take(tmp_path: Path) -> None:
    """The policy of :func:`test_policy_frames_take_half_the_queue_answers_all_of_it`, batched:
    a held writer, a queue of 10: 8 frames → the first 5, 8 answers → the first 5."""
    release = threading.Event()
    lg = McapLogger(tmp_path / "q.mcap", queue_size=10, writer_setup=release.wait)
    assert lg.log_many("/cmm/can_rx", [FRAME] * 8, T0_NS) == 5
    assert lg.log_many("/cmm/corrected", [_corrected(i) for i in range(8)], T0_NS + 1) == 5
    assert lg.log_many("/cmm/corrected", [], T0_NS + 2) == 0
    release.set()
    assert lg.stop(10.0)
    assert lg.log_many("/cmm/raw", [RAW], T0_NS + 3) == 0  # after stop: dropped, counted
    st = lg.stats()
    assert st.dropped_by_topic == {"/cmm/can_rx": 3, "/cmm/corrected": 3, "/cmm/raw": 1}
    assert st.written_by_topic == {"/cmm/can_rx": 5, "/cmm/corrected": 5}
    with open(tmp_path / "q.mcap", "rb") as f:
        seqs = [
            json.loads(m.data)["seq"]
            for _, ch, m in make_reader(f).iter_messages()
            if ch.topic == "/cmm/corrected"
        ]
    assert seqs == [0, 1, 2, 3, 4]


def test_enqueued_message_of_an_unknown_topic_becomes_an_error_record(tmp_path: Path) -> None:
    lg = McapLogger(tmp_path / "u.mcap")
    lg.enqueue([("/cmm/nope", {"a": 1}, T0_NS), ("/cmm/raw", RAW, T0_NS + 1)])
    assert lg.stop(10.0)
    st = lg.stats()
    assert st.encode_errors_by_topic == {"/cmm/nope": 1}
    assert st.written_by_topic == {"/cmm/raw": 1, "/cmm/log_error": 1}
