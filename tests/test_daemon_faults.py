"""Daemon on a python-can ``virtual`` bus, in process: every fault case answers with a status
that says the point is not (fully) corrected, and the daemon keeps serving."""

from __future__ import annotations

import json
import time
import urllib.request

import can
import pytest
from test_daemon_support import (
    CENTRE_MM,
    base_config,
    channel,
    daemon_and_controller,
    npl_grid_path,
    send_temps,
)

from cmm_comp.daemon.config import DaemonConfig
from cmm_comp.protocol import CanIds, RawAxis, encode_message
from cmm_comp.protocol.codes import Applied, Axis, DaemonState, grid_id_from_sha256
from cmm_comp.sim_controller.controller import RawReading

IDS = CanIds()


def _reading(seq: int, pos=CENTRE_MM, **kw) -> RawReading:
    return RawReading(seq, pos, **kw)


def _wait(pred, timeout_s: float = 10.0) -> bool:
    """Poll ``pred`` until true (generous timeout: only a failing test waits that long)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if pred():
            return True
        time.sleep(0.005)
    return False


def test_ok_answer_heartbeat_and_metrics() -> None:
    cfg = base_config(channel())
    with daemon_and_controller(cfg) as (d, ctl, _bus):
        send_temps(ctl, 20.5)
        time.sleep(0.02)
        ans = ctl.exchange(_reading(1))
        assert ans.status == "ok"
        assert ans.corrected_mm is not None and ans.corrected_mm != CENTRE_MM
        assert (
            Applied(ans.applied) & Applied.GEOMETRY and Applied(ans.applied) & Applied.SCALE_THERMAL
        )
        assert 0 < ans.correction_um < 50
        assert _wait(lambda: ctl.heartbeat is not None and ctl.heartbeat.answered >= 1)
        hb = ctl.heartbeat
        assert hb.state == DaemonState.READY
        assert hb.grid_id == grid_id_from_sha256(d.grids.current.sha256)
        assert d.metrics_server is not None
        body = urllib.request.urlopen(d.metrics_server.url, timeout=2).read().decode()
        assert 'cmm_comp_answers_total{status="ok"} 1' in body
        assert "cmm_comp_reply_latency_us_count 1" in body
        assert 'cmm_comp_state{state="ready"} 1' in body


def test_no_grid_then_reload_and_bad_grid_refused(tmp_path) -> None:
    cfg = base_config(channel())
    cfg.grid.path = str(tmp_path / "missing.grid")
    with daemon_and_controller(cfg) as (d, ctl, _bus):
        send_temps(ctl)
        ans = ctl.exchange(_reading(1))
        assert ans.status == "no_grid" and ans.corrected_mm == CENTRE_MM
        assert d.state.state == DaemonState.NO_GRID
        assert d.reload_grid(str(npl_grid_path()))
        good = d.grids.current.sha256
        assert ctl.exchange(_reading(2)).status == "ok"
        bad = tmp_path / "bad.grid"
        bad.write_bytes(b"not a grid at all")
        assert not d.reload_grid(str(bad))
        assert d.grids.current.sha256 == good  # the old grid stays active
        assert d.metrics.faults["grid_refused"] == 2
        assert ctl.exchange(_reading(3)).status == "ok"


def test_outside_volume_and_invalid_reading() -> None:
    with daemon_and_controller(base_config(channel())) as (_d, ctl, _bus):
        send_temps(ctl)
        out = (950.0, 100.0, 100.0)
        ans = ctl.exchange(_reading(1, out))
        assert ans.status == "outside_volume" and ans.corrected_mm == out
        ans = ctl.exchange(_reading(2, valid=(True, False, True)))
        assert ans.status == "invalid_reading" and ans.corrected_mm == CENTRE_MM
        assert ctl.exchange(_reading(3)).status == "ok"


@pytest.mark.parametrize(
    ("temps", "valid", "expected"),
    [
        (None, True, "no_temperature"),
        (500.0, True, "implausible_temperature"),
        (35.0, True, "implausible_temperature"),  # plausible, outside the compensated range
        (20.5, False, "no_temperature"),
    ],
)
def test_temperature_faults_reject(temps, valid, expected) -> None:
    cfg = base_config(channel())
    cfg.temperatures.valid_range_C = [10.0, 30.0]
    with daemon_and_controller(cfg) as (d, ctl, _bus):
        if temps is not None:
            ctl.send_temperatures({0: temps, 1: 20.5, 2: 20.5, 3: 20.5}, valid=valid)
            time.sleep(0.02)
        ans = ctl.exchange(_reading(1))
        assert ans.status == expected
        assert ans.corrected_mm == CENTRE_MM  # never a silently wrong coordinate
        assert _wait(lambda: d.state.state == DaemonState.DEGRADED)


def test_stale_and_jumping_temperatures() -> None:
    """Staleness: the reading right after a sample is fresh (stale_s 1 s is far more than one
    exchange takes, even on a loaded machine); one after sleeping past stale_s is stale."""
    cfg = base_config(channel())
    cfg.temperatures.stale_s = 1.0
    cfg.temperatures.max_rate_C_per_s = 0.5
    with daemon_and_controller(cfg) as (_d, ctl, _bus):
        send_temps(ctl, 20.5)
        assert ctl.exchange(_reading(1)).status == "ok"
        time.sleep(1.2)
        assert ctl.exchange(_reading(2)).status == "stale_temperature"
        send_temps(ctl, 20.5)
        assert ctl.exchange(_reading(3)).status == "ok"
        send_temps(ctl, 25.0)  # +4.5 °C: > 0.5 °C/s unless 9 s passed since the last sample
        assert ctl.exchange(_reading(4)).status == "implausible_temperature"


def test_repeated_temperature_counter_is_not_a_new_sample() -> None:
    """docs/can.md: a repeated counter is not a new sample. A frame with the previous counter
    and another value changes nothing (the answer equals the one before, bit for bit) and is
    counted; the next counter is used."""
    from cmm_comp.protocol import TemperatureSample

    cfg = base_config(channel())
    cfg.temperatures.max_rate_C_per_s = 1000.0  # 0.05 °C in two exchanges: always plausible
    with daemon_and_controller(cfg) as (d, ctl, bus):
        send_temps(ctl, 20.5)  # counter 1 for every sensor
        before = ctl.exchange(_reading(1))
        assert before.status == "ok"
        bus.send(encode_message(TemperatureSample.from_celsius(3, 22.0, 1, True), IDS))
        same = ctl.exchange(_reading(2))
        assert (same.status, same.corrected_mm) == ("ok", before.corrected_mm)
        assert d.metrics.get("temperature_repeats") == 1
        bus.send(encode_message(TemperatureSample.from_celsius(3, 20.55, 2, True), IDS))
        used = ctl.exchange(_reading(3))
        assert used.status == "ok" and used.corrected_mm != before.corrected_mm
        assert d.metrics.get("temperature_samples") == 5


def test_a_restarted_controller_is_answered_from_its_first_reading() -> None:
    """The controller restarts its seq counter (back to 0, within 256 of the last finished
    seq, and onto recently answered seqs): every complete reading is answered, with its own
    position (oracle: corrected lies within 0.1 mm of this run's indicated position, 5 mm away
    from the previous run's reading with the same seq)."""
    with daemon_and_controller(base_config(channel())) as (_d, ctl, _bus):
        send_temps(ctl)
        first = [ctl.exchange(_reading(s, (400.0 + s, 575.0, 200.0))) for s in range(40)]
        assert [a.status for a in first] == ["ok"] * 40
        for restart in range(2):
            x0 = 405.0 + 5.0 * restart
            for s in (*range(10), *range(30, 40)):
                ans = ctl.exchange(_reading(s, (x0 + s, 575.0, 200.0)))
                assert ans.status == "ok", (restart, s, ans)
                assert ans.corrected_mm is not None
                assert abs(ans.corrected_mm[0] - (x0 + s)) < 0.1


def test_geometry_only_mode() -> None:
    cfg = base_config(channel())
    cfg.temperatures.on_fault = "geometry_only"
    with daemon_and_controller(cfg) as (_d, ctl, _bus):
        ans = ctl.exchange(_reading(1))  # no temperature ever sent
        assert ans.status == "not_thermally_corrected"
        assert ans.corrected_mm != CENTRE_MM
        assert Applied(ans.applied) == Applied.GEOMETRY


def test_correction_limits() -> None:
    cfg = base_config(channel())
    cfg.limits.warn_um = 0.5
    cfg.limits.error_um = 5.0
    with daemon_and_controller(cfg) as (d, ctl, _bus):
        send_temps(ctl, 20.0)
        time.sleep(0.02)
        small = ctl.exchange(_reading(1, (10.0, 10.0, 390.0)))
        big = ctl.exchange(_reading(2, (890.0, 1140.0, 10.0)))
        assert big.status == "correction_limit" and big.corrected_mm == (890.0, 1140.0, 10.0)
        if small.status == "ok":  # corrections between the limits are applied and counted
            assert d.metrics.get("correction_warnings") >= 1 or small.correction_um <= 0.5


def _send_axes(bus: can.BusABC, seq: int, axes=(Axis.X, Axis.Y, Axis.Z), pos=CENTRE_MM) -> None:
    for ax in axes:
        frame = RawAxis(ax, seq, round(pos[int(ax)] * 1e6))
        bus.send(encode_message(frame, IDS))


def test_incomplete_superseded_out_of_order_duplicate() -> None:
    cfg = base_config(channel())
    cfg.can.triplet_timeout_s = 0.05
    with daemon_and_controller(cfg) as (d, ctl, bus):
        send_temps(ctl)
        time.sleep(0.02)
        _send_axes(bus, 10, (Axis.X, Axis.Y))  # Z never comes
        ans = ctl.wait_answer(10, 10.0)
        assert ans.status == "incomplete_reading" and ans.corrected_mm is None
        _send_axes(bus, 20, (Axis.X, Axis.Y))
        assert ctl.exchange(_reading(21)).status == "ok"  # 21 completes first: 20 is dropped
        assert ctl.wait_answer(20, 10.0).status == "incomplete_reading"
        _send_axes(bus, 20, (Axis.Z,))  # the missing frame of the dropped reading, too late
        _send_axes(bus, 21, (Axis.Y,))  # duplicate of an answered reading
        assert _wait(lambda: d.metrics.faults.get("out_of_order", 0) >= 1)
        assert _wait(lambda: d.metrics.faults.get("duplicate_frame", 0) >= 1)
        assert ctl.exchange(_reading(22)).status == "ok"


def test_bad_frames_are_counted_and_service_continues() -> None:
    with daemon_and_controller(base_config(channel())) as (d, ctl, bus):
        send_temps(ctl)
        block = IDS.block_start
        bus.send(can.Message(arbitration_id=block + 0x6, data=bytes(8), is_extended_id=False))
        bus.send(can.Message(arbitration_id=block + 0x0, data=bytes(5), is_extended_id=False))
        bus.send(can.Message(arbitration_id=block + 0x1, data=bytes(8), is_extended_id=False))
        bus.send(can.Message(arbitration_id=block, is_remote_frame=True, is_extended_id=False))
        bus.send(can.Message(arbitration_id=block, is_error_frame=True, is_extended_id=False))
        bus.send(can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False))
        bus.send(can.Message(arbitration_id=0x12345, data=bytes(8), is_extended_id=True))
        faults = d.metrics.faults
        assert _wait(lambda: sum(faults.values()) >= 5)
        assert faults.get("unknown_id", 0) >= 1  # 0x206 is in our block but undefined
        assert faults.get("bad_length", 0) == 1
        assert faults.get("bad_value", 0) == 1  # axis field X on the RAW_Y id
        assert faults.get("remote_frame", 0) == 1
        assert faults.get("error_frame", 0) == 1
        assert ctl.exchange(_reading(1)).status == "ok"


