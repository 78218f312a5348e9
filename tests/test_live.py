"""The live view end to end: a WebSocket client written from the Foxglove protocol's public spec
(tests/foxglove_ws_client.py) connects to a :class:`LiveSink` on 127.0.0.1, reads serverInfo and
the advertised channels, subscribes, and decodes Message Data frames. Oracles: the fed records
read field by field (nm → mm by hand), the MCAP log's schemas, the ``foxglove.SceneUpdate``
decoded with ``protobuf`` from the schema the server advertises and checked against the fed
corrections with quaternion algebra written here. Counters are checked exactly: nothing is
encoded while no client subscribes, overload drops the oldest and counts each one, bad values
never stop the sink."""

from __future__ import annotations

import json
import math
import os
import socket
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from foxglove_ws_client import SUBPROTOCOLS, FoxgloveClient, Message, protobuf_class

from cmm_comp.daemon.live import (
    SCENE_TOPIC,
    STREAMED_TOPICS,
    SUBPROTOCOL,
    LiveSection,
    LiveSink,
    LiveStartError,
)
from cmm_comp.daemon.live import sink as sink_module
from cmm_comp.daemon.sessionlog.encoding import encode_message
from cmm_comp.protocol.session_topics import TOPIC_SCHEMAS, check_message

T0_NS = 1_700_000_000_123_456_789


def raw_rec(seq: int, x: float, y: float, z: float) -> tuple[Any, ...]:
    """A ``/cmm/raw`` record in the layout the engine logs (sessionlog.records.RawRecord)."""
    return (seq, x, y, z, (1, 0, -1), (True, True, False), "can", (0.0, 0.0, -120.0), None)


def corr_rec(
    seq: int, pos_nm: tuple[int, int, int], status: str, d_um: tuple[float, float, float]
) -> tuple[Any, ...]:
    """A ``/cmm/corrected`` record (sessionlog.records.CorrectedRecord)."""
    return (seq, *pos_nm, status, d_um, 42.5, 1, "can", "")


