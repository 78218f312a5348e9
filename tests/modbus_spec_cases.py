"""The Modbus TCP cases of docs/modbus.md, packed by hand with ``struct`` from the specs.

Shared by tests/test_protocol_modbus_conformance.py (our server must answer each as listed) and
benchmarks/bench_modbus_conformance.py (the same cases sent to pymodbus's server as well).

Oracles: the Modbus Application Protocol Specification V1.1b3 (exception response = function
code | 0x80 + code; the per-function state diagrams: 01 function not supported, 03 quantity /
byte count / length, 02 address, 04 device failure) and the Messaging on TCP/IP Implementation
Guide V1.0b (MBAP header: transaction id, protocol id 0, length = unit id + PDU bytes, unit id).
Register addresses are the documented map's (docs/modbus.md), written as numbers here rather
than taken from the project's code.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

REG_DIR_X = 112
REG_READING_FLAGS = 118
REG_SEQ = 119
REG_STATUS = 301


class ExceptionCase(NamedTuple):
    pdu: bytes
    expected: bytes
    """The response PDU: function code | 0x80, exception code."""
    what: str
    application: bool = False
    """A rule of this register map (value ranges, read-only registers) rather than of the
    protocol: a generic server knows it only through an application hook."""


def read_pdu(fc: int, address: int, count: int) -> bytes:
    return struct.pack(">BHH", fc, address, count)


def write_multiple_pdu(address: int, values: list[int], byte_count: int | None = None) -> bytes:
    n = 2 * len(values) if byte_count is None else byte_count
    return struct.pack(f">BHHB{len(values)}H", 16, address, len(values), n, *values)


def frame(
    pdu: bytes, tid: int = 1, unit: int = 1, protocol_id: int = 0, length: int | None = None
) -> bytes:
    """An MBAP frame packed by hand: >HHHB header, then the PDU."""
    n = len(pdu) + 1 if length is None else length
    return struct.pack(">HHHB", tid, protocol_id, n, unit) + pdu


E = ExceptionCase
EXCEPTION_CASES: tuple[ExceptionCase, ...] = (
    # FC3/FC4: quantity 1..125 (0x7D), else 03 — before any address check
    E(read_pdu(3, 0, 0), b"\x83\x03", "FC3 quantity 0"),
    E(read_pdu(3, 200, 126), b"\x83\x03", "FC3 quantity 126"),
    E(read_pdu(3, 0, 0xFFFF), b"\x83\x03", "FC3 quantity 65535"),
    E(read_pdu(4, 0, 0), b"\x84\x03", "FC4 quantity 0"),
    E(read_pdu(4, 200, 126), b"\x84\x03", "FC4 quantity 126"),
    E(read_pdu(3, 200, 125), b"\x83\x02", "FC3 200..324, not all defined"),
    E(read_pdu(3, 50, 1), b"\x83\x02", "FC3 undefined register 50"),
    E(read_pdu(4, 0xFFFF, 1), b"\x84\x02", "FC4 address 65535"),
    E(read_pdu(3, 0, 3) + b"\x00", b"\x83\x03", "FC3 PDU one byte long"),
    E(b"\x03\x00\x00", b"\x83\x03", "FC3 PDU truncated"),
    # FC6: one register; a read-only or undefined register is 02, a bad value 03
    E(struct.pack(">BHH", 6, REG_STATUS, 0), b"\x86\x02", "FC6 to read-only STATUS", True),
    E(struct.pack(">BHH", 6, 150, 0), b"\x86\x02", "FC6 to undefined register 150"),
    E(struct.pack(">BHH", 6, REG_DIR_X, 3), b"\x86\x03", "FC6 DIR_X = 3", True),
    E(struct.pack(">BHHB", 6, REG_SEQ, 1, 0), b"\x86\x03", "FC6 PDU one byte long"),
    # FC16: quantity 1..123 (0x7B) and byte count = 2 × quantity, else 03
    E(struct.pack(">BHHB", 16, 200, 124, 248) + bytes(8), b"\x90\x03", "FC16 quantity 124"),
    E(write_multiple_pdu(200, [0] * 123), b"\x90\x02", "FC16 123 registers, 264..322 undefined"),
    E(struct.pack(">BHHB", 16, 200, 0, 0), b"\x90\x03", "FC16 quantity 0"),
    E(write_multiple_pdu(200, [0, 0], byte_count=3), b"\x90\x03", "FC16 byte count 3 for 2"),
    E(write_multiple_pdu(200, [0, 0])[:-1], b"\x90\x03", "FC16 fewer bytes than byte count"),
    E(write_multiple_pdu(200, [0, 0]) + b"\x00\x00", b"\x90\x03", "FC16 more bytes"),
    E(b"\x10\x00\xc8", b"\x90\x03", "FC16 PDU truncated"),
    E(write_multiple_pdu(300, [1]), b"\x90\x02", "FC16 to read-only ANSWER", True),
    E(write_multiple_pdu(118, [0, 0, 0]), b"\x90\x02", "FC16 118..120, off READING"),
    E(
        write_multiple_pdu(REG_READING_FLAGS, [8]),
        b"\x90\x03",
        "FC16 reserved flag bit",
        True,
    ),
    # functions this server does not implement: 01 with the request's code | 0x80
    E(read_pdu(1, 0, 1), b"\x81\x01", "FC1 read coils"),
    E(read_pdu(2, 0, 1), b"\x82\x01", "FC2 read discrete inputs"),
    E(struct.pack(">BHH", 5, 0, 0xFF00), b"\x85\x01", "FC5 write single coil"),
    E(struct.pack(">BHHBB", 15, 0, 1, 1, 1), b"\x8f\x01", "FC15 write multiple coils"),
    E(b"\x17" + bytes(9), b"\x97\x01", "FC23 read/write registers"),
    E(b"\x08\x00\x00\x12\x34", b"\x88\x01", "FC8 diagnostics"),
    E(b"\x41", b"\xc1\x01", "undefined FC65"),
    E(b"\x7f\x00", b"\xff\x01", "undefined FC127"),
    E(b"\x2b\x0d\x00\x00", b"\xab\x01", "FC43 MEI 13 (CANopen)"),
)

BAD_FRAMES: tuple[tuple[bytes, str], ...] = (
    (frame(read_pdu(3, 0, 1), protocol_id=1), "protocol id"),
    (frame(read_pdu(3, 0, 1), protocol_id=0xFFFF), "protocol id"),
    (frame(read_pdu(3, 0, 1), length=65535), "length field 65535"),
    (frame(read_pdu(3, 0, 1), length=255), "length field 255"),
    (frame(b"", length=1), "length field 1"),
    (frame(b"", length=0), "length field 0"),
    (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", "protocol id"),
)
"""Headers no Modbus TCP request has (docs/modbus.md: the connection is closed), with the
reason our server reports."""
