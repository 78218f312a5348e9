"""Modbus TCP conformance of the server, checked byte by byte with a raw socket.

Oracle: the Modbus Application Protocol Specification V1.1b3 (function codes, request/response
layouts, exception responses = function code | 0x80 + code, the per-function state diagrams:
01 function not supported, 03 quantity / byte count / length, 02 address, 04 device failure)
and the Messaging on TCP/IP Implementation Guide V1.0b (MBAP header). Every frame is
packed by hand with ``struct`` (the cases in tests/modbus_spec_cases.py, shared with
benchmarks/bench_modbus_conformance.py, which sends them to pymodbus's server too), not with
our codec.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator

import pytest
from modbus_spec_cases import (
    BAD_FRAMES,
    EXCEPTION_CASES,
    ExceptionCase,
    frame,
    read_pdu,
    write_multiple_pdu,
)
from test_protocol_modbus_support import WAIT_S, RawClient, threaded_server, wait_for

from cmm_comp.protocol import AnswerBlock, MapDevice, ReadingBlock, Status


@pytest.fixture
def client() -> Iterator[RawClient]:
    with threaded_server(MapDevice()) as served, RawClient(served.port) as raw:
        yield raw


@pytest.mark.parametrize("case", EXCEPTION_CASES, ids=[c.what for c in EXCEPTION_CASES])
def test_exception_responses(client: RawClient, case: ExceptionCase) -> None:
    assert client.request(case.pdu) == case.expected


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


@pytest.mark.parametrize(("garbage", "reason"), BAD_FRAMES)
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
