"""Modbus TCP conformance of the server, checked byte by byte with a raw socket.

Oracle: the Modbus Application Protocol Specification V1.1b3 (function codes, request/response
layouts, exception responses = function code | 0x80 + code, the per-function state diagrams:
01 function not supported, 03 quantity / byte count / length, 02 address, 04 device failure)
and the Messaging on TCP/IP Implementation Guide V1.0b (MBAP header). Every frame below is
packed by hand with ``struct`` (tests/test_protocol_modbus_support.py), not with our codec.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator

import pytest
from test_protocol_modbus_support import WAIT_S, RawClient, frame, threaded_server, wait_for

from cmm_comp.protocol import AnswerBlock, MapDevice, ReadingBlock, Status
from cmm_comp.protocol import modbus_map as mm


def read_pdu(fc: int, address: int, count: int) -> bytes:
    return struct.pack(">BHH", fc, address, count)


def write_multiple_pdu(address: int, values: list[int], byte_count: int | None = None) -> bytes:
    n = 2 * len(values) if byte_count is None else byte_count
    return struct.pack(f">BHHB{len(values)}H", 16, address, len(values), n, *values)


@pytest.fixture
def client() -> Iterator[RawClient]:
    with threaded_server(MapDevice()) as served, RawClient(served.port) as raw:
        yield raw


@pytest.mark.parametrize(
    ("pdu", "expected"),
    [
        # FC3/FC4: quantity 1..125 (0x7D), else 03 — before any address check
        (read_pdu(3, 0, 0), b"\x83\x03"),
        (read_pdu(3, 200, 126), b"\x83\x03"),
        (read_pdu(3, 0, 0xFFFF), b"\x83\x03"),
        (read_pdu(4, 0, 0), b"\x84\x03"),
        (read_pdu(4, 200, 126), b"\x84\x03"),
        (read_pdu(3, 200, 125), b"\x83\x02"),  # quantity fine, 200..324 not all defined
        (read_pdu(3, 50, 1), b"\x83\x02"),
        (read_pdu(4, 0xFFFF, 1), b"\x84\x02"),
        (read_pdu(3, 0, 3) + b"\x00", b"\x83\x03"),  # PDU longer than FC3's 5 bytes
        (b"\x03\x00\x00", b"\x83\x03"),  # truncated PDU
        # FC6: one register; a read-only or undefined register is 02, a bad value 03
        (struct.pack(">BHH", 6, mm.REG_STATUS, 0), b"\x86\x02"),
        (struct.pack(">BHH", 6, 150, 0), b"\x86\x02"),
        (struct.pack(">BHH", 6, mm.REG_DIR_X, 3), b"\x86\x03"),
        (struct.pack(">BHHB", 6, mm.REG_SEQ, 1, 0), b"\x86\x03"),  # 6 bytes
        # FC16: quantity 1..123 (0x7B) and byte count = 2 × quantity, else 03
        (struct.pack(">BHHB", 16, 200, 124, 248) + bytes(8), b"\x90\x03"),  # 124 > 0x7B
        (write_multiple_pdu(200, [0] * 123), b"\x90\x02"),  # largest quantity; 200..322 undefined
        (struct.pack(">BHHB", 16, 200, 0, 0), b"\x90\x03"),
        (write_multiple_pdu(200, [0, 0], byte_count=3), b"\x90\x03"),
        (write_multiple_pdu(200, [0, 0])[:-1], b"\x90\x03"),  # fewer bytes than byte count
        (write_multiple_pdu(200, [0, 0]) + b"\x00\x00", b"\x90\x03"),  # more bytes
        (b"\x10\x00\xc8", b"\x90\x03"),
        (write_multiple_pdu(300, [1]), b"\x90\x02"),  # ANSWER is read-only
        (write_multiple_pdu(118, [0, 0, 0]), b"\x90\x02"),  # runs off READING
        (write_multiple_pdu(mm.REG_READING_FLAGS, [8]), b"\x90\x03"),  # reserved bit
        # functions this server does not implement: 01 with the request's code | 0x80
        (read_pdu(1, 0, 1), b"\x81\x01"),  # read coils
        (read_pdu(2, 0, 1), b"\x82\x01"),  # read discrete inputs
        (struct.pack(">BHH", 5, 0, 0xFF00), b"\x85\x01"),  # write single coil
        (struct.pack(">BHHBB", 15, 0, 1, 1, 1), b"\x8f\x01"),  # write multiple coils
        (b"\x17" + bytes(9), b"\x97\x01"),  # read/write multiple registers
        (b"\x08\x00\x00\x12\x34", b"\x88\x01"),  # diagnostics
        (b"\x41", b"\xc1\x01"),  # undefined function code 65
        (b"\x7f\x00", b"\xff\x01"),
        (b"\x2b\x0d\x00\x00", b"\xab\x01"),  # FC43 with MEI 13 (CANopen): not implemented
    ],
)
def test_exception_responses(client: RawClient, pdu: bytes, expected: bytes) -> None:
    assert client.request(pdu) == expected


def test_normal_responses_byte_for_byte(client: RawClient) -> None:
    assert client.request(read_pdu(3, 0, 3)) == bytes.fromhex("03 06 0002 434d 0010")
    assert client.request(read_pdu(4, 1, 1)) == bytes.fromhex("04 02 434d")
    # docs/modbus.md worked example: sensor 3, 20.125 °C, valid, counter 258 at 212..215
    assert client.request(struct.pack(">BHH", 6, 213, 0x4E9D)) == bytes.fromhex("06 00d5 4e9d")
    assert client.request(write_multiple_pdu(214, [1, 258])) == bytes.fromhex("10 00d6 0002")
    assert client.request(read_pdu(3, 212, 4)) == bytes.fromhex("03 08 0000 4e9d 0001 0102")
    # 24 registers of ANSWER + DAEMON: before any answer, seq 0 with status not_ready (13)
    out = client.request(read_pdu(3, 300, 24))
    assert out[:2] == b"\x03\x30" and len(out) == 2 + 48
    assert struct.unpack(">HH", out[2:6]) == (0, int(Status.NOT_READY))


def test_transaction_and_unit_ids_echoed_and_pipelined_requests_answered_in_order() -> None:
    with threaded_server(MapDevice()) as served, RawClient(served.port) as raw:
        burst = b"".join(
            frame(read_pdu(3, 0, 1), tid=tid, unit=unit)
            for tid, unit in ((0xBEEF, 1), (7, 0), (0xFFFF, 0xFF))
        )
        raw.send(burst[:5])  # split mid-header, then the rest in one go
        raw.send(burst[5:])
        assert [raw.response() for _ in range(3)] == [
            (0xBEEF, 0, 1, b"\x03\x02\x00\x02"),
            (7, 0, 0, b"\x03\x02\x00\x02"),
            (0xFFFF, 0, 0xFF, b"\x03\x02\x00\x02"),
        ]


def test_wrong_unit_gets_no_response_and_the_connection_stays_usable() -> None:
    with threaded_server(MapDevice()) as served, RawClient(served.port) as raw:
        raw.send(frame(read_pdu(3, 0, 1), tid=1, unit=7) + frame(read_pdu(3, 0, 1), tid=2, unit=2))
        raw.send(frame(read_pdu(3, 1, 1), tid=3, unit=1))
        assert raw.response() == (3, 0, 1, b"\x03\x02\x43\x4d")  # 1 and 2 were never answered
        assert served.recorder.wrong_units == [7, 2]


@pytest.mark.parametrize(
    ("garbage", "reason"),
    [
        (frame(read_pdu(3, 0, 1), protocol_id=1), "protocol id"),
        (frame(read_pdu(3, 0, 1), protocol_id=0xFFFF), "protocol id"),
        (frame(read_pdu(3, 0, 1), length=65535), "length field 65535"),
        (frame(read_pdu(3, 0, 1), length=255), "length field 255"),
        (frame(b"", length=1), "length field 1"),
        (frame(b"", length=0), "length field 0"),
        (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", "protocol id"),
    ],
)
def test_bad_frames_close_the_connection_and_are_reported(garbage: bytes, reason: str) -> None:
    with threaded_server(MapDevice()) as served:
        with RawClient(served.port) as raw:
            assert raw.request(read_pdu(3, 0, 1)) == b"\x03\x02\x00\x02"
            raw.send(garbage)
            raw.wait_eof()
        assert wait_for(lambda: served.recorder.bad_frames)
        assert len(served.recorder.bad_frames) == 1 and reason in served.recorder.bad_frames[0]
        with RawClient(served.port) as raw:  # the server itself is unharmed
            assert raw.request(read_pdu(3, 0, 1)) == b"\x03\x02\x00\x02"


def test_truncated_header_then_silence_closes_as_a_bad_frame() -> None:
    with threaded_server(MapDevice(), idle_timeout_s=0, frame_timeout_s=0.2) as served:
        with RawClient(served.port) as raw:
            raw.send(b"\x00\x01\x00")  # 3 bytes of a header, then nothing
            raw.wait_eof(WAIT_S)
        assert wait_for(lambda: served.recorder.bad_frames)
        assert "incomplete frame (3 bytes)" in served.recorder.bad_frames[0]
        assert served.recorder.idle_closed == []


def test_idle_connection_is_closed_and_reported() -> None:
    with threaded_server(MapDevice(), idle_timeout_s=1.0) as served:
        with RawClient(served.port) as raw:
            assert raw.request(read_pdu(3, 0, 1)) == b"\x03\x02\x00\x02"
            raw.wait_eof(WAIT_S)  # closed by the server, within a generous bound
        assert wait_for(lambda: served.recorder.idle_closed)
        assert served.recorder.bad_frames == []


def test_idle_timeout_zero_never_closes() -> None:
    with threaded_server(MapDevice(), idle_timeout_s=0, frame_timeout_s=0.05) as served:
        with RawClient(served.port) as raw:
            assert raw.request(read_pdu(3, 0, 1)) == b"\x03\x02\x00\x02"
            raw.sock.settimeout(0.5)
            with pytest.raises(TimeoutError):  # nothing arrives, the connection is not closed
                raw.sock.recv(1)
            raw.sock.settimeout(WAIT_S)
            assert raw.request(read_pdu(3, 0, 1)) == b"\x03\x02\x00\x02"
        assert served.recorder.idle_closed == served.recorder.bad_frames == []


def test_failing_hook_answers_server_device_failure_and_keeps_serving() -> None:
    def on_commit(reading: ReadingBlock) -> AnswerBlock:
        raise RuntimeError("engine exploded")

    with threaded_server(MapDevice(on_commit=on_commit)) as served, RawClient(served.port) as raw:
        regs = ReadingBlock.from_mm(5, (1.0, 2.0, 3.0)).to_registers()
        assert raw.request(write_multiple_pdu(100, regs)) == b"\x90\x04"
        assert raw.request(read_pdu(3, 0, 1)) == b"\x03\x02\x00\x02"


def test_device_answers_every_request_it_parses() -> None:
    """The device never raises for any PDU of 1..253 bytes (fuzz with a fixed seed)."""
    import random

    rng = random.Random(12)
    device = MapDevice(on_commit=lambda r: None)
    for _ in range(20_000):
        n = rng.randint(1, 253) if rng.random() < 0.3 else rng.randint(1, 8)
        fc = rng.choice([3, 4, 6, 16, 43, rng.randint(0, 255)])
        pdu = bytes([fc]) + rng.randbytes(n - 1)
        out = device.handle(pdu)
        if out.code is not None:
            assert out.response == bytes([fc | 0x80, int(out.code)])
        else:
            assert out.response[0] == fc
