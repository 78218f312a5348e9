"""The daemon answers U (issue 13 item 4): CAN, Modbus, MCAP and replay, against oracles.

The grid carries a *synthetic* uncertainty whose node covariances are linear in x, y, z (a
not-a-knot cubic spline reproduces a linear field exactly), so the expected U at any point is
written here in closed form from the rule of docs/formats.md §7, in matrix form: var(r_i) =
aᵢᵀ Σ aᵢ with r = δt + 10⁻³ δω × p, plus the thermal and probing terms. Frames are checked with
cantools on the DBC, the Modbus registers with a raw socket packing MBAP by hand, the MCAP log
with the ``mcap`` reader and the ``jsonschema`` validator (draft 2020-12) against the schema the
file itself carries. Nothing here waits on a clock: answers are awaited, frames read after.
"""

from __future__ import annotations

import functools
import json
import math
import struct
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import can
import cantools
import jsonschema
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from test_daemon_can_reply import endpoint
from test_daemon_support import (
    STYLUS,
    _workdir,
    base_config,
    channel,
    daemon_and_controller,
    npl_grid_path,
    npl_machine,
    send_temps,
    signing_key,
)
from test_protocol_modbus_support import RawClient
from test_protocol_uncertainty import expected_raw, u_values

from cmm_comp.cli.sessionlog.replay import replay_offline
from cmm_comp.compensation.grid import CorrectionGrid, sign_grid
from cmm_comp.compensation.grid.uncertainty import (
    COVARIANCE_COMPONENTS,
    GridUncertainty,
    ThermalUncertainty,
)
from cmm_comp.daemon.engine import U_UNKNOWN, Answer, CorrectionEngine, Reading
from cmm_comp.daemon.service import DaemonService
from cmm_comp.protocol import Applied, Axis, CanIds, Heartbeat, Status, dbc_text
from cmm_comp.protocol.codes import NM_PER_MM
from cmm_comp.sim_controller.controller import RawReading

DB = cantools.database.load_string(dbc_text(), database_format="dbc")
IDS = CanIds()
U_BIT = 0x20
TEMP_C = 20.5
THERMAL = ThermalUncertainty(
    reference_C=20.0,
    reference_mm=(0.0, 0.0, 0.0),
    expansion=(11.0, 0.0, 8.0),
    u_expansion=(1.1, 0.0, 0.8),
    u_temperature_C=(0.1, 0.1, 0.15),
    workpiece_expansion=11.5,
    u_workpiece_expansion=1.15,
    u_workpiece_temperature_C=0.2,
    workpiece_fixture_mm=(450.0, 575.0, 0.0),
)
PROBE_UM = 0.25
OK_POINTS_MM = [(120.0, 200.0, 50.0), (450.0, 575.0, 200.0), (880.0, 1100.0, 390.0), (5, 7, 3)]


def cov_entries(x: float, y: float, z: float) -> dict[str, float]:
    """The synthetic node covariance (µm², µm·µrad, µrad²): linear in the position, mm."""
    return {
        "tx_tx": 4.0 + 0.004 * x,
        "ty_ty": 9.0 + 0.003 * y,
        "tz_tz": 1.0 + 0.01 * z,
        "tx_wy": 0.3 + 0.0005 * z,
        "tx_wz": -0.2,
        "ty_wx": 0.1 + 0.0002 * y,
        "ty_wz": 0.05,
        "tz_wx": 0.1,
        "tz_wy": -0.15,
        "wx_wx": 2.0,
        "wy_wy": 3.0 + 0.002 * x,
        "wz_wz": 1.5,
        "wx_wy": 0.4,
        "wx_wz": -0.3,
        "wy_wz": 0.2,
    }


