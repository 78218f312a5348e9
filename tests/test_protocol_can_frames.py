"""CAN frames: round trips, byte-exact cross-check against cantools on the DBC, golden frames."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_comp.protocol import (
    Applied,
    Axis,
    CanIds,
    CorrectedAxis,
    CorrectionStatus,
    CorrectionUncertainty,
    DaemonState,
    Direction,
    Frame,
    Heartbeat,
    MessageKind,
    ProbeDirection,
    RawAxis,
    Status,
    TemperatureSample,
    dbc_text,
    decode_message,
    encode_message,
    grid_id_from_sha256,
    sent_by_daemon,
)
from cmm_comp.protocol.can_frames import PAYLOAD_SIZES

GOLDEN = Path(__file__).parent / "data" / "protocol_golden_frames.json"
DB = cantools.database.load_string(dbc_text(), database_format="dbc")

u16 = st.integers(0, 0xFFFF)
int40 = st.integers(-(1 << 39), (1 << 39) - 1)
i16 = st.integers(-0x8000, 0x7FFF)

raw_axes = st.builds(
    RawAxis, st.sampled_from(Axis), u16, int40, st.sampled_from(Direction), st.booleans()
)
corrected_axes = st.builds(
    CorrectedAxis, st.sampled_from(Axis), u16, int40, st.sampled_from(Status)
)
probe_dirs = st.builds(ProbeDirection, u16, i16, i16, i16)
temps = st.builds(
    TemperatureSample,
    st.integers(0, 255),
    st.integers(-(1 << 31), (1 << 31) - 1),
    u16,
    st.booleans(),
)
statuses = st.builds(
    CorrectionStatus, u16, st.sampled_from(Status), st.integers(0, 63).map(Applied), u16, u16
)
uncertainties = st.builds(CorrectionUncertainty, u16, u16, u16, u16)
heartbeats = st.builds(Heartbeat, st.sampled_from(DaemonState), u16, u16, st.integers(0, 2**24 - 1))
frames = st.one_of(raw_axes, corrected_axes, probe_dirs, temps, statuses, uncertainties, heartbeats)


def expected_signals(frame: Frame) -> dict[str, int]:
    """Raw signal values the DBC must show for ``frame`` (written from docs/can.md)."""
    if isinstance(frame, RawAxis):
        return {
            "Position": frame.position_nm,
            "Seq": frame.seq,
            "Axis": int(frame.axis),
            "Direction": int(frame.direction),
            "Valid": int(frame.valid),
        }
    if isinstance(frame, CorrectedAxis):
        return {
            "Position": frame.position_nm,
            "Seq": frame.seq,
            "Axis": int(frame.axis),
            "Status": int(frame.status),
        }
    if isinstance(frame, ProbeDirection):
        return {"Seq": frame.seq, "Nx": frame.nx_raw, "Ny": frame.ny_raw, "Nz": frame.nz_raw}
    if isinstance(frame, TemperatureSample):
        return {
            "Sensor": frame.sensor,
            "Valid": int(frame.valid),
            "Counter": frame.counter,
            "Temperature": frame.temp_mC,
        }
    if isinstance(frame, CorrectionStatus):
        return {
            "Seq": frame.seq,
            "Status": int(frame.status),
            "Applied": int(frame.applied),
            "Latency": frame.latency_us,
            "Correction": frame.correction_10nm,
        }
    if isinstance(frame, CorrectionUncertainty):
        return {"Seq": frame.seq, "Ux": frame.ux_10nm, "Uy": frame.uy_10nm, "Uz": frame.uz_10nm}
    assert isinstance(frame, Heartbeat)
    return {
        "State": int(frame.state),
        "Answered": frame.answered,
        "NotOk": frame.not_ok,
        "GridId": frame.grid_id,
    }


@settings(max_examples=300, deadline=None)
@given(frames)
def test_round_trip(frame: Frame) -> None:
    data = frame.encode()
    assert len(data) == 8
    assert type(frame).decode(data) == frame
    assert type(frame).decode(bytearray(data)) == frame


@settings(max_examples=300, deadline=None)
@given(frames)
def test_ours_to_cantools_and_back_byte_exact(frame: Frame) -> None:
    ids = CanIds()
    msg = DB.get_message_by_frame_id(ids.id_of(frame.kind))
    data = frame.encode()
    decoded = msg.decode(data, decode_choices=False, scaling=False)
    assert decoded == expected_signals(frame)
    assert msg.encode(expected_signals(frame), scaling=False) == data


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_cantools_to_ours(data: st.DataObject) -> None:
    """cantools encodes random raw signal values; our decode must agree field by field."""
    frame = data.draw(frames)
    msg = DB.get_message_by_frame_id(CanIds().id_of(frame.kind))
    payload = msg.encode(expected_signals(frame), scaling=False)
    assert type(frame).decode(payload) == frame


@settings(max_examples=100, deadline=None)
@given(st.one_of(raw_axes, temps, probe_dirs, statuses))
def test_physical_values_match_dbc_scaling(frame: Frame) -> None:
    msg = DB.get_message_by_frame_id(CanIds().id_of(frame.kind))
    phys = msg.decode(frame.encode(), decode_choices=False)
    if isinstance(frame, RawAxis):
        assert phys["Position"] == pytest.approx(frame.position_mm, abs=1e-9)
    elif isinstance(frame, TemperatureSample):
        assert phys["Temperature"] == pytest.approx(frame.temp_C, abs=1e-9)
    elif isinstance(frame, ProbeDirection):
        assert (phys["Nx"], phys["Ny"], phys["Nz"]) == frame.unit_vector  # 2**-14 is exact
    else:
        assert isinstance(frame, CorrectionStatus)
        assert phys["Correction"] == pytest.approx(frame.correction_um, abs=1e-9)


def test_dbc_lists_every_message_kind_once() -> None:
    assert sorted(m.frame_id for m in DB.messages) == sorted(0x200 + k for k in MessageKind)
    for kind in MessageKind:
        assert DB.get_message_by_frame_id(0x200 + kind).name == kind.name
        size = PAYLOAD_SIZES[kind]  # 8, the CAN FD pair 20 and 32
        assert DB.get_message_by_frame_id(0x200 + kind).length == size
        assert DB.get_message_by_frame_id(0x200 + kind).is_fd == (size > 8)
    assert {k.name for k in MessageKind if PAYLOAD_SIZES[k] > 8} == {"RAW_XYZ", "CORRECTED_XYZ"}


def test_dbc_status_names_are_the_status_labels() -> None:
    choices = DB.get_message_by_name("CORRECTION_STATUS").get_signal_by_name("Status").choices
    assert {int(k): str(v) for k, v in choices.items()} == {int(s): s.label for s in Status}
    assert Status.OK.label == "ok" and Status.from_label("outside_volume") is Status.OUTSIDE_VOLUME
    with pytest.raises(ValueError, match="unknown status 'fine'; allowed: ok, outside_volume"):
        Status.from_label("fine")


def test_dbc_shifted_to_another_node() -> None:
    db3 = cantools.database.load_string(dbc_text(CanIds(node_id=3)), database_format="dbc")
    assert db3.get_message_by_name("HEARTBEAT").frame_id == 0x23F
    assert db3.get_message_by_name("RAW_X").frame_id == 0x230
    # comments and value tables moved with their messages
    assert db3.get_message_by_name("HEARTBEAT").comment.startswith("Daemon heartbeat")
    assert db3.get_message_by_name("RAW_Y").get_signal_by_name("Direction").choices[1] == "positive"


@pytest.mark.parametrize(("node_id", "base_id"), [(0, 0x200), (3, 0x200), (5, 0x100), (0, 0)])
def test_sent_by_daemon_follows_the_dbc_transmitters(node_id: int, base_id: int) -> None:
    """Replay's rule for logs without a frame direction: the DBC's transmitter of each message
    (cantools), for any node and base id; every other id of the standard range, extended ids
    and ids of other kinds are not the daemon's."""
    db = cantools.database.load_string(
        dbc_text(CanIds(node_id=node_id, base_id=base_id)), database_format="dbc"
    )
    daemon_ids = set()
    for msg in db.messages:
        assert msg.senders in (["Daemon"], ["Controller"])
        assert sent_by_daemon(msg.frame_id) == (msg.senders == ["Daemon"]), msg.name
        assert not sent_by_daemon(msg.frame_id, is_extended=True)
        if msg.senders == ["Daemon"]:
            daemon_ids.add(msg.frame_id)
    block = CanIds(node_id=node_id, base_id=base_id).block_start
    in_block = {i for i in range(block, block + 16) if sent_by_daemon(i)}
    assert in_block == daemon_ids
    assert not sent_by_daemon(-1) and not sent_by_daemon(0x800)