class _FlakyBus(can.BusABC):
    """A virtual bus whose receive fails once (a driver error), to test reconnects."""

    def __init__(self, channel: str, fail: list[bool]) -> None:
        self._inner = can.Bus(interface="virtual", channel=channel)
        self._fail = fail
        super().__init__(channel=channel)

    def _recv_internal(self, timeout):
        if self._fail and self._fail.pop():
            raise can.CanOperationError("simulated bus-off")
        return self._inner.recv(timeout), False

    def send(self, msg, timeout=None):
        self._inner.send(msg, timeout)

    def shutdown(self):
        self._inner.shutdown()
        super().shutdown()


def test_bus_error_reconnects() -> None:
    cfg = base_config(channel())
    cfg.can.reconnect_s = 0.05
    fails = [True]
    opened: list[int] = []

    def factory(c, ids):
        opened.append(1)
        return _FlakyBus(c.channel, fails)

    with daemon_and_controller(cfg, bus_factory=factory) as (d, ctl, _bus):
        assert _wait(lambda: d.metrics.faults.get("bus_error", 0) == 1)
        assert _wait(lambda: d.can is not None and d.can.connected and len(opened) == 2)
        send_temps(ctl)
        time.sleep(0.02)
        assert ctl.exchange(_reading(1)).status == "ok"
        assert d.metrics.get("can_reconnects") == 1