def u_oracle(p_mm: tuple[float, float, float], temp_C: float = TEMP_C) -> np.ndarray:
    """U (k = 2) of X, Y, Z, µm, at ``p_mm`` with the daemon's stylus, every sensor at
    ``temp_C``: Σ (6×6) of (tx, ty, tz, wx, wy, wz) and r = δt + 10⁻³ δω × p."""
    c = cov_entries(*p_mm)
    names = ("tx", "ty", "tz", "wx", "wy", "wz")
    sigma = np.zeros((6, 6))
    for key, v in c.items():
        a, b = (names.index(n) for n in key.split("_"))
        sigma[a, b] = sigma[b, a] = v
    px, py, pz = STYLUS
    jac = 1e-3 * np.array([[0, pz, -py], [-pz, 0, px], [py, -px, 0]])  # r = δt + J·δω
    rows = np.hstack([np.eye(3), jac])
    var = np.einsum("ij,jk,ik->i", rows, sigma, rows)
    t = THERMAL
    for k in range(3):
        a, ua, ut = t.expansion[k], t.u_expansion[k], t.u_temperature_C[k]
        dt = temp_C - t.reference_C
        lever = (p_mm[k] - t.reference_mm[k]) / 1000.0
        var[k] += (a * a * ut * ut + dt * dt * ua * ua + ua * ua * ut * ut) * lever**2
        a, ua, ut = t.workpiece_expansion, t.u_workpiece_expansion, t.u_workpiece_temperature_C
        lever = (p_mm[k] - t.workpiece_fixture_mm[k]) / 1000.0
        var[k] += (a * a * ut * ut + dt * dt * ua * ua + ua * ua * ut * ut) * lever**2
    return 2.0 * np.sqrt(var + PROBE_UM**2)


@functools.cache
def u_grid_path() -> Path:
    """The NPL grid (10×12×6 nodes) carrying the synthetic U, signed with the test key."""
    plain = CorrectionGrid.build(npl_machine(), steps=(10, 12, 6))
    nodes = np.stack(np.meshgrid(*plain.axes, indexing="ij"), axis=-1)
    cov = np.zeros((*plain.steps, len(COVARIANCE_COMPONENTS)))
    for i, name in enumerate(COVARIANCE_COMPONENTS):
        cov[..., i] = np.vectorize(lambda x, y, z, n=name: cov_entries(x, y, z)[n])(
            nodes[..., 0], nodes[..., 1], nodes[..., 2]
        )
    gu = GridUncertainty(cov, PROBE_UM, THERMAL, info={"method": "synthetic (tests)"})
    path = _workdir() / "npl-u.grid"
    plain.with_uncertainty(gu).save(path)
    sign_grid(path, signing_key()[0])
    return path


def nm(p_mm: tuple[float, float, float]) -> tuple[int, int, int]:
    x, y, z = p_mm
    return (round(x * NM_PER_MM), round(y * NM_PER_MM), round(z * NM_PER_MM))


def check_u(decoded: float, oracle: float) -> None:
    """A decoded U is the oracle rounded up to 0.01 µm (float noise of the kernels: 1e-9)."""
    assert oracle - 1e-9 <= decoded < oracle + 0.01 + 1e-9, (decoded, oracle)


# --------------------------------------------------------------------------- CAN
def test_can_answers_U_before_the_status_frame_cantools_decodes_it() -> None:
    cfg = base_config(channel(), u_grid_path())
    cfg.can.send_uncertainty = True
    cfg.metrics.enabled = False
    readings = [RawReading(i + 1, p) for i, p in enumerate(OK_POINTS_MM)]
    readings.append(RawReading(20, (-30.0, 100.0, 100.0)))  # outside the volume
    readings.append(RawReading(21, (100.0, 100.0, 100.0), valid=(True, False, True)))
    with daemon_and_controller(cfg) as (_, ctl, _bus):
        spy = can.Bus(interface="virtual", channel=cfg.can.channel)
        try:
            send_temps(ctl, TEMP_C)
            answers = {r.seq: ctl.exchange(r) for r in readings}
            frames = []
            while (msg := spy.recv(0.0)) is not None:
                frames.append(msg)
        finally:
            spy.shutdown()
    daemon_ids = IDS.daemon_tx_ids() - {IDS.id_of(Heartbeat.kind)}
    by_seq: dict[int, list[can.Message]] = {}
    for msg in frames:
        if msg.arbitration_id in daemon_ids:
            seq = DB.get_message_by_frame_id(msg.arbitration_id).decode(msg.data)["Seq"]
            by_seq.setdefault(seq, []).append(msg)
    for r in readings:
        got = by_seq[r.seq]
        assert [m.arbitration_id for m in got] == [0x208, 0x209, 0x20A, 0x20C, 0x20B]
        u = DB.get_message_by_name("CORRECTION_UNCERTAINTY").decode(got[3].data)
        status = DB.get_message_by_name("CORRECTION_STATUS").decode(got[4].data)
        ok = r.seq < 20
        assert (status["Status"] == "ok") is ok
        assert bool(status["Applied"] & U_BIT) is ok
        if ok:
            for k, name in enumerate(("Ux", "Uy", "Uz")):
                check_u(u[name], u_oracle(r.indicated_mm)[k])
            # the simulated controller reads the same frame (raw / 100; cantools: raw · 0.01)
            assert answers[r.seq].uncertainty_um == pytest.approx(
                [u["Ux"], u["Uy"], u["Uz"]], rel=1e-15
            )
        else:
            assert (u["Ux"], u["Uy"], u["Uz"]) == ("unknown", "unknown", "unknown")
            assert all(math.isnan(v) for v in answers[r.seq].uncertainty_um or ())


