"""The CAN FD pair RAW_XYZ / CORRECTED_XYZ: byte-exact against cantools on the DBC (both
directions), against the layout written out by hand in docs/can.md, and on a real python-can
bus as FD frames."""

from __future__ import annotations

import math

import can
import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_comp.protocol import (
    Applied,
    CanIds,
    CorrectedReading,
    Direction,
    MessageKind,
    RawReading,
    Status,
    dbc_text,
    decode_message,
    encode_corrected_reading,
    encode_message,
)

DB = cantools.database.load_string(dbc_text(), database_format="dbc")
RAW_MSG = DB.get_message_by_name("RAW_XYZ")
COR_MSG = DB.get_message_by_name("CORRECTED_XYZ")

u16 = st.integers(0, 0xFFFF)
int40 = st.integers(-(1 << 39), (1 << 39) - 1)
xyz = st.tuples(int40, int40, int40)
raw_readings = st.builds(
    RawReading,
    u16,
    xyz,
    st.tuples(*[st.sampled_from(Direction)] * 3),
    st.tuples(st.booleans(), st.booleans(), st.booleans()),
)
corrected_readings = st.builds(
    CorrectedReading,
    u16,
    xyz,
    st.sampled_from(Status),
    st.integers(0, 63).map(Applied),
    u16,
    u16,
    st.tuples(u16, u16, u16),
)


def test_dbc_declares_the_pair_as_can_fd_frames() -> None:
    assert (RAW_MSG.frame_id, RAW_MSG.length, RAW_MSG.is_fd) == (0x205, 20, True)
    assert (COR_MSG.frame_id, COR_MSG.length, COR_MSG.is_fd) == (0x20D, 32, True)
    assert RAW_MSG.senders == ["Controller"] and COR_MSG.senders == ["Daemon"]


@settings(max_examples=300, deadline=None)
@given(raw_readings)
def test_raw_reading_matches_cantools_both_ways(r: RawReading) -> None:
    sig = DB.decode_message(RAW_MSG.frame_id, r.encode(), decode_choices=False, scaling=False)
    assert (sig["PositionX"], sig["PositionY"], sig["PositionZ"]) == r.position_nm
    assert sig["Seq"] == r.seq
    assert (sig["DirectionX"], sig["DirectionY"], sig["DirectionZ"]) == tuple(
        int(d) for d in r.directions
    )
    assert (sig["ValidX"], sig["ValidY"], sig["ValidZ"]) == tuple(int(v) for v in r.valid)
    assert RawReading.decode(RAW_MSG.encode(sig, scaling=False)) == r


@settings(max_examples=300, deadline=None)
@given(corrected_readings)
def test_corrected_reading_matches_cantools_both_ways(c: CorrectedReading) -> None:
    sig = DB.decode_message(COR_MSG.frame_id, c.encode(), decode_choices=False, scaling=False)
    assert (sig["PositionX"], sig["PositionY"], sig["PositionZ"]) == c.position_nm
    assert (sig["Seq"], sig["Status"], sig["Applied"]) == (c.seq, int(c.status), int(c.applied))
    assert (sig["Latency"], sig["Correction"]) == (c.latency_us, c.correction_10nm)
    assert (sig["Ux"], sig["Uy"], sig["Uz"]) == c.u_10nm
    assert CorrectedReading.decode(COR_MSG.encode(sig, scaling=False)) == c


def test_raw_reading_bytes_as_docs_can_md_lays_them_out() -> None:
    r = RawReading(
        0x1234,
        (1, -1, 0x0102030405),
        (Direction.POSITIVE, Direction.NEGATIVE, Direction.UNKNOWN),
        (True, False, True),
    )
    want = bytes.fromhex(
        "0100000000"  # X = 1 nm
        "ffffffffff"  # Y = -1 nm
        "0504030201"  # Z, little-endian
        "3412"  # seq
        "09"  # directions: X positive (1), Y negative (2 << 2)
        "05"  # valid: X and Z
        "00"  # reserved
    )
    assert r.encode() == want
    msg = encode_message(r, CanIds())
    assert (msg.arbitration_id, msg.is_fd, msg.dlc) == (0x205, True, 20)


def test_fast_answer_encoder_equals_the_frame_and_rounds_u_up() -> None:
    """The daemon's reply-path packer against the frame class and cantools' physical values."""
    payload = encode_corrected_reading(
        7, int(Status.OK), int(Applied.GEOMETRY), (10, -20, 30), 123.4, 1.234, (0.001, 0.0, 700.0)
    )
    frame = CorrectedReading.decode(payload)
    assert frame == CorrectedReading(
        7, (10, -20, 30), Status.OK, Applied.GEOMETRY, 123, 123, (1, 0, 0xFFFE)
    )
    phys = DB.decode_message(COR_MSG.frame_id, payload, decode_choices=False)
    assert phys["Ux"] >= 0.001 and phys["Ux"] == pytest.approx(0.01)  # never below U
    assert phys["Correction"] == pytest.approx(1.23)
    assert math.isinf(frame.u_um[2]) and not frame.u_known
    unknown = CorrectedReading.decode(
        encode_corrected_reading(7, int(Status.NO_GRID), 0, (1, 2, 3), 0.0, 0.0, None)
    )
    assert unknown.u_10nm == (0xFFFF,) * 3 and all(math.isnan(u) for u in unknown.u_um)


def test_bad_values_are_clear_errors() -> None:
    with pytest.raises(ValueError, match=r"position_nm Y .* out of range"):
        RawReading(0, (0, 1 << 40, 0))
    with pytest.raises(ValueError, match="must be 20 bytes"):
        RawReading.decode(bytes(8))
    bad_direction = bytearray(RawReading(0, (0, 0, 0)).encode())
    bad_direction[17] = 3 << 2  # Y: code 3
    with pytest.raises(ValueError, match="direction code 3 of Y"):
        RawReading.decode(bytes(bad_direction))
    msg = can.Message(arbitration_id=0x205, data=bytes(8), is_extended_id=False)
    result = decode_message(msg, CanIds())
    assert result.reason == "RAW_XYZ needs 20 data bytes, got 8"  # type: ignore[union-attr]


def test_pair_travels_as_fd_frames_on_a_python_can_bus() -> None:
    ids = CanIds(node_id=2)
    r = RawReading(5, (1_000_000, 2_000_000, -3), (Direction.NEGATIVE,) * 3)
    c = CorrectedReading(5, (1_000_001, 2_000_002, -4), Status.OK, Applied.GEOMETRY, 80, 141)
    with (
        can.Bus(interface="virtual", channel="fd-test", fd=True) as tx,
        can.Bus(
            interface="virtual", channel="fd-test", fd=True, can_filters=ids.can_filters()
        ) as rx,
    ):
        tx.send(encode_message(r, ids))
        tx.send(encode_message(c, ids))
        got = [rx.recv(1.0), rx.recv(1.0)]
    assert all(m is not None and m.is_fd for m in got)
    assert [decode_message(m, ids) for m in got] == [r, c]  # type: ignore[arg-type]
    assert ids.kind_of(got[0].arbitration_id) is MessageKind.RAW_XYZ  # type: ignore[union-attr]
