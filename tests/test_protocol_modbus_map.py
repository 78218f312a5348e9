"""Modbus register map: codecs round trip, word order against pymodbus' converter, validation."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymodbus.client.mixin import ModbusClientMixin

from cmm_comp.protocol import (
    AnswerBlock,
    Applied,
    DaemonBlock,
    DaemonState,
    Direction,
    ExceptionCode,
    ReadingBlock,
    Status,
    TemperatureSlot,
    check_request,
    check_write,
    commits_reading,
    decode_output,
)
from cmm_comp.protocol import modbus_map as mm
from cmm_comp.protocol.modbus_codec import int_from_registers, int_to_registers

DT = ModbusClientMixin.DATATYPE
i64 = st.integers(-(1 << 63), (1 << 63) - 1)
u16 = st.integers(0, 0xFFFF)
vec3 = st.tuples(i64, i64, i64)
readings = st.builds(
    ReadingBlock,
    u16,
    vec3,
    st.tuples(*[st.sampled_from(Direction)] * 3),
    st.tuples(*[st.integers(-0x8000, 0x7FFF)] * 3),
    st.tuples(st.booleans(), st.booleans(), st.booleans()),
)
answers = st.builds(
    AnswerBlock,
    u16,
    st.sampled_from(Status),
    vec3,
    st.integers(0, 63).map(Applied),
    u16,
    u16,
    st.tuples(u16, u16, u16),
)
daemons = st.builds(
    DaemonBlock, st.sampled_from(DaemonState), u16, u16, st.integers(0, 2**24 - 1), u16, u16
)


def test_layout_constants_are_consistent() -> None:
    assert mm.REG_SEQ == mm.READING_START + mm.READING_SIZE - 1  # SEQ last: one write commits
    assert mm.DAEMON_START == mm.ANSWER_START + mm.ANSWER_SIZE  # one read of 300..326
    assert mm.UNCERTAINTY_START == mm.DAEMON_START + mm.DAEMON_SIZE
    assert mm.OUTPUT_SIZE == 27 and mm.OUTPUT_SIZE_V1 == 24
    assert mm.temperature_address(15) + 4 == mm.TEMPERATURE_START + mm.TEMPERATURE_SIZE
    starts = [b.start for b in mm.BLOCKS]
    assert starts == sorted(starts)
    assert all(a.stop <= b.start for a, b in zip(mm.BLOCKS, mm.BLOCKS[1:], strict=False))


@settings(max_examples=200, deadline=None)
@given(readings)
def test_reading_round_trip_and_word_order(reading: ReadingBlock) -> None:
    regs = reading.to_registers()
    assert len(regs) == mm.READING_SIZE and all(0 <= r <= 0xFFFF for r in regs)
    assert ReadingBlock.from_registers(regs) == reading
    # independent oracle: pymodbus' own INT64/INT16 converter, big-endian word order
    for i, value in enumerate(reading.position_nm):
        off = mm.REG_X_NM - mm.READING_START + 4 * i
        assert regs[off : off + 4] == ModbusClientMixin.convert_to_registers(value, DT.INT64, "big")
    for i, value in enumerate(reading.probe_raw):
        off = mm.REG_PROBE_NX - mm.READING_START + i
        assert regs[off : off + 1] == ModbusClientMixin.convert_to_registers(value, DT.INT16)
    assert regs[-1] == reading.seq
    assert check_write(16, mm.READING_START, regs) is None


@settings(max_examples=200, deadline=None)
@given(answers, daemons)
def test_output_round_trip(answer: AnswerBlock, daemon: DaemonBlock) -> None:
    regs = answer.to_registers() + daemon.to_registers() + answer.uncertainty_registers()
    assert decode_output(regs) == (answer, daemon)
    cx = ModbusClientMixin.convert_from_registers(regs[2:6], DT.INT64, "big")
    assert cx == answer.position_nm[0]
    grid = ModbusClientMixin.convert_from_registers(regs[20:22], DT.UINT32, "big")
    assert grid == daemon.grid_id
    assert tuple(regs[24:27]) == answer.uncertainty_10nm  # 324..326
    # a map-version-1 read (300..323) still decodes, U unknown
    old, _ = decode_output(regs[:24])
    assert old.uncertainty_10nm == (0xFFFF,) * 3 and old.position_nm == answer.position_nm


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 15), st.integers(-(1 << 31), (1 << 31) - 1), st.booleans(), u16)
def test_temperature_slot_round_trip(sensor: int, temp: int, valid: bool, counter: int) -> None:
    slot = TemperatureSlot(sensor, temp, valid, counter)
    regs = slot.to_registers()
    assert TemperatureSlot.from_registers(sensor, regs) == slot
    assert regs[:2] == ModbusClientMixin.convert_to_registers(temp, DT.INT32, "big")
    assert check_write(16, slot.address, regs) is None


def test_hand_computed_registers() -> None:
    """Worked example from docs/modbus.md."""
    reading = ReadingBlock.from_mm(
        0x1234, (1.0, -0.000001, 2500.0), directions=(1, -1, 0), probe=(0.0, 0.0, -1.0)
    )
    assert reading.to_registers() == [
        0x0000, 0x0000, 0x000F, 0x4240,  # X 1 000 000 nm
        0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF,  # Y −1 nm
        0x0000, 0x0000, 0x9502, 0xF900,  # Z 2 500 000 000 nm
        1, 2, 0,                         # directions +, −, unknown
        0x0000, 0x0000, 0xC000,          # probe (0, 0, −1) · 2**14
        0x0007,                          # X, Y, Z valid
        0x1234,                          # seq (commit)
    ]  # fmt: skip
    slot = TemperatureSlot(3, 20_125, True, 258)
    assert slot.address == 212 and slot.to_registers() == [0x0000, 0x4E9D, 1, 258]
    assert TemperatureSlot(0, -5_500).to_registers()[:2] == [0xFFFF, 0xEA84]
    assert reading.position_mm == pytest.approx((1.0, -0.000001, 2500.0))


def test_int_registers_helpers() -> None:
    assert int_to_registers(-2, 2) == [0xFFFF, 0xFFFE]
    assert int_from_registers([0xFFFF, 0xFFFE]) == -2
    assert int_from_registers([0xFFFF, 0xFFFE], signed=False) == 0xFFFFFFFE
    with pytest.raises(ValueError, match="70000 does not fit uint16"):
        int_to_registers(70000, 1, signed=False)
    with pytest.raises(ValueError, match=r"register value 65536 out of range 0\.\.65535"):
        int_from_registers([65536])


@pytest.mark.parametrize(
    ("fc", "address", "count", "expected"),
    [
        (3, 0, 3, None),
        (4, 0, 3, None),
        (3, 300, 24, None),  # ANSWER + DAEMON in one read (map version 1)
        (3, 300, 27, None),  # ANSWER + DAEMON + UNCERTAINTY (version 2)
        (4, 324, 3, None),
        (3, 326, 1, None),
        (3, 100, 20, None),  # reading back what was written is allowed
        (3, 200, 64, None),
        (16, 100, 20, None),
        (6, 119, 1, None),
        (16, 212, 4, None),
        (3, 0, 4, ExceptionCode.ILLEGAL_DATA_ADDRESS),  # runs past INFO
        (3, 50, 1, ExceptionCode.ILLEGAL_DATA_ADDRESS),  # gap
        (3, 300, 28, ExceptionCode.ILLEGAL_DATA_ADDRESS),  # past UNCERTAINTY
        (3, 327, 1, ExceptionCode.ILLEGAL_DATA_ADDRESS),
        (16, 324, 1, ExceptionCode.ILLEGAL_DATA_ADDRESS),  # UNCERTAINTY is read-only
        (6, 326, 1, ExceptionCode.ILLEGAL_DATA_ADDRESS),
        (3, 110, 100, ExceptionCode.ILLEGAL_DATA_ADDRESS),  # READING..gap..TEMPERATURE
        (3, 65535, 1, ExceptionCode.ILLEGAL_DATA_ADDRESS),
        (16, 300, 1, ExceptionCode.ILLEGAL_DATA_ADDRESS),  # ANSWER is read-only
        (6, 0, 1, ExceptionCode.ILLEGAL_DATA_ADDRESS),  # INFO is read-only
        (16, 118, 3, ExceptionCode.ILLEGAL_DATA_ADDRESS),  # runs off READING
        (3, 0, 0, ExceptionCode.ILLEGAL_DATA_VALUE),
        (3, 200, 126, ExceptionCode.ILLEGAL_DATA_VALUE),
        (16, 200, 124, ExceptionCode.ILLEGAL_DATA_VALUE),
        (6, 100, 2, ExceptionCode.ILLEGAL_DATA_VALUE),
        (1, 0, 1, ExceptionCode.ILLEGAL_FUNCTION),  # coils
        (5, 0, 1, ExceptionCode.ILLEGAL_FUNCTION),
        (23, 100, 1, ExceptionCode.ILLEGAL_FUNCTION),  # read/write multiple: not supported
    ],
)
def test_check_request(fc: int, address: int, count: int, expected: ExceptionCode | None) -> None:
    assert check_request(fc, address, count) == expected


@pytest.mark.parametrize(
    ("address", "values", "expected"),
    [
        (mm.REG_DIR_X, [2, 1, 0], None),
        (mm.REG_DIR_Y, [3], ExceptionCode.ILLEGAL_DATA_VALUE),  # direction code 3
        (mm.REG_READING_FLAGS, [0x8], ExceptionCode.ILLEGAL_DATA_VALUE),  # reserved bit
        (mm.REG_READING_FLAGS, [0x7, 0xFFFF], None),  # any seq value
        (mm.temperature_address(2) + 2, [2], ExceptionCode.ILLEGAL_DATA_VALUE),  # temp flags
        (mm.temperature_address(2) + 3, [0xFFFF], None),  # counter: any value
        (mm.REG_X_NM, [0x10000], ExceptionCode.ILLEGAL_DATA_VALUE),  # not a 16-bit word
        (mm.REG_STATUS, [0], ExceptionCode.ILLEGAL_DATA_ADDRESS),
    ],
)
def test_check_write_values(
    address: int, values: list[int], expected: ExceptionCode | None
) -> None:
    assert check_write(16, address, values) == expected


def test_check_write_rejects_read_function() -> None:
    assert check_write(3, 100, [0]) == ExceptionCode.ILLEGAL_FUNCTION


def test_commit_detection() -> None:
    assert commits_reading(16, 100, 20)
    assert commits_reading(6, 119, 1)
    assert not commits_reading(16, 100, 19)  # values written, SEQ not yet
    assert not commits_reading(3, 100, 20)


def test_decode_errors_name_the_problem() -> None:
    with pytest.raises(ValueError, match="READING block needs 20 registers, got 19"):
        ReadingBlock.from_registers([0] * 19)
    regs = AnswerBlock(1, Status.OK, (0, 0, 0)).to_registers()
    regs[1] = 99
    with pytest.raises(ValueError, match="99 is not a valid Status"):
        AnswerBlock.from_registers(regs)
    with pytest.raises(ValueError, match=r"sensor 16 has no Modbus slot; allowed 0\.\.15"):
        TemperatureSlot(16, 0).to_registers()
    with pytest.raises(ValueError, match="direction sign 2 is not one of"):
        ReadingBlock.from_mm(1, (0, 0, 0), directions=(2, 0, 0))