def test_a_grid_without_U_answers_exactly_as_before() -> None:
    """No U in the grid, default config: four frames a reading, Applied bit 5 clear; the same
    grid and readings with send_uncertainty: the fifth frame says unknown, nothing else moves."""
    out: dict[bool, list[list[tuple[int, bytes]]]] = {}
    for send_u in (False, True):
        cfg = base_config(channel(), npl_grid_path())
        cfg.can.send_uncertainty = send_u
        cfg.metrics.enabled = False
        with daemon_and_controller(cfg) as (d, ctl, _bus):
            spy = can.Bus(interface="virtual", channel=cfg.can.channel)
            try:
                send_temps(ctl, TEMP_C)
                for i, p in enumerate(OK_POINTS_MM):
                    a = ctl.exchange(RawReading(i + 1, p))
                    assert a.status == "ok"
                    if send_u:
                        assert a.uncertainty_um is not None
                        assert all(math.isnan(v) for v in a.uncertainty_um)
                    else:
                        assert a.uncertainty_um is None  # no U frame came
                frames = []
                while (m := spy.recv(0.0)) is not None:
                    frames.append((m.arbitration_id, bytes(m.data)))
            finally:
                spy.shutdown()
            assert d.engine is not None and d.grids.current is not None
            assert not d.grids.current.has_uncertainty
        answers = [f for f in frames if f[0] in IDS.daemon_tx_ids() and f[0] != 0x20F]
        per = 5 if send_u else 4
        out[send_u] = [answers[i : i + per] for i in range(0, len(answers), per)]
    for plain, with_u in zip(out[False], out[True], strict=True):
        assert [f[0] for f in plain] == [0x208, 0x209, 0x20A, 0x20B]
        assert [f[0] for f in with_u] == [0x208, 0x209, 0x20A, 0x20C, 0x20B]
        assert plain[:3] == with_u[:3]
        assert with_u[3][1][2:] == b"\xff" * 6  # unknown, unknown, unknown
        for status in (plain[3][1], with_u[4][1]):
            assert status[3] & U_BIT == 0 and status[3] & 0x01
        assert plain[3][1][:4] == with_u[4][1][:4]  # latency and |d| may differ: same reading


@settings(max_examples=200, deadline=None)
@given(u_values, u_values, u_values, st.integers(0, 0xFFFF), st.sampled_from(list(Status)))
def test_endpoint_u_frame_is_byte_exact_against_cantools(
    ux: float, uy: float, uz: float, seq: int, status: Status
) -> None:
    """The endpoint's reply path with hypothesis U values: its five frames equal cantools
    encoding the DBC from the raw values of the rounding rule, and decode to U or more."""
    ep, bus = endpoint(send_uncertainty=True)
    try:
        pos = (123_456_789, -5, 400_000_000)
        answer = Answer(seq, status, pos, Applied.GEOMETRY, (0.0, 1.0, 0.0), "", (ux, uy, uz))
        ep._send_answer(answer, time.perf_counter())
    finally:
        ep._close()
    got = [(m.arbitration_id, bytes(m.data)) for m in bus.sent]
    assert [g[0] for g in got] == [0x208, 0x209, 0x20A, 0x20C, 0x20B]
    msg = DB.get_message_by_name("CORRECTION_UNCERTAINTY")
    raw = {"Seq": seq, "Ux": expected_raw(ux), "Uy": expected_raw(uy), "Uz": expected_raw(uz)}
    assert got[3][1] == msg.encode(raw, scaling=False)
    phys = msg.decode(got[3][1])  # cantools' own scaling and value table: never below U
    for name, u in (("Ux", ux), ("Uy", uy), ("Uz", uz)):
        if math.isnan(u) or u < 0:
            assert str(phys[name]) == "unknown"
        elif str(phys[name]) != "saturated":
            assert phys[name] >= u
        else:
            assert u > 655.33
    for axis, (cid, data) in zip(Axis, got[:3], strict=True):
        sig = DB.get_message_by_frame_id(cid).decode(data, scaling=False)
        assert sig["Seq"] == seq and sig["Position"] == pos[axis]


