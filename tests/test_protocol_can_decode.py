"""decode_message: typed results for every input, never an exception."""

from __future__ import annotations

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_comp.protocol import (
    Axis,
    BadLength,
    BadValue,
    CanIds,
    CorrectedReading,
    CorrectionStatus,
    Direction,
    Heartbeat,
    MessageKind,
    NotData,
    RawAxis,
    RawReading,
    TemperatureSample,
    UnknownId,
    decode_message,
    encode_message,
)
from cmm_comp.protocol.can_frames import FRAME_CLASS, PAYLOAD_SIZES

USED_BITS: dict[type, tuple[tuple[int, int], ...]] = {
    RawAxis: ((7, 0x1F),),
    TemperatureSample: ((1, 0x01),),
    CorrectionStatus: ((3, 0x3F),),
    RawReading: ((17, 0x3F), (18, 0x07), (19, 0x00)),
    CorrectedReading: ((18, 0x3F), (19, 0x00), (30, 0x00), (31, 0x00)),
}
"""(byte index, mask of defined bits) for the frames that have reserved bits (docs/can.md)."""


def clear_reserved(cls: type, data: bytes) -> bytes:
    out = bytearray(data)
    for index, used in USED_BITS.get(cls, ()):
        out[index] &= used
    return bytes(out)


TYPED = (*set(FRAME_CLASS.values()), UnknownId, NotData, BadLength, BadValue)


@settings(max_examples=1500, deadline=None)
@given(
    node=st.integers(0, 3),
    can_id=st.one_of(st.integers(0x200, 0x23F), st.integers(0, 0x1FFFFFFF)),
    extended=st.booleans(),
    data=st.binary(min_size=0, max_size=64),
    remote=st.booleans(),
    error=st.booleans(),
    fd=st.booleans(),
)
def test_fuzz_never_raises_and_is_typed(
    node: int, can_id: int, extended: bool, data: bytes, remote: bool, error: bool, fd: bool
) -> None:
    extended = extended or can_id > 0x7FF
    msg = can.Message(
        arbitration_id=can_id,
        is_extended_id=extended,
        data=data,
        is_remote_frame=remote and not fd,
        is_error_frame=error,
        is_fd=fd,
        check=False,
    )
    result = decode_message(msg, CanIds(node_id=node))
    assert isinstance(result, TYPED)
    if isinstance(result, (BadLength, BadValue, UnknownId)):
        assert result.reason
    if not isinstance(result, (UnknownId, NotData, BadLength, BadValue)):
        # re-encoding gives the payload with its reserved bits cleared (docs/can.md)
        assert result.encode() == clear_reserved(type(result), bytes(data))


@settings(max_examples=500, deadline=None)
@given(st.sampled_from(MessageKind), st.data())
def test_any_payload_of_the_right_length_on_a_known_id_is_frame_or_bad_value(
    kind: MessageKind, draw: st.DataObject
) -> None:
    size = PAYLOAD_SIZES[kind]  # 8; the CAN FD pair: 20 and 32
    data = draw.draw(st.binary(min_size=size, max_size=size))
    ids = CanIds()
    msg = can.Message(
        arbitration_id=ids.id_of(kind), data=data, is_extended_id=False, is_fd=size > 8
    )
    result = decode_message(msg, ids)
    assert isinstance(result, (FRAME_CLASS[kind], BadValue))


def test_specific_results() -> None:
    ids = CanIds(node_id=1)
    raw_y = RawAxis(Axis.Y, 9, 123, Direction.POSITIVE)
    assert decode_message(encode_message(raw_y, ids), ids) == raw_y
    # not ours: other node, extended id, unused offset in our block
    assert decode_message(encode_message(raw_y, CanIds(node_id=2)), ids) == UnknownId(0x221, False)
    assert decode_message(can.Message(arbitration_id=0x211, is_extended_id=True), ids) == UnknownId(
        0x211, True
    )
    unused = can.Message(arbitration_id=0x216, data=b"\0" * 8, is_extended_id=False)
    assert decode_message(unused, ids) == UnknownId(0x216, False)
    # remote and error frames
    rtr = decode_message(
        can.Message(arbitration_id=0x21F, is_extended_id=False, is_remote_frame=True, dlc=8), ids
    )
    assert rtr == NotData(0x21F, MessageKind.HEARTBEAT, "remote frame on HEARTBEAT")
    err = decode_message(can.Message(is_error_frame=True, arbitration_id=0x210), ids)
    assert err == NotData(0x210, None, "error frame")
    # length
    short = decode_message(
        can.Message(arbitration_id=0x214, data=b"\1\2\3", is_extended_id=False), ids
    )
    assert short == BadLength(0x214, MessageKind.TEMPERATURE, 8, 3)
    assert short.reason == "TEMPERATURE needs 8 data bytes, got 3"
    # payload axis field disagrees with the id: a RAW_Y payload sent on RAW_X
    wrong = can.Message(
        arbitration_id=ids.raw_id(Axis.X), data=raw_y.encode(), is_extended_id=False
    )
    result = decode_message(wrong, ids)
    assert isinstance(result, BadValue) and "axis field says Y, id says RAW_X" in result.reason
    # undefined code
    bad_state = can.Message(arbitration_id=0x21F, data=bytes([7]) + b"\0" * 7, is_extended_id=False)
    result = decode_message(bad_state, ids)
    assert isinstance(result, BadValue) and "state code 7 is not defined" in result.reason


