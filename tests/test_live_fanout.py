"""The live view fed by the daemon's real correction engine through :class:`LiveFanOut`: what a
Foxglove client receives equals the engine's answers (read from the Answer objects) and, message
for message, what the MCAP session log wrote in the same run (payload and log time)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from foxglove_ws_client import FoxgloveClient, protobuf_class
from test_daemon_support import base_config, channel

from cmm_comp.cli.sessionlog.reader import read_messages
from cmm_comp.daemon.engine import CorrectionEngine, Reading
from cmm_comp.daemon.live import SCENE_TOPIC, LiveFanOut, LiveProcessSink, LiveSection
from cmm_comp.daemon.service import DaemonService
from cmm_comp.daemon.sessionlog.writer import SessionWriter

NOW_S = 1000.0


@pytest.fixture(scope="module")
def engine() -> Iterator[CorrectionEngine]:
    """The engine of a daemon (Modbus side only, no MCAP), temperatures set at NOW_S."""
    cfg = base_config(channel())
    cfg.can.enabled = False
    cfg.modbus.enabled = True
    cfg.modbus.port = 0
    cfg.metrics.enabled = False
    with DaemonService(cfg, events_stream=None) as d:
        assert d.engine is not None
        for sensor, temp in enumerate((20.7, 21.1, 19.6, 20.3)):
            d.temperatures.update(sensor, temp, 1, True, NOW_S)
        yield d.engine


def test_live_equals_the_engine_and_the_mcap_log(engine: CorrectionEngine, tmp_path: Path) -> None:
    readings = [
        Reading(i, (100_000_000 + 60_000_000 * i, 150_000_000 + 70_000_000 * i, 350_000_000))
        for i in range(12)
    ]
    readings.append(Reading(12, (5_000_000_000, 0, 0)))  # far outside: outside_volume
    answers = engine.correct_many(readings, NOW_S)
    assert {a.status.label for a in answers} == {"ok", "outside_volume"}
    path = tmp_path / "s.mcap"
    live = LiveProcessSink(
        LiveSection(enabled=True, port=0, scene_max_new_arrows=64, max_per_update=100_000)
    ).start()
    fan = LiveFanOut(SessionWriter(path), live)
    saved, engine.logger = engine.logger, fan
    try:
        with FoxgloveClient(live.url) as client:
            topics = ["/cmm/raw", "/cmm/corrected", SCENE_TOPIC]
            client.wait_for_channels(topics)
            client.subscribe(topics)
            while live.stats().subscriptions < 3:
                client.drain_text(0.001)
            engine.report_many(
                [(r, a, 40.0 + r.seq) for r, a in zip(readings, answers, strict=True)]
            )
            fan.kick()
            msgs = client.receive(2 * len(readings) + 1)
            scene_cls = protobuf_class(client.channels[SCENE_TOPIC])
    finally:
        engine.logger = saved
        assert fan.stop(5.0)
    got = {(m.topic, m.json()["seq"]): m for m in msgs if m.topic != SCENE_TOPIC}
    for r, a in zip(readings, answers, strict=True):
        c = got["/cmm/corrected", r.seq].json()
        assert c["status"] == a.status.label
        assert (c["dx_um"], c["dy_um"], c["dz_um"]) == a.correction_um
        for axis, nm in zip("xyz", a.position_nm, strict=True):
            assert c[f"{axis}_mm"] == pytest.approx(nm / 1e6, abs=1e-12)
        raw = got["/cmm/raw", r.seq].json()
        for axis, nm in zip("xyz", r.position_nm, strict=True):
            assert raw[f"{axis}_mm"] == pytest.approx(nm / 1e6, abs=1e-12)
    logged = read_messages(path, topics=["/cmm/raw", "/cmm/corrected"])
    assert not logged.truncated and len(logged.messages) == 2 * len(readings)
    for m in logged.messages:
        live_msg = got[m.topic, m.payload["seq"]]
        assert live_msg.json() == m.payload  # the same object as the file
        assert live_msg.log_time_ns == m.log_time_ns
    (scene_msg,) = [m for m in msgs if m.topic == SCENE_TOPIC]
    update = scene_cls.FromString(scene_msg.payload)
    arrows = [e for e in update.entities if e.arrows]
    cubes = [e for e in update.entities if e.cubes]
    assert (len(arrows), len(cubes)) == (12, 1)  # 12 corrected, 1 outside the volume
    s = live.stats()
    assert (s.sent, s.dropped, s.encode_errors, s.scene_points) == (26, 0, 0, 13)


def test_fanout_without_an_mcap_log() -> None:
    live = LiveProcessSink(LiveSection(enabled=True, port=0)).start()
    fan = LiveFanOut(None, live)
    with fan:
        assert fan.log("/cmm/status", {"state": "ready", "detail": "", "grid_sha256": ""})
        assert (
            fan.log_many(
                "/cmm/raw", [(1, 0.0, 0.0, 0.0, (0, 0, 0), (True,) * 3, "c", (0, 0, 0), None)]
            )
            == 1
        )
        fan.kick()
        assert fan.healthy and fan.error is None and fan.files == ()
        assert fan.stats().written == 0
    assert live.stats().offered == 2 and live.stats().not_encoded == 2