# --------------------------------------------------------------------------- engine
NOW_S = 1000.0


@pytest.fixture(scope="module")
def u_engine() -> Iterator[tuple[CorrectionEngine, DaemonService]]:
    cfg = base_config(channel(), u_grid_path())
    cfg.can.enabled = False
    cfg.metrics.enabled = False
    cfg.limits.error_um = 12.0  # some corners of the NPL machine exceed it: correction_limit
    with DaemonService(cfg, events_stream=None) as d:
        assert d.engine is not None
        for sensor in range(4):
            d.temperatures.update(sensor, TEMP_C, 1, True, NOW_S)
        yield d.engine, d


def test_U_is_known_only_for_a_final_status_ok(
    u_engine: tuple[CorrectionEngine, DaemonService],
) -> None:
    eng, _ = u_engine
    cases = {
        "ok": Reading(1, nm((300.0, 400.0, 200.0))),
        "outside": Reading(2, nm((950.0, 400.0, 200.0))),
        "invalid": Reading(3, nm((300.0, 400.0, 200.0)), valid=(False, True, True)),
    }
    seen = {}
    for name, r in cases.items():
        a = eng.correct(r, NOW_S)
        seen[name] = a.status
        if a.status is Status.OK:
            assert a.uncertainty_known and bool(a.applied & Applied.UNCERTAINTY)
            np.testing.assert_allclose(a.uncertainty_um, u_oracle(r.position_mm), rtol=1e-12)
        else:
            assert a.uncertainty_um is U_UNKNOWN and not a.applied & Applied.UNCERTAINTY
    assert seen == {
        "ok": Status.OK,
        "outside": Status.OUTSIDE_VOLUME,
        "invalid": Status.INVALID_READING,
    }
    # a correction refused by the limit, a stale temperature: unknown too
    corners = [(x, y, z) for x in (0.0, 900.0) for y in (0.0, 1150.0) for z in (0.0, 400.0)]
    answers = [eng.correct(Reading(9, nm(p)), NOW_S) for p in corners]
    limited = [a for a in answers if a.status is Status.CORRECTION_LIMIT]
    assert limited and all(a.uncertainty_um is U_UNKNOWN for a in limited)
    stale = eng.correct(Reading(10, nm((300.0, 400.0, 200.0))), NOW_S + 1e6)
    assert stale.status is Status.STALE_TEMPERATURE and stale.uncertainty_um is U_UNKNOWN


def test_geometry_only_answers_have_no_U() -> None:
    """on_fault = geometry_only: the thermal terms are left out, so is their U."""
    cfg = base_config(channel(), u_grid_path())
    cfg.can.enabled = False
    cfg.metrics.enabled = False
    cfg.temperatures.on_fault = "geometry_only"
    with DaemonService(cfg, events_stream=None) as d:
        assert d.engine is not None
        a = d.engine.correct(Reading(1, nm((300.0, 400.0, 200.0))), NOW_S)
    assert a.status is Status.NOT_THERMALLY_CORRECTED
    assert a.uncertainty_um is U_UNKNOWN and not a.applied & Applied.UNCERTAINTY