def test_structured_logs_and_mcap(tmp_path) -> None:
    import io

    from cmm_comp.cli.sessionlog.reader import read_messages

    cfg = base_config(channel())
    cfg.mcap.path = str(tmp_path / "s.mcap")
    cfg.log.format = "json"
    stream = io.StringIO()
    with daemon_and_controller(cfg, events_stream=stream) as (_d, ctl, _bus):
        send_temps(ctl)
        time.sleep(0.02)
        for seq in range(5):
            assert ctl.exchange(_reading(seq)).status == "ok"
    events = [json.loads(line) for line in stream.getvalue().splitlines()]
    names = [e["event"] for e in events]
    assert "grid_loaded" in names and names[-1] == "stopped"
    res = read_messages(cfg.mcap.path)
    assert not res.truncated
    topics = {m.topic for m in res.messages}
    assert {"/cmm/raw", "/cmm/corrected", "/cmm/temperature", "/cmm/status", "/cmm/grid"} <= topics
    assert {"/cmm/can_rx", "/cmm/can_tx", "/cmm/counters"} <= topics
    corrected = [m.payload for m in res.messages if m.topic == "/cmm/corrected"]
    assert [c["seq"] for c in corrected] == list(range(5))


def test_config_must_enable_a_transport() -> None:
    cfg = DaemonConfig()
    cfg.can.enabled = False
    with pytest.raises(ValueError, match="enable at least one"):
        cfg.check()


