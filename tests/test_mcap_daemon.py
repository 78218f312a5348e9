"""The daemon's session log under the faults an outside tester met (issue 12): a reading that
never completes (its expiry answer waited longer than the histogram's top edge) once made the
period's p99 infinite, ``/cmm/counters`` failed to encode and the log stopped for the rest of
the session. Oracle: the answers the controller decoded from the bus against the ``mcap``
package's reader on the file, with strict JSON (NaN/Infinity refused)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import can
from mcap.reader import make_reader
from test_daemon_support import CENTRE_MM, base_config, channel, send_temps

from cmm_comp.daemon.metrics import LatencyHistogram, Metrics
from cmm_comp.daemon.service import DaemonService
from cmm_comp.protocol import Axis, CanIds, RawAxis, encode_message
from cmm_comp.sim_controller.controller import CanController, RawReading


def _strict(data: bytes) -> dict:
    def refuse(token: str) -> None:
        raise ValueError(f"non-JSON constant {token}")

    return json.loads(data, parse_constant=refuse)


def _wait(pred, timeout_s: float = 10.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if pred():
            return True
        time.sleep(0.005)
    return False


def test_histogram_statistics_stay_finite() -> None:
    h = LatencyHistogram()
    assert h.quantile(0.5) is None  # empty: no statistic, not NaN
    for v in (float("inf"), float("nan"), -1.0, float("-inf")):
        h.add(v)
    assert h.total == 0 and h.invalid == 4 and h.quantile(0.99) is None
    h.add(50.0)
    h.add(250_000.0)  # above the top edge (100 ms): the overflow bin
    assert h.quantile(0.5) == 50.0
    assert h.quantile(0.99) == 250_000.0  # the largest seen, never inf
    m = Metrics()
    m.answer("incomplete_reading", None)  # no reply latency: counted apart
    m.answer("ok", 1e9)
    m.answer("ok", float("inf"))
    snap = m.snapshot(reset_period=True)
    json.dumps(snap, allow_nan=False)  # encodable as it stands
    assert snap["latency_p99_us"] == 1e9 and snap["latency_over_top"] == 1
    assert snap["counters"]["answers_incomplete_reading"] == 1
    assert snap["counters"]["answers_without_latency"] == 1
    assert snap["counters"]["latency_invalid"] == 1
    assert "inf" not in m.prometheus().lower().replace("+inf", "")


def test_a_reading_that_never_completes_does_not_stop_the_log(tmp_path: Path) -> None:
    cfg = base_config(channel())
    cfg.metrics.enabled = False
    cfg.metrics.period_s = 1.0  # ok answers and the expired one share a period
    cfg.can.triplet_timeout_s = 0.15  # the expiry answer comes > 100 ms (top edge) later
    cfg.mcap.path = str(tmp_path / "session.mcap")
    cfg.check()
    ids = CanIds(node_id=cfg.can.node_id)
    n = 30
    with DaemonService(cfg, events_stream=None) as d:
        assert d.logger is not None
        counters_logged = [0]
        log = d.logger.log

        def counting_log(topic, payload, *args, **kw):
            if topic == "/cmm/counters":
                counters_logged[0] += 1
            return log(topic, payload, *args, **kw)

        d.logger.log = counting_log  # type: ignore[method-assign]
        bus = can.Bus(interface="virtual", channel=cfg.can.channel)
        try:
            with CanController(bus, answer_timeout_s=10.0) as ctl:
                send_temps(ctl)
                answers = [ctl.exchange(RawReading(100 + i, CENTRE_MM)) for i in range(n // 2)]
                for ax in (Axis.X, Axis.Y):  # Z never comes
                    bus.send(encode_message(RawAxis(ax, 5, round(CENTRE_MM[ax] * 1e6)), ids))
                assert ctl.wait_answer(5, 10.0).status == "incomplete_reading"
                assert _wait(lambda: d.metrics.answers.get("incomplete_reading", 0) == 1)
                answers += [ctl.exchange(RawReading(100 + i, CENTRE_MM)) for i in range(n // 2, n)]
                # the counters of the period holding these answers are published (no clock)
                after = counters_logged[0]
                assert _wait(lambda: counters_logged[0] >= max(2, after + 1), 60.0)
        finally:
            bus.shutdown()
        logger = d.logger
        assert logger is not None
    assert [a.status for a in answers] == ["ok"] * n
    st = logger.stats()
    assert logger.error is None and st.dropped == 0 and st.encode_errors == 0

    with open(cfg.mcap.path, "rb") as f:
        reader = make_reader(f)
        msgs = [(c.topic, _strict(m.data)) for _, c, m in reader.iter_messages()]
        f.seek(0)
        end = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["session_end"]
    assert (end["dropped"], end["encode_errors"], end["error"]) == ("0", "0", "")
    assert not [p for t, p in msgs if t == "/cmm/log_error"]
    corrected = [p["seq"] for t, p in msgs if t == "/cmm/corrected"]
    assert corrected == [100 + i for i in range(n)]  # every answer given is in the file
    counters = [p for t, p in msgs if t == "/cmm/counters"]
    assert len(counters) >= 2
    assert any("latency_p99_us" in c for c in counters)
    last = counters[-1]
    assert last["counters"]["answers_incomplete_reading"] == 1
    assert last["counters"]["mcap_dropped"] == 0
    for c in counters:
        for key in ("latency_p50_us", "latency_p99_us"):
            assert key not in c or math.isfinite(c[key])


def test_an_existing_explicit_log_path_is_rotated_never_refused_or_overwritten(
    tmp_path: Path,
) -> None:
    """A crash-restart loop with ``[mcap] path = "session.mcap"`` keeps starting: each start
    writes the first free ``session.N.mcap``; earlier files stay as they were."""
    first = tmp_path / "session.mcap"
    first.write_bytes(b"an earlier session")
    (tmp_path / "session.1.mcap").write_bytes(b"another one")
    cfg = base_config(channel())
    cfg.metrics.enabled = False
    cfg.mcap.path = str(first)
    cfg.check()
    for run in range(2):
        with DaemonService(cfg, events_stream=None) as d:
            bus = can.Bus(interface="virtual", channel=cfg.can.channel)
            try:
                with CanController(bus, answer_timeout_s=10.0) as ctl:
                    send_temps(ctl)
                    time.sleep(0.02)
                    assert ctl.exchange(RawReading(run, CENTRE_MM)).status == "ok"
            finally:
                bus.shutdown()
            assert d.logger is not None
            files = d.logger.files
        expected = tmp_path / f"session.{2 + run}.mcap"
        assert files == (expected,)
        with open(expected, "rb") as f:
            reader = make_reader(f)
            seqs = [
                _strict(m.data)["seq"]
                for _, _, m in reader.iter_messages(topics=["/cmm/corrected"])
            ]
            f.seek(0)
            session = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["session"]
        assert seqs == [run]
        assert session["file"] == expected.name and session["requested_file"] == "session.mcap"
    assert first.read_bytes() == b"an earlier session"
    assert (tmp_path / "session.1.mcap").read_bytes() == b"another one"


def test_log_drops_reach_the_status_page_exactly(tmp_path: Path) -> None:
    """Drops of the session log are in the daemon's status (Prometheus), per topic and in
    total, exactly: after the log stopped, 5 + 2 ``/cmm/modbus`` records (a topic this daemon,
    Modbus off, never logs itself) are dropped and counted."""
    import urllib.request

    cfg = base_config(channel())
    cfg.metrics.enabled = True
    cfg.metrics.port = 0
    cfg.mcap.path = str(tmp_path / "s.mcap")
    cfg.check()
    record = {"op": "read", "address": 0, "count": 1, "values": [1]}
    with DaemonService(cfg, events_stream=None) as d:
        assert d.logger is not None and d.metrics_server is not None
        assert d.logger.stop(30.0)
        assert d.logger.log_many("/cmm/modbus", [record] * 5) == 0
        assert d.logger.log("/cmm/modbus", record) is False
        assert d.logger.log("/cmm/modbus", record) is False
        with urllib.request.urlopen(d.metrics_server.url, timeout=10) as resp:
            text = resp.read().decode()
    values = {
        line.split()[0]: float(line.split()[1])
        for line in text.splitlines()
        if line.startswith("cmm_comp_mcap_")
    }
    assert values["cmm_comp_mcap_dropped_modbus"] == 7
    per_topic = sum(v for k, v in values.items() if k.startswith("cmm_comp_mcap_dropped_"))
    assert values["cmm_comp_mcap_dropped"] == per_topic >= 7
