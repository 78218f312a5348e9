"""The daemon with ``[live] enabled = true``: a simulated controller on a ``virtual`` CAN bus
gets its answers, and a Foxglove WebSocket client (written from the protocol spec) receives the
same answers on ``/cmm/corrected``, the daemon's status and counters (with the live view's own
exact counters); a live view that cannot listen leaves the daemon running and says why."""

from __future__ import annotations

import io
import json
import socket
import time
from pathlib import Path

import pytest
from foxglove_ws_client import FoxgloveClient
from test_daemon_support import base_config, channel, daemon_and_controller, send_temps

from cmm_comp.cli.sessionlog.reader import read_messages
from cmm_comp.sim_controller.controller import RawReading


def test_the_daemon_streams_its_answers_live() -> None:
    cfg = base_config(channel())
    cfg.live.enabled = True
    cfg.live.port = 0
    cfg.live.max_per_update = 1000  # every answer (decimation: tests/test_live_decimate.py)
    cfg.metrics.period_s = 0.2
    events = io.StringIO()
    with daemon_and_controller(cfg, events_stream=events) as (d, ctl, _bus):
        assert d.live is not None
        topics = ["/cmm/corrected", "/cmm/status", "/cmm/counters"]
        with FoxgloveClient(d.live.url) as client:
            client.wait_for_channels(topics)
            client.subscribe(topics)
            deadline = time.monotonic() + 5.0
            while d.live.stats().subscriptions < 3 and time.monotonic() < deadline:
                client.drain_text(0.01)
            send_temps(ctl)
            time.sleep(0.05)  # the samples are taken before the readings
            answers = [
                ctl.exchange(RawReading(i, (200.0 + 40 * i, 300.0 + 25 * i, 150.0)))
                for i in range(10)
            ]
            got: dict[str, list[dict]] = {}
            deadline = time.monotonic() + 10.0

            def watched() -> bool:  # a counters record made once the client was counted
                c = got.get("/cmm/counters", [])
                return bool(c) and c[-1]["counters"].get("live_clients") == 1

            # (the view's counters reach the daemon ≤ 0.1 s late: an earlier record says 0)
            while (
                len(got.get("/cmm/corrected", [])) < 10 or not watched()
            ) and time.monotonic() < deadline:
                for m in client.receive(1):
                    got.setdefault(m.topic, []).append(m.json())
    assert {a.status for a in answers} == {"ok"}
    live = {c["seq"]: c for c in got["/cmm/corrected"]}
    for a in answers:
        c = live[a.seq]
        assert c["status"] == a.status
        assert a.corrected_mm is not None
        for axis, v in zip("xyz", a.corrected_mm, strict=True):
            assert c[f"{axis}_mm"] == pytest.approx(v, abs=1e-6)  # the frame carries nm
    # greeted with the latest (degraded: no temperature sample yet when it subscribed)
    assert got["/cmm/status"][0]["state"] in {"starting", "ready", "degraded"}
    counters = got["/cmm/counters"][-1]["counters"]
    assert {"live_sent", "live_dropped", "live_not_encoded", "live_clients"} <= set(counters)
    assert counters["live_dropped"] == 0 and counters["live_clients"] == 1
    lines = [json.loads(line) for line in events.getvalue().splitlines()]
    assert any(e.get("event") == "live_listening" for e in lines), lines[:5]


def test_a_live_view_that_cannot_listen_leaves_the_daemon_running() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        cfg = base_config(channel())
        cfg.live.enabled = True
        cfg.live.port = busy.getsockname()[1]
        events = io.StringIO()
        with daemon_and_controller(cfg, events_stream=events) as (d, ctl, _bus):
            assert d.live is None
            send_temps(ctl)
            time.sleep(0.05)
            assert ctl.exchange(RawReading(1, (300.0, 400.0, 150.0))).status == "ok"
    lines = [json.loads(line) for line in events.getvalue().splitlines()]
    errors = [e for e in lines if e.get("event") == "live_error"]
    assert len(errors) == 1 and "cannot listen on 127.0.0.1" in errors[0]["error"]


def test_a_stopped_or_killed_live_process_never_stalls_the_answers(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """With a client watching every answer, SIGSTOP and then SIGKILL the live view's process
    while the controller keeps asking: every reading is answered ``ok`` throughout, the stall
    and the death are events (``live_error``) and ``/cmm/status`` lines (the daemon's state
    unchanged), and the counters say ``live_up`` 0."""
    import os
    import signal

    from cmm_comp.daemon.live import process

    monkeypatch.setattr(process, "STALL_S", 0.5)
    cfg = base_config(channel())
    cfg.live.enabled = True
    cfg.live.port = 0
    cfg.metrics.period_s = 0.1  # the housekeeping asks for the counters: that checks the child
    cfg.mcap.path = str(tmp_path / "run.mcap")
    events = io.StringIO()

    next_seq = [0]

    def ask(n: int) -> list[str]:
        """``n`` readings, one after the other (fresh seqs), their answers' statuses."""
        first = next_seq[0]
        next_seq[0] += n
        return [
            ctl.exchange(RawReading(i & 0xFFFF, (200.0 + i % 500, 300.0, 150.0))).status
            for i in range(first, first + n)
        ]

    def live_errors() -> list[str]:
        lines = [json.loads(line) for line in events.getvalue().splitlines()]
        return [e["error"] for e in lines if e.get("event") == "live_error"]

    with daemon_and_controller(cfg, events_stream=events) as (d, ctl, _bus):
        assert d.live is not None
        pid = d.live.child_pid
        assert pid is not None
        with FoxgloveClient(d.live.url) as client:
            client.wait_for_channels(["/cmm/corrected"])
            client.subscribe(["/cmm/corrected"])
            send_temps(ctl)
            time.sleep(0.05)
            assert set(ask(20)) == {"ok"}
            os.kill(pid, signal.SIGSTOP)
            try:
                statuses = ask(400)  # ~1 s with the child stopped: the stall is noticed
                deadline = time.monotonic() + 10.0
                while d.live.counters()["live_up"] and time.monotonic() < deadline:
                    statuses += ask(20)
                assert d.live.counters()["live_up"] == 0
                assert any("has not run" in e for e in live_errors()), live_errors()
            finally:
                os.kill(pid, signal.SIGKILL)
            statuses += ask(200)
            deadline = time.monotonic() + 10.0
            # counted at once (the event lines of one kind are rate-limited: 20/s)
            while d.metrics.snapshot()["counters"].get("live_errors", 0) < 2:
                assert time.monotonic() < deadline, (live_errors(), d.live.child_pid)
                statuses += ask(10)
        assert set(statuses) == {"ok"}  # every reading answered, none timed out
        assert d.live.counters()["live_up"] == 0
        assert d.metrics.snapshot()["counters"]["live_errors"] >= 2
        assert not [c for c in d.state.conditions() if "live" in c]  # not a daemon condition
    status = [m.payload for m in read_messages(cfg.mcap.path, ["/cmm/status"]).messages]
    lines = [st for st in status if st["detail"].startswith("live view: its process")]
    assert any("has not run" in st["detail"] for st in lines), status
    assert any("process ended" in st["detail"] for st in lines), status
    counters = [m.payload for m in read_messages(cfg.mcap.path, ["/cmm/counters"]).messages]
    assert counters[-1]["counters"]["live_up"] == 0