def test_a_slow_mcap_logger_never_delays_an_answer(tmp_path) -> None:
    """Causality, not a clock: the log() / log_many() calls of a reading's own records (``/cmm/raw``,
    ``/cmm/corrected`` of its seq) block on a gate the test opens only once the controller
    holds the answer. Were any of them on the way between the reading and its answer, the
    answer could not arrive while the gate is shut (the exchange would time out). Other log
    calls (heartbeat frames, counters) pass, so nothing else can hold the endpoint. After each
    answer the test checks the gated call is waiting, opens the gate and waits for the
    bookkeeping to finish; the MCAP file then holds every answer and every frame."""
    import threading

    from cmm_comp.cli.sessionlog.reader import read_messages

    cfg = base_config(channel())
    cfg.mcap.path = str(tmp_path / "s.mcap")
    n = 8
    with daemon_and_controller(cfg) as (d, ctl, _bus):
        assert d.logger is not None and d.can is not None
        endpoint = d.can
        fast_log = d.logger.log
        gate = threading.Event()
        gate.set()
        gated_seq = [-1]
        waiting: list[tuple[str, int]] = []
        returned: list[tuple[str, int]] = []

        def gated_log(topic, payload, *args, **kw):
            if topic not in ("/cmm/raw", "/cmm/corrected") or payload[0] != gated_seq[0]:
                return fast_log(topic, payload, *args, **kw)
            waiting.append((topic, payload[0]))
            gate.wait(60.0)
            try:
                return fast_log(topic, payload, *args, **kw)
            finally:
                returned.append((topic, payload[0]))

        fast_log_many = d.logger.log_many

        def gated_log_many(topic, payloads, *args, **kw):
            mine = [p[0] for p in payloads if topic in ("/cmm/raw", "/cmm/corrected")]
            if gated_seq[0] not in mine:
                return fast_log_many(topic, payloads, *args, **kw)
            waiting.append((topic, gated_seq[0]))
            gate.wait(60.0)
            try:
                return fast_log_many(topic, payloads, *args, **kw)
            finally:
                returned.extend((topic, s) for s in mine)

        d.logger.log = gated_log  # type: ignore[method-assign]
        d.logger.log_many = gated_log_many  # type: ignore[method-assign]
        send_temps(ctl)
        for seq in range(n):
            gated_seq[0] = seq
            gate.clear()
            ans = ctl.exchange(_reading(seq), timeout_s=30.0)
            assert ans.status == "ok", (seq, ans)  # answered while its records could not log
            assert not any(s == seq for _, s in returned)
            assert _wait(lambda s=seq: ("/cmm/raw", s) in waiting)  # its bookkeeping waits
            gate.set()
            assert _wait(lambda s=seq: ("/cmm/corrected", s) in returned)
            assert _wait(lambda: not endpoint._deferred)
    res = read_messages(cfg.mcap.path)
    corrected = [m.payload["seq"] for m in res.messages if m.topic == "/cmm/corrected"]
    assert corrected == list(range(n))
    assert sum(m.topic == "/cmm/can_tx" for m in res.messages) >= 4 * n
