"""The daemon with ``[live] enabled = true``: a simulated controller on a ``virtual`` CAN bus
gets its answers, and a Foxglove WebSocket client (written from the protocol spec) receives the
same answers on ``/cmm/corrected``, the daemon's status and counters (with the live view's own
exact counters); a live view that cannot listen leaves the daemon running and says why."""

from __future__ import annotations

import io
import json
import logging
import socket
import time
from collections.abc import Iterator

import pytest
from foxglove_ws_client import FoxgloveClient
from test_daemon_support import base_config, channel, daemon_and_controller, send_temps

from cmm_comp.sim_controller.controller import RawReading


@pytest.fixture(autouse=True)
def _quiet_sdk_log() -> Iterator[None]:
    """See tests/test_live.py: the SDK's log records would register its threads as dummies."""
    logger = logging.getLogger("foxglove")
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    yield
    logger.setLevel(level)


def test_the_daemon_streams_its_answers_live() -> None:
    cfg = base_config(channel())
    cfg.live.enabled = True
    cfg.live.port = 0
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
            while (
                len(got.get("/cmm/corrected", [])) < 10 or "/cmm/counters" not in got
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
    assert got["/cmm/status"][0]["state"] in {"starting", "ready"}  # greeted with the latest
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