def test_fd_message_with_an_8_byte_payload_decodes() -> None:
    ids = CanIds()
    t = TemperatureSample(2, 21_000, 5)
    msg = can.Message(arbitration_id=0x204, data=t.encode(), is_fd=True, is_extended_id=False)
    assert decode_message(msg, ids) == t


def test_ids_helpers() -> None:
    ids = CanIds(node_id=2)
    assert ids.id_of(MessageKind.HEARTBEAT) == 0x22F
    assert ids.kind_of(0x22B) is MessageKind.CORRECTION_STATUS
    assert ids.kind_of(0x22C) is MessageKind.CORRECTION_UNCERTAINTY
    assert (
        ids.kind_of(0x22D) is MessageKind.CORRECTED_XYZ
        and ids.kind_of(0x225) is MessageKind.RAW_XYZ
    )
    assert ids.kind_of(0x22E) is None and ids.kind_of(0x21B) is None
    assert ids.controller_tx_ids() == {0x220, 0x221, 0x222, 0x223, 0x224, 0x225}
    assert ids.daemon_tx_ids() == {0x228, 0x229, 0x22A, 0x22B, 0x22C, 0x22D, 0x22F}
    assert ids.can_filters() == [{"can_id": 0x220, "can_mask": 0x7F0, "extended": False}]
    assert Heartbeat.kind is MessageKind.HEARTBEAT


def test_virtual_bus_round_trip_with_node_filter() -> None:
    """A real python-can bus carries our frames; the node filter passes only our block."""
    ids = CanIds(node_id=1)
    frames = [RawAxis(a, 1, 10 * int(a)) for a in Axis]
    with (
        can.Bus(interface="virtual", channel="protocol-test", receive_own_messages=False) as tx,
        can.Bus(interface="virtual", channel="protocol-test", can_filters=ids.can_filters()) as rx,
    ):
        tx.send(encode_message(RawAxis(Axis.X, 1, 1), CanIds(node_id=0)))  # other machine
        for f in frames:
            tx.send(encode_message(f, ids))
        got = [decode_message(rx.recv(timeout=1.0), ids) for _ in frames]  # type: ignore[arg-type]
        assert rx.recv(timeout=0.01) is None
    assert got == frames


@pytest.mark.parametrize("kind", list(MessageKind))
def test_every_kind_has_a_frame_class(kind: MessageKind) -> None:
    assert kind in FRAME_CLASS


_NODE = CanIds(node_id=3)


@settings(max_examples=400, deadline=None)
@given(
    offset=st.integers(-2, 18),
    extended=st.booleans(),
    remote=st.booleans(),
    error=st.booleans(),
    data=st.binary(min_size=0, max_size=9),
    raw_like=st.booleans(),
)
def test_raw_axis_fast_path_is_decode_message_or_nothing(
    offset: int, extended: bool, remote: bool, error: bool, data: bytes, raw_like: bool
) -> None:
    """The daemon's hot-path decoder (RawAxisDecoder) answers only clean RAW_X/Y/Z frames and
    then exactly what decode_message answers (the oracle); everything else it leaves to it."""
    from cmm_comp.protocol.can_codec import RawAxisDecoder

    fast = RawAxisDecoder(_NODE)
    if raw_like:  # mostly well-formed raw axis frames on the right id
        extended = remote = error = False
        offset = offset % 3
        data = (data + bytes(8))[:7] + bytes([offset | (data[:1] or b"\0")[0] & 0x1C])
    msg = can.Message(
        arbitration_id=_NODE.block_start + offset if offset >= 0 else 0x100,
        is_extended_id=extended,
        is_remote_frame=remote and not error,
        is_error_frame=error,
        data=None if remote and not error else data,
        dlc=len(data),
        check=False,
    )
    got = fast(msg)
    ref = decode_message(msg, _NODE)
    if got is not None:
        assert got == ref
    else:
        assert not isinstance(ref, RawAxis)