def _golden() -> list[dict[str, Any]]:
    return json.loads(GOLDEN.read_text(encoding="utf-8"))["frames"]


def _frame_from_fields(kind: str, fields: dict[str, Any]) -> Frame:
    enums = {"axis": Axis, "direction": Direction, "status": Status, "state": DaemonState}
    args = {k: enums[k][v] if k in enums else v for k, v in fields.items()}
    cls = {
        c.__name__: c
        for c in (RawAxis, CorrectedAxis, ProbeDirection, TemperatureSample, CorrectionStatus)
    }
    cls["Heartbeat"] = Heartbeat
    if kind == "CorrectionStatus":
        args["applied"] = Applied(args["applied"])
    return cls[kind](**args)


@pytest.mark.parametrize("golden", _golden(), ids=lambda g: g["name"])
def test_golden_frames(golden: dict[str, Any]) -> None:
    ids = CanIds(node_id=golden["node_id"])
    frame = _frame_from_fields(golden["type"], golden["fields"])
    msg = encode_message(frame, ids)
    assert msg.arbitration_id == int(golden["can_id"], 16)
    assert bytes(msg.data) == bytes.fromhex(golden["data"])
    assert decode_message(msg, ids) == frame


@pytest.mark.parametrize("golden", _golden(), ids=lambda g: g["name"])
def test_golden_frames_agree_with_cantools(golden: dict[str, Any]) -> None:
    db = cantools.database.load_string(
        dbc_text(CanIds(node_id=golden["node_id"])), database_format="dbc"
    )
    msg = db.get_message_by_frame_id(int(golden["can_id"], 16))
    frame = _frame_from_fields(golden["type"], golden["fields"])
    got = msg.decode(bytes.fromhex(golden["data"]), decode_choices=False, scaling=False)
    assert got == expected_signals(frame)