def test_batch_and_single_path_give_the_same_U(
    u_engine: tuple[CorrectionEngine, DaemonService],
) -> None:
    eng, _ = u_engine
    rng = np.random.default_rng(5)
    pts = rng.uniform((-40, -40, -20), (940, 1190, 420), (60, 3))
    rs = [
        Reading(i, nm((p[0], p[1], p[2])), directions=(1, -1, 0) if i % 3 else (0, 0, 0))
        for i, p in enumerate(pts)
    ]
    single = [eng.correct(r, NOW_S) for r in rs]
    batch = eng.correct_many(rs, NOW_S)
    assert batch == single
    assert {a.status for a in single} >= {Status.OK, Status.OUTSIDE_VOLUME}
    for r, a in zip(rs, single, strict=True):
        if a.status is Status.OK:
            np.testing.assert_allclose(a.uncertainty_um, u_oracle(r.position_mm), rtol=1e-12)


# --------------------------------------------------------------------------- Modbus
def _fc16(address: int, values: list[int]) -> bytes:
    return struct.pack(">BHHB", 16, address, len(values), 2 * len(values)) + struct.pack(
        f">{len(values)}H", *values
    )


def _int64_words(v: int) -> list[int]:
    return list(struct.unpack(">4H", struct.pack(">q", v)))


@contextmanager
def _modbus_only(grid_path: Path) -> Iterator[RawClient]:
    """A daemon serving Modbus only on ``grid_path``, a raw client connected, the four
    temperatures written (FC16 at 200, acknowledged)."""
    cfg = base_config(channel(), grid_path)
    cfg.can.enabled = False
    cfg.metrics.enabled = False
    cfg.modbus.enabled = True
    cfg.modbus.port = 0
    with DaemonService(cfg.check(), events_stream=None) as d:
        assert d.modbus is not None
        with RawClient(d.modbus.port) as raw:
            temps: list[int] = []
            for _ in range(4):
                temps += [*struct.unpack(">2H", struct.pack(">i", round(TEMP_C * 1000))), 1, 1]
            assert raw.request(_fc16(200, temps)) == struct.pack(">BHH", 16, 200, 16)
            yield raw


def test_modbus_raw_socket_reads_U_in_one_read_of_300_to_326() -> None:
    with _modbus_only(u_grid_path()) as raw:
        for seq, p in ((7, (450.0, 575.0, 200.0)), (8, (-30.0, 575.0, 200.0))):
            words = [w for c in nm(p) for w in _int64_words(c)] + [0, 0, 0, 0, 0, 0, 7, seq]
            assert raw.request(_fc16(100, words)) == struct.pack(">BHH", 16, 100, 20)
            resp = raw.request(struct.pack(">BHH", 3, 300, 27))
            assert resp[:2] == bytes([3, 54])
            regs = struct.unpack(">27H", resp[2:])
            assert regs[0] == seq
            ux, uy, uz = regs[24:27]
            if seq == 7:
                assert regs[1] == 0 and regs[14] & U_BIT
                for got, want in zip((ux, uy, uz), u_oracle(p), strict=True):
                    check_u(got / 100, want)
            else:
                assert regs[1] == Status.OUTSIDE_VOLUME and not regs[14] & U_BIT
                assert (ux, uy, uz) == (0xFFFF, 0xFFFF, 0xFFFF)
        # the new range as docs/modbus.md says: readable alone, read-only, nothing past it
        assert raw.request(struct.pack(">BHH", 4, 324, 3))[:2] == bytes([4, 6])
        assert raw.request(struct.pack(">BHH", 3, 324, 4)) == bytes([0x83, 0x02])
        assert raw.request(struct.pack(">BHH", 3, 327, 1)) == bytes([0x83, 0x02])
        assert raw.request(struct.pack(">BHH", 6, 325, 1)) == bytes([0x86, 0x02])
        assert raw.request(_fc16(320, [0] * 7)) == bytes([0x90, 0x02])
        version = raw.request(struct.pack(">BHH", 3, 0, 1))
        assert version == bytes([3, 2, 0, 2])  # MAP_VERSION 2


def test_modbus_registers_read_unknown_with_a_grid_without_U() -> None:
    with _modbus_only(npl_grid_path()) as raw:
        words = [w for c in nm((450.0, 575.0, 200.0)) for w in _int64_words(c)]
        raw.request(_fc16(100, [*words, 0, 0, 0, 0, 0, 0, 7, 5]))
        regs = struct.unpack(">27H", raw.request(struct.pack(">BHH", 3, 300, 27))[2:])
    assert (
        regs[0] == 5 and regs[1] == 0 and regs[14] == 0x07
    )  # geometry, scale + workpiece thermal; no U bit
    assert regs[24:27] == (0xFFFF, 0xFFFF, 0xFFFF)


