""":class:`LiveProcessSink`: the live view's server and encoding in a child process. The same
spec-written client checks what arrives; the daemon-side counters stay exact when the child is
stopped (SIGSTOP: the shared ring fills, the daemon drops what does not fit, never waits; the
stall is reported), killed (reported, the daemon goes on) or cannot listen (one line, nothing
left running)."""

from __future__ import annotations

import logging
import os
import signal
import socket
import time
from typing import Any

import pytest
from foxglove_ws_client import protobuf_class
from test_live import T0_NS, connect, corr_rec, raw_rec, stamp, wait_until

from cmm_comp.daemon.live import (
    SCENE_TOPIC,
    LiveChildError,
    LiveProcessSink,
    LiveSection,
    LiveStartError,
)


def settings(**kw: Any) -> LiveSection:
    base = {"enabled": True, "port": 0, "scene_rate_hz": 1000.0, "max_per_update": 100_000}
    return LiveSection(**{**base, **kw})


def test_messages_and_scene_arrive_through_the_child() -> None:
    errors: list[BaseException] = []
    with LiveProcessSink(settings(), on_error=errors.append).start() as sink:
        assert sink.child_pid is not None and sink.child_pid != os.getpid()
        with connect(sink, ["/cmm/raw", "/cmm/corrected", SCENE_TOPIC]) as client:
            wait_until(lambda: "/cmm/corrected" in sink.wanted_topics, "the child's wanted set")
            sink.log_many("/cmm/raw", [raw_rec(1, 10.5, 20.25, 30.0)], T0_NS)
            sink.log_many(
                "/cmm/corrected", [corr_rec(1, (10_503_000, 20_250_000, 30_000_000), "ok", (3.0, 0.0, 0.0))], T0_NS
            )  # fmt: skip
            sink.log("/cmm/temperature", {"sensor": "0", "role": "T_x", "temp_C": 20.0}, T0_NS)
            got = {m.topic: m for m in client.receive(3)}
            update = protobuf_class(client.channels[SCENE_TOPIC]).FromString(
                got[SCENE_TOPIC].payload
            )
    raw = got["/cmm/raw"].json()
    assert (raw["seq"], raw["x_mm"], raw["stamp"]) == (1, 10.5, stamp(T0_NS))
    assert got["/cmm/corrected"].json()["dx_um"] == 3.0
    arrow = next(e for e in update.entities if e.arrows).arrows[0]
    assert arrow.pose.position.x == pytest.approx(0.0105, abs=1e-12)  # (10.503 − 0.003) mm
    s = sink.stats()
    # nobody watched /cmm/temperature: dropped in the daemon, never sent to the child
    assert (s.offered, s.sent, s.not_encoded, s.dropped, s.queue_len) == (3, 2, 1, 0, 0)
    assert s.scene_updates == 1 and errors == []


def test_nothing_leaves_the_daemon_without_a_subscriber() -> None:
    with LiveProcessSink(settings()).start() as sink:
        sink.log_many("/cmm/raw", [raw_rec(i, 0.0, 0.0, 0.0) for i in range(1000)], T0_NS)
        time.sleep(0.05)  # the forwarder's poll runs a few times
        assert sink._forwarded == 0  # nothing pickled, nothing sent to the child
    s = sink.stats()
    assert (s.offered, s.not_encoded, s.sent) == (1000, 1000, 0)


def test_the_child_decimates_and_never_loses_a_bad_answer() -> None:
    """1000 answers 1 ms apart (log time), one not ok (seq 505); ``max_per_update = 4``: the
    daemon hands every watched batch over (one gate, the child's); the child sends at most 4
    ok answers per update plus the ones not ok, so the bad answer always arrives, and every
    message offered is accounted for exactly once."""
    with (
        LiveProcessSink(settings(update_rate_hz=30.0, max_per_update=4)).start() as sink,
        connect(sink, ["/cmm/corrected"]) as client,
    ):
        wait_until(lambda: "/cmm/corrected" in sink.wanted_topics, "the child's wanted set")
        for k in range(1000):
            status = "outside_volume" if k == 505 else "ok"
            rec = corr_rec(k, (1, 2, 3), status, (0.5, 0.0, 0.0))
            sink.log_many("/cmm/corrected", [rec], T0_NS + k * 10**6)
        assert sink._forwarded == 1000
        seen: set[int] = set()
        while 505 not in seen:  # the bad answer is never decimated away
            seen.update(m.json()["seq"] for m in client.receive(1))
    s = sink.stats()
    assert s.offered == 1000 == s.decimated + s.sent + s.not_encoded + s.dropped
    assert s.sent >= len(seen)