def test_physical_helpers() -> None:
    assert TemperatureSample.from_celsius(1, 20.1234).temp_mC == 20123
    p = ProbeDirection.from_unit_vector(3, (0.0, -1.0, 0.5))
    assert (p.nx_raw, p.ny_raw, p.nz_raw) == (0, -16384, 8192) and p.present
    assert not ProbeDirection(3, 0, 0, 0).present
    assert RawAxis(Axis.X, 0, 1_234_567).position_mm == pytest.approx(1.234567)
    assert Direction.NEGATIVE.sign == -1 and Direction.from_sign(1) is Direction.POSITIVE
    hb = Heartbeat.with_grid_sha256(DaemonState.READY, 70000, 3, "a1b2c3" + "0" * 58)
    assert (hb.answered, hb.grid_id) == (70000 - 65536, 0xA1B2C3)
    assert grid_id_from_sha256("f" * 64) == 0xFFFFFF


@pytest.mark.parametrize(
    ("build", "match"),
    [
        (lambda: RawAxis(Axis.X, 70000, 0), r"seq 70000 out of range 0\.\.65535"),
        (lambda: RawAxis(Axis.X, 0, 1 << 39), r"position_nm 549755813888 out of range"),
        (lambda: RawAxis(3, 0, 0), r"axis code 3 is not defined; allowed: 0 \(x\)"),  # type: ignore[arg-type]
        (lambda: CorrectedAxis(Axis.X, 0, 0, 17), r"status code 17 is not defined"),  # type: ignore[arg-type]
        (lambda: TemperatureSample(256, 0), r"sensor 256 out of range 0\.\.255"),
        (lambda: ProbeDirection(0, 0x8000, 0, 0), r"nx_raw 32768 out of range"),
        (lambda: CorrectionStatus(0, Status.OK, latency_us=-1), r"latency_us -1 out of range"),
        (lambda: Heartbeat(DaemonState.READY, grid_id=1 << 24), r"grid_id 16777216 out of range"),
        (lambda: Heartbeat(9), r"state code 9 is not defined"),  # type: ignore[arg-type]
        (lambda: CanIds(node_id=96), r"node_id 96 out of range 0\.\.95"),
        (lambda: CanIds(base_id=0x205), r"base_id 0x205 must be a non-negative multiple of 0x10"),
    ],
)
def test_invalid_values_are_rejected_with_a_clear_message(build: Any, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        build()


@pytest.mark.parametrize(
    ("cls", "data", "match"),
    [
        (RawAxis, b"\x00" * 7, r"RawAxis payload must be 8 bytes, got 7"),
        (RawAxis, bytes.fromhex("000000000000000f"), r"direction code 3 is not defined"),
        (RawAxis, bytes.fromhex("0000000000000003"), r"axis code 3 is not defined"),
        (CorrectedAxis, bytes.fromhex("0000000000000040"), r"status code 16 is not defined"),
        (Heartbeat, bytes.fromhex("0600000000000000"), r"state code 6 is not defined"),
    ],
)
def test_decode_rejects_bad_payloads(cls: type, data: bytes, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        cls.decode(data)


def test_reserved_bits_are_ignored_on_decode_and_zero_on_encode() -> None:
    frame = RawAxis.decode(bytes.fromhex("40420f00000100f4"))  # 0x14 plus reserved bits 5-7
    assert frame == RawAxis(Axis.X, 1, 1_000_000, Direction.POSITIVE, True)
    assert frame.encode() == bytes.fromhex("40420f0000010014")
    status = CorrectionStatus.decode(bytes.fromhex("01000083fa007b00"))
    assert status.applied == Applied.GEOMETRY | Applied.SCALE_THERMAL


@given(pos=int40, seq=u16, flags=st.integers(0, 255))
def test_raw_axis_fast_decode_equals_the_validating_constructor(
    pos: int, seq: int, flags: int
) -> None:
    """RawAxis.decode skips __init__ on its hot path; the validating constructor (and the
    bit layout written out here) is the oracle, for every flags byte."""
    data = pos.to_bytes(5, "little", signed=True) + seq.to_bytes(2, "little") + bytes([flags])
    try:
        expected: RawAxis | str = RawAxis(
            Axis(flags & 3), seq, pos, Direction(flags >> 2 & 3), bool(flags >> 4 & 1)
        )
    except ValueError:
        expected = "ValueError"
    try:
        got: RawAxis | str = RawAxis.decode(data)
    except ValueError as exc:
        got = "ValueError"
        assert ("direction code" if flags >> 2 & 3 == 3 else "axis code") in str(exc)
    assert got == expected
    if isinstance(got, RawAxis):
        assert type(got.axis) is Axis and type(got.direction) is Direction
        assert hash(got) == hash(expected) and got.encode() == data[:7] + bytes([flags & 0x1F])