# --------------------------------------------------------------------------- MCAP + replay
def test_mcap_log_validates_with_null_U_and_replay_reproduces_it(tmp_path: Path) -> None:
    cfg = base_config(channel(), u_grid_path())
    cfg.metrics.enabled = False
    cfg.mcap.path = str(tmp_path / "u.mcap")
    points = [*OK_POINTS_MM, (-30.0, 100.0, 100.0), (100.0, 1200.0, 100.0)]
    with daemon_and_controller(cfg) as (_, ctl, _bus):
        send_temps(ctl, TEMP_C)
        ctl.stream([RawReading(i + 1, p) for i, p in enumerate(points)], 0.0, in_flight=1)
    with open(cfg.mcap.path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {
            ch.topic: json.loads(summary.schemas[ch.schema_id].data)
            for ch in summary.channels.values()
        }
        msgs = [(ch.topic, json.loads(m.data)) for _, ch, m in reader.iter_messages()]
    validators = {t: jsonschema.Draft202012Validator(s) for t, s in schemas.items()}
    for s in schemas.values():
        jsonschema.Draft202012Validator.check_schema(s)
    for topic, payload in msgs:
        validators[topic].validate(payload)
    corrected = [p for t, p in msgs if t == "/cmm/corrected"]
    assert len(corrected) == len(points)
    for p in corrected:
        keys = (p["ux_um"], p["uy_um"], p["uz_um"])
        if p["status"] == "ok":
            np.testing.assert_allclose(keys, u_oracle(points[p["seq"] - 1]), rtol=1e-12)
            assert p["applied"] & U_BIT
        else:
            assert keys == (None, None, None) and not p["applied"] & U_BIT
    assert sum(p["status"] == "ok" for p in corrected) == len(OK_POINTS_MM)
    grid_msgs = [p for t, p in msgs if t == "/cmm/grid"]
    assert grid_msgs and grid_msgs[-1]["uncertainty"] is True
    # a null U is refused where the schema says number only (the validator is not lenient)
    strict = {**schemas["/cmm/corrected"]}
    strict["properties"] = {**strict["properties"], "ux_um": {"type": "number"}}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(next(p for p in corrected if p["ux_um"] is None), strict)

    same = replay_offline(cfg.mcap.path, u_grid_path())
    n_ok = len(OK_POINTS_MM)
    assert same.grid_has_uncertainty and same.readings == len(points)
    assert (same.sent_uncertainty_known, same.replayed_uncertainty_known) == (n_ok, n_ok)
    assert same.uncertainty_compared == n_ok and same.uncertainty_mismatch == 0
    assert same.max_abs_u_diff_um <= 1e-9
    other = replay_offline(cfg.mcap.path, npl_grid_path())  # a grid without U
    assert not other.grid_has_uncertainty and other.replayed_uncertainty_known == 0
    assert other.uncertainty_mismatch == n_ok and math.isnan(other.max_abs_u_diff_um)
    assert other.as_dict()["max_abs_u_diff_um"] is None  # JSON: never NaN


def test_mcap_log_of_a_grid_without_U_has_no_U_keys(tmp_path: Path) -> None:
    cfg = base_config(channel(), npl_grid_path())
    cfg.metrics.enabled = False
    cfg.mcap.path = str(tmp_path / "plain.mcap")
    with daemon_and_controller(cfg) as (_, ctl, _bus):
        send_temps(ctl, TEMP_C)
        assert ctl.exchange(RawReading(1, OK_POINTS_MM[1])).status == "ok"
    with open(cfg.mcap.path, "rb") as f:
        msgs = [(ch.topic, json.loads(m.data)) for _, ch, m in make_reader(f).iter_messages()]
    (corr,) = [p for t, p in msgs if t == "/cmm/corrected"]
    assert not {"ux_um", "uy_um", "uz_um"} & set(corr) and corr["applied"] == 0x07
    assert [p["uncertainty"] for t, p in msgs if t == "/cmm/grid"] == [False]