def test_a_stopped_child_is_reported_down_and_nothing_waits_for_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SIGSTOP the child: the shared ring fills and the daemon drops what does not fit
    (counted exactly, never blocking); the stall is reported once, ``up`` turns False and
    nothing more is copied; after SIGCONT it runs again (reported) and the newest arrives."""
    from cmm_comp.daemon.live import process

    monkeypatch.setattr(process, "STALL_S", 0.3)
    errors: list[BaseException] = []
    with LiveProcessSink(settings(queue=10), on_error=errors.append).start() as sink:
        pid = sink.child_pid
        assert pid is not None
        with connect(sink, ["/cmm/raw"]) as client:
            wait_until(lambda: "/cmm/raw" in sink.wanted_topics, "the child's wanted set")
            os.kill(pid, signal.SIGSTOP)
            try:
                seq, slowest = 0, 0.0
                while sink.stats().dropped == 0:  # until the ring (64 KiB) is full
                    batch = [raw_rec(seq + i, 1.0, 2.0, 3.0) for i in range(50)]
                    t0 = time.perf_counter()
                    assert sink.log_many("/cmm/raw", batch, T0_NS + seq * 10**6) == 50
                    slowest = max(slowest, time.perf_counter() - t0)
                    seq += 50
                    assert seq < 1_000_000, "the ring never filled"
                full = sink.stats()
                wait_until(lambda: not sink.stats().up, "the stall noticed", 10.0)
                assert isinstance(errors[0], LiveChildError) and "has not run" in str(errors[0])
                sink.log_many("/cmm/raw", [raw_rec(seq, 1.0, 2.0, 3.0)], T0_NS + seq)
                seq += 1
                down = sink.stats()
                assert down.counters()["live_up"] == 0
                assert down.not_encoded == full.not_encoded + 1  # not even pickled while down
            finally:
                os.kill(pid, signal.SIGCONT)
            wait_until(lambda: sink.stats().up, "the child running again", 20.0)
            assert "runs again" in str(errors[-1])
            last = seq
            sink.log_many("/cmm/raw", [raw_rec(last, 1.0, 2.0, 3.0)], T0_NS + last)
            seq += 1
            seen: set[int] = set()
            while last not in seen:
                seen.update(m.json()["seq"] for m in client.receive(1, timeout_s=20.0))
    s = sink.stats()
    assert slowest < 0.05  # never waited for the stopped child
    assert full.dropped > 0 and full.dropped == full.dropped_by_topic["/cmm/raw"]
    assert s.queue_len == 0
    assert s.offered == seq == s.not_encoded + s.decimated + s.dropped + s.sent + s.encode_errors


def test_a_killed_child_is_reported_and_the_daemon_goes_on() -> None:
    errors: list[BaseException] = []
    sink = LiveProcessSink(settings(), on_error=errors.append).start()
    try:
        pid = sink.child_pid
        assert pid is not None
        client = connect(sink, ["/cmm/raw"])
        client.close()
        os.kill(pid, signal.SIGKILL)
        wait_until(lambda: not sink.stats().up, "the death noticed")
        assert isinstance(errors[0], LiveChildError) and "process ended" in str(errors[0])
        assert sink.log_many("/cmm/raw", [raw_rec(1, 0.0, 0.0, 0.0)], T0_NS) == 1
        assert sink.counters()["live_up"] == 0
    finally:
        t0 = time.monotonic()
        sink.stop(2.0)
        assert time.monotonic() - t0 < 3.0
    s = sink.stats()
    assert s.offered == s.not_encoded + s.decimated + s.dropped + s.sent + s.encode_errors
    assert s.queue_len == 0 and len(errors) == 1


def test_a_busy_port_is_one_clear_error_from_the_child() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        sink = LiveProcessSink(settings(port=port))
        before = set(_children())
        with pytest.raises(LiveStartError, match=rf"cannot listen on 127\.0\.0\.1:{port}") as err:
            sink.start()
        assert "\n" not in str(err.value)
        assert sink.child_pid is None and set(_children()) <= before  # reaped


def _children() -> list[int]:
    """Process ids of this process's children (/proc/self/task/*/children)."""
    out: list[int] = []
    for task in os.listdir("/proc/self/task"):
        with open(f"/proc/self/task/{task}/children") as f:
            out += [int(p) for p in f.read().split()]
    return out


def test_unpicklable_payloads_are_counted_not_sent() -> None:
    errors: list[BaseException] = []
    with (
        LiveProcessSink(settings(), on_error=errors.append).start() as sink,
        connect(sink, ["/cmm/counters"]) as client,
    ):
        wait_until(lambda: "/cmm/counters" in sink.wanted_topics, "the child's wanted set")
        sink.log("/cmm/counters", {"counters": {"a": 1}, "f": lambda: 0}, T0_NS)
        sink.log("/cmm/counters", {"counters": {"a": 2}}, T0_NS + 1)
        (m,) = client.receive(1)
    assert m.json()["counters"] == {"a": 2}
    assert sink.stats().encode_errors == 1 and "/cmm/counters" in str(errors[0])


def test_the_childs_sdk_log_is_rate_limited(monkeypatch: pytest.MonkeyPatch) -> None:
    """A vanished client makes the SDK log an error per message: the child passes one line a
    second and says how many it held back."""
    from cmm_comp.daemon.live import child

    now = [100.0]
    monkeypatch.setattr(child.time, "monotonic", lambda: now[0])
    limit = child.RateLimit(per_s=1.0)

    def record(i: int) -> logging.LogRecord:
        return logging.LogRecord("foxglove", logging.ERROR, "x", 1, "broken pipe %d", (i,), None)

    passed = [r for r in map(record, range(500)) if limit.filter(r)]
    assert len(passed) == 1 and passed[0].getMessage() == "broken pipe 0"
    now[0] += 1.0
    r = record(500)
    assert limit.filter(r) and r.getMessage() == "broken pipe 500 (499 similar lines suppressed)"