def stamp(t_ns: int) -> dict[str, int]:
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def wait_until(cond: Callable[[], bool], what: str, timeout_s: float = 5.0) -> None:
    """Poll ``cond`` (causal evidence: a counter, a subscription) until true."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.001)


def settings(**kw: Any) -> LiveSection:
    """Every message sent (no decimation) unless a test asks for it."""
    base: dict[str, Any] = {
        "enabled": True,
        "port": 0,
        "scene_rate_hz": 1000.0,
        "max_per_update": 100_000,
    }
    return LiveSection(**{**base, **kw})


@pytest.fixture
def errors() -> list[BaseException]:
    return []


@pytest.fixture
def sink(errors: list[BaseException]) -> Iterator[LiveSink]:
    with LiveSink(settings(), on_error=errors.append).start() as s:
        yield s


def connect(sink: LiveSink, topics: list[str]) -> FoxgloveClient:
    """A client subscribed to ``topics``, returned once the sink sees every subscription."""
    client = FoxgloveClient(sink.url)
    try:
        client.wait_for_channels(topics)
        before = sink.stats().subscriptions
        client.subscribe(topics)
        wait_until(lambda: sink.stats().subscriptions == before + len(topics), "subscriptions")
    except BaseException:
        client.close()
        raise
    return client


def wrap_encoders(monkeypatch: pytest.MonkeyPatch, hook: Callable[[str], None]) -> None:
    """Call ``hook(name)`` before every encoding an update does: building the checked message
    (``message_struct``) and its JSON (``struct_json``)."""

    def wrapped(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def call(*a: Any, **kw: Any) -> Any:
            hook(name)
            return fn(*a, **kw)

        return call

    monkeypatch.setattr(sink_module, "struct_json", wrapped("encode", sink_module.struct_json))
    monkeypatch.setattr(
        sink_module, "message_struct", wrapped("object", sink_module.message_struct)
    )


def by_topic(msgs: list[Message]) -> dict[str, list[Message]]:
    out: dict[str, list[Message]] = {}
    for m in msgs:
        out.setdefault(m.topic, []).append(m)
    return out


# ---------------------------------------------------------------------------- protocol


def test_handshake_server_info_and_advertised_channels(sink: LiveSink) -> None:
    with FoxgloveClient(sink.url) as client:
        assert client.subprotocol == SUBPROTOCOL == "foxglove.sdk.v1"
        assert SUBPROTOCOL in SUBPROTOCOLS
        assert client.server_info["name"] == "cmm-comp"
        client.wait_for_channels([*STREAMED_TOPICS, SCENE_TOPIC])
        for topic in STREAMED_TOPICS:
            ch = client.channels[topic]
            assert ch["encoding"] == "json" and ch["schemaEncoding"] == "jsonschema"
            assert ch["schemaName"] == TOPIC_SCHEMAS[topic].name  # the MCAP log's names
            assert json.loads(ch["schema"]) == TOPIC_SCHEMAS[topic].schema
        scene = client.channels[SCENE_TOPIC]
        assert (scene["encoding"], scene["schemaName"]) == ("protobuf", "foxglove.SceneUpdate")
        assert set(client.channels) == {*STREAMED_TOPICS, SCENE_TOPIC}


def test_the_old_subprotocol_alone_is_refused_by_the_sdk(sink: LiveSink) -> None:
    """foxglove-sdk selects only ``foxglove.sdk.v1`` (docs/live.md: use a current Foxglove)."""
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect as ws_connect

    with (
        pytest.raises(InvalidStatus, match="HTTP 400"),
        ws_connect(sink.url, subprotocols=["foxglove.websocket.v1"]),  # type: ignore[list-item]
    ):
        pass


def test_values_arrive_as_fed(sink: LiveSink, errors: list[BaseException]) -> None:
    topics = ["/cmm/raw", "/cmm/corrected", "/cmm/temperature", "/cmm/status", "/cmm/counters"]
    with connect(sink, topics) as client:
        raws = [raw_rec(10 + i, 100.25 + i, -20.5, 300.125) for i in range(3)]
        corrs = [
            corr_rec(10, (100_251_000, -20_497_000, 300_121_000), "ok", (1.0, 3.0, -4.0)),
            corr_rec(11, (101_250_000, -20_500_000, 300_125_000), "outside_volume", (0, 0, 0)),
        ]
        temp = {"sensor": "2", "role": "T_z", "temp_C": 20.75, "counter": 9, "valid": True}
        status = {"state": "ready", "detail": "grid loaded", "grid_sha256": "ab" * 32}
        counters = {"counters": {"answered": 2**40 + 3}, "period_s": 1.0}
        sink.log_many("/cmm/raw", raws, T0_NS)
        sink.log_many("/cmm/corrected", corrs, T0_NS + 1)
        sink.log("/cmm/temperature", temp, T0_NS + 2)
        sink.log("/cmm/status", status, T0_NS + 3)
        sink.log("/cmm/counters", counters, T0_NS + 4)
        sink.log_many("/cmm/can_rx", [(1, False, 0, b"", 0.0, "c", False, False, False)])
        sink.tick()
        got = by_topic(client.receive(8))
    for rec, m in zip([*raws, *corrs], [*got["/cmm/raw"], *got["/cmm/corrected"]], strict=True):
        # byte for byte what the MCAP session log writes for the same record and time
        assert m.payload == encode_message(m.topic, rec, m.log_time_ns)
    for i, m in enumerate(got["/cmm/raw"]):
        assert m.log_time_ns == T0_NS
        assert m.json() == {
            "seq": 10 + i,
            "x_mm": 100.25 + i,
            "y_mm": -20.5,
            "z_mm": 300.125,
            "travel_dir": [1, 0, -1],
            "valid": [True, True, False],
            "source": "can",
            "stylus_x_mm": 0.0,
            "stylus_y_mm": 0.0,
            "stylus_z_mm": -120.0,
            "stamp": stamp(T0_NS),
        }
        check_message("/cmm/raw", m.json())
    c0, c1 = (m.json() for m in got["/cmm/corrected"])
    assert got["/cmm/corrected"][0].log_time_ns == T0_NS + 1
    assert c0["x_mm"] == pytest.approx(100.251, abs=1e-12)
    assert c0["y_mm"] == pytest.approx(-20.497, abs=1e-12)
    assert c0["z_mm"] == pytest.approx(300.121, abs=1e-12)
    assert (c0["seq"], c0["status"], c0["dx_um"], c0["dy_um"], c0["dz_um"]) == (
        10,
        "ok",
        1.0,
        3.0,
        -4.0,
    )
    assert (c0["latency_us"], c0["applied"], c0["stamp"]) == (42.5, 1, stamp(T0_NS + 1))
    assert c1["status"] == "outside_volume" and "detail" not in c1
    for topic, fed, dt in (
        ("/cmm/temperature", temp, 2),
        ("/cmm/status", status, 3),
        ("/cmm/counters", counters, 4),
    ):
        (m,) = got[topic]
        assert m.log_time_ns == T0_NS + dt
        assert m.json() == {**fed, "stamp": stamp(T0_NS + dt)}
        check_message(topic, m.json())
    assert "/cmm/can_rx" not in got
    s = sink.stats()
    assert (s.sent, s.encode_errors, s.nulled, s.dropped) == (8, 0, 0, 0)
    assert errors == []


# ---------------------------------------------------------------------------- the 3-D scene


def rotate(q_wxyz: tuple[float, float, float, float], v: tuple[float, ...]) -> list[float]:
    """``q v q*`` for a unit quaternion (w, x, y, z), written out (Rodrigues form)."""
    w, x, y, z = q_wxyz
    tx, ty, tz = 2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])
    return [
        v[0] + w * tx + (y * tz - z * ty),
        v[1] + w * ty + (z * tx - x * tz),
        v[2] + w * tz + (x * ty - y * tx),
    ]


def test_scene_keep_arrows_point_along_the_correction(sink: LiveSink) -> None:
    cases = [  # (seq, answered position nm, status, correction µm)
        (1, (250_003_000, 400_000_000, 100_012_000), "ok", (3.0, -4.0, 12.0)),
        (2, (500_000_000, 100_000_000, 50_000_000), "not_thermally_corrected", (-2.5, 0.0, 0.0)),
        (3, (700_000_000, 800_000_000, 300_000_000), "outside_volume", (0.0, 0.0, 0.0)),
        (4, (10_000_000, 20_000_000, 30_000_000), "ok", (0.0, 0.0, 0.0)),
    ]
    with connect(sink, [SCENE_TOPIC]) as client:
        sink.log_many("/cmm/corrected", [corr_rec(*c) for c in cases], T0_NS)
        sink.tick()
        (msg,) = client.receive(1)
        update = protobuf_class(client.channels[SCENE_TOPIC]).FromString(msg.payload)
    scale = sink.settings.arrow_mm_per_um
    entities = {e.id: e for e in update.entities}
    assert set(entities) == {
        "correction/0",
        "correction/1",
        "correction/2",
        "correction/3",
        "probe",
    }
    for slot, (seq, pos_nm, status, d) in enumerate(cases):
        e = entities[f"correction/{slot}"]
        assert e.frame_id == "cmm"
        assert (e.timestamp.seconds, e.timestamp.nanos) == divmod(T0_NS, 1_000_000_000)
        meta = {kv.key: kv.value for kv in e.metadata}
        assert (meta["seq"], meta["status"]) == (str(seq), status)
        applied = status != "outside_volume"
        # tail at the indicated position = answered − applied correction, in metres
        tail_m = [
            (p / 1e6 - (di / 1000 if applied else 0.0)) / 1000
            for p, di in zip(pos_nm, d, strict=True)
        ]
        norm = math.sqrt(sum(c * c for c in d))
        if not applied:
            assert not e.arrows and len(e.cubes) == 1
            cube = e.cubes[0]
            got = [cube.pose.position.x, cube.pose.position.y, cube.pose.position.z]
            assert got == pytest.approx(tail_m, abs=1e-12)
            assert cube.color.r > 0.8 > cube.color.g  # red
            continue
        if norm == 0:
            assert not e.arrows and len(e.spheres) == 1
            continue
        (arrow,) = e.arrows
        p = arrow.pose.position
        assert [p.x, p.y, p.z] == pytest.approx(tail_m, abs=1e-12)
        o = arrow.pose.orientation
        assert math.isclose(o.w**2 + o.x**2 + o.y**2 + o.z**2, 1.0, rel_tol=1e-12)
        direction = rotate((o.w, o.x, o.y, o.z), (1.0, 0.0, 0.0))
        assert direction == pytest.approx([c / norm for c in d], abs=1e-12)
        assert arrow.shaft_length + arrow.head_length == pytest.approx(norm * scale / 1000)
        assert 0 < arrow.head_length < arrow.shaft_length + arrow.head_length
        if status == "ok":
            assert arrow.color.g > arrow.color.r  # green
        else:
            assert arrow.color.r > arrow.color.g > arrow.color.b  # amber
    probe = entities["probe"].spheres[0].pose.position
    assert [probe.x, probe.y, probe.z] == pytest.approx([0.01, 0.02, 0.03], abs=1e-12)


def test_scene_decimates_and_cycles_its_slots() -> None:
    with LiveSink(settings(scene_keep_arrows=6, scene_max_new_arrows=4)).start() as sink:
        with connect(sink, [SCENE_TOPIC]) as client:
            cls = protobuf_class(client.channels[SCENE_TOPIC])
            batch = [corr_rec(i, (1_000_000 * i, 0, 0), "ok", (1.0, 0.0, 0.0)) for i in range(100)]
            sink.log_many("/cmm/corrected", batch, T0_NS)
            sink.tick()
            first = cls.FromString(client.receive(1)[0].payload)
            sink.log_many("/cmm/corrected", batch[:4], T0_NS + 1)
            time.sleep(2.0 / 1000.0)  # past the 1 ms scene period (scene_rate_hz = 1000)
            sink.tick()
            second = cls.FromString(client.receive(1)[0].payload)
        s = sink.stats()

    def seqs(update: Any) -> dict[str, str]:
        return {
            e.id: {kv.key: kv.value for kv in e.metadata}["seq"]
            for e in update.entities
            if e.id != "probe"
        }

    assert seqs(first) == {"correction/0": "0", "correction/1": "33", "correction/2": "66",
                           "correction/3": "99"}  # fmt: skip
    assert seqs(second) == {"correction/4": "0", "correction/5": "1", "correction/0": "2",
                            "correction/1": "3"}  # fmt: skip
    assert (s.scene_updates, s.scene_points, s.scene_decimated) == (2, 8, 96)
    # the scene alone asked for the corrected records: none was encoded as /cmm/corrected JSON
    assert (s.sent, s.not_encoded) == (0, 104)


# ---------------------------------------------------------------------------- counters


def test_nothing_is_encoded_without_a_subscriber(
    sink: LiveSink, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[str] = []
    wrap_encoders(monkeypatch, calls.append)
    for i in range(500):
        sink.log("/cmm/raw", raw_rec(i, 1.0, 2.0, 3.0), T0_NS + i)
    sink.log_many("/cmm/corrected", [corr_rec(i, (0, 0, 0), "ok", (1, 1, 1)) for i in range(500)])
    with connect(sink, ["/cmm/temperature"]) as client:  # a client, but not on these topics
        sink.log_many("/cmm/raw", [raw_rec(i, 1.0, 2.0, 3.0) for i in range(1000)], T0_NS)
        sink.tick()
        assert sink.stats().queue_len == 0
        assert calls == []
        client.subscribe(["/cmm/raw"])
        wait_until(lambda: sink.stats().subscriptions == 2, "raw subscription")
        sink.log("/cmm/raw", raw_rec(7, 1.0, 2.0, 3.0), T0_NS)
        sink.tick()
        (m,) = client.receive(1)
        assert m.json()["seq"] == 7
    s = sink.stats()
    assert calls == ["object", "encode"]  # one record, by the session log's encoding
    assert (s.offered, s.not_encoded, s.sent, s.dropped) == (2001, 2000, 1, 0)


def test_bad_values_never_stop_the_sink(sink: LiveSink, errors: list[BaseException]) -> None:
    topics = ["/cmm/raw", "/cmm/corrected", "/cmm/counters", SCENE_TOPIC]
    with connect(sink, topics) as client:
        sink.log("/cmm/raw", raw_rec(1, math.nan, math.inf, -math.inf), T0_NS)
        sink.log(
            "/cmm/raw", ("seven", 1.0, 2.0, 3.0, (0, 0, 0), (True,) * 3, "can", (0, 0, 0), None)
        )
        sink.log("/cmm/raw", raw_rec(2, 1.0, 2.0, 3.0)[:-2], T0_NS)  # too short
        sink.log("/cmm/counters", {"counters": {"a": 1}, "latency_edges_us": [1.0, math.nan]})
        sink.log("/cmm/counters", {"counters": {"a": {1, 2}}})  # a set is not JSON
        sink.log_many(
            "/cmm/corrected",
            [
                corr_rec(3, (1_000_000, 0, 0), "ok", (math.nan, 1.0, 2.0)),
                corr_rec(4, (2_000_000, 0, 0), "ok", (1.0, 0.0, 0.0)),
            ],
            T0_NS,
        )
        sink.log("/cmm/raw", raw_rec(5, 1.0, 2.0, 3.0), T0_NS)
        sink.tick()
        got = by_topic(client.receive(6))
    raw = [m.json() for m in got["/cmm/raw"]]
    assert (raw[0]["seq"], raw[0]["x_mm"], raw[0]["y_mm"], raw[0]["z_mm"]) == (1, None, None, None)
    assert raw[1]["seq"] == 5
    assert got["/cmm/counters"][0].json()["latency_edges_us"] == [1.0, None]
    c3, c4 = (m.json() for m in got["/cmm/corrected"])
    assert (c3["dx_um"], c3["dy_um"], c4["dx_um"]) == (None, 1.0, 1.0)
    s = sink.stats()
    assert (s.sent, s.encode_errors, s.nulled) == (5, 3, 5)  # + 1 scene update
    assert (s.scene_skipped, s.scene_points) == (1, 1)  # the NaN correction is not drawn
    assert len(errors) == 3 and all("message not sent" in str(e) for e in errors)
    assert "/cmm/raw" in str(errors[0]) and "/cmm/counters" in str(errors[2])


def test_a_bad_log_time_is_counted_not_sent(sink: LiveSink, errors: list[BaseException]) -> None:
    with connect(sink, ["/cmm/raw"]) as client:
        sink.log_many("/cmm/raw", [raw_rec(1, 0.0, 0.0, 0.0)] * 2, -1)
        sink.log_many("/cmm/raw", [raw_rec(2, 0.0, 0.0, 0.0)], 1.5e18)  # type: ignore[arg-type]
        sink.log("/cmm/raw", raw_rec(3, 0.0, 0.0, 0.0), T0_NS)
        sink.tick()
        (m,) = client.receive(1)
    assert m.json()["seq"] == 3
    assert (sink.stats().encode_errors, sink.stats().sent) == (3, 1)
    assert "log time -1 is not integer ns" in str(errors[0])


def test_a_failing_error_handler_does_not_stop_the_sink() -> None:
    def boom(exc: BaseException) -> None:
        raise RuntimeError("handler bug")

    with LiveSink(settings(), on_error=boom).start() as sink, connect(sink, ["/cmm/raw"]) as c:
        sink.log("/cmm/raw", ("bad",), T0_NS)
        sink.log("/cmm/raw", raw_rec(9, 1.0, 2.0, 3.0), T0_NS)
        sink.tick()
        assert c.receive(1)[0].json()["seq"] == 9
    assert sink.stats().encode_errors == 1


def test_status_and_grid_greet_a_new_subscriber(sink: LiveSink) -> None:
    status = {"state": "degraded", "detail": "stale T_x", "grid_sha256": ""}
    sink.log("/cmm/status", {"state": "ready", "detail": "old", "grid_sha256": ""}, T0_NS)
    sink.log("/cmm/status", status, T0_NS + 5)
    with connect(sink, ["/cmm/status"]) as client:
        sink.tick()  # the next update greets the new subscriber
        (m,) = client.receive(1)
    assert m.log_time_ns == T0_NS + 5
    assert m.json() == {**status, "stamp": stamp(T0_NS + 5)}
    assert sink.stats().replayed == 1


# ---------------------------------------------------------------------------- lifecycle


def test_a_busy_port_is_one_clear_error_and_leaves_nothing_running() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        sink = LiveSink(settings(port=port))
        with pytest.raises(LiveStartError, match=rf"cannot listen on 127\.0\.0\.1:{port}") as err:
            sink.start()
        assert "\n" not in str(err.value) and "live.port" in str(err.value)
        assert sink.stop(1.0)


def test_missing_foxglove_is_one_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove -> ImportError
    with pytest.raises(LiveStartError, match=r"pip install 'cmm-comp\[live\]'"):
        LiveSink(settings()).start()


def test_stop_closes_the_port_and_refuses_later_messages() -> None:
    sink = LiveSink(settings()).start()
    port = sink.port
    client = connect(sink, ["/cmm/raw"])
    try:
        assert sink.stop(2.0)
        assert sink.stop(0.1)  # idempotent
        assert sink.log_many("/cmm/raw", [raw_rec(1, 0.0, 0.0, 0.0)]) == 0
        # nothing in this process listens there any more (another process on a busy machine
        # may take the freed port: a refused connection alone would be a test of the machine)
        assert not _listening_here(port)
    finally:
        client.close()


def _listening_here(port: int) -> bool:
    """Whether a socket of this process listens on TCP ``port`` (/proc/net/tcp{,6}: state 0A
    is LISTEN; the socket's inode matched against this process' open file descriptors)."""
    inodes = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text(encoding="ascii").splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            f = line.split()
            if f[3] == "0A" and int(f[1].rsplit(":", 1)[1], 16) == port and f[9] in inodes:
                return True
    return False
