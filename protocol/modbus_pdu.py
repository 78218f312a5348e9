"""Modbus TCP framing (MBAP) and the request/response PDUs the register map serves (pure, no I/O).

Per the Modbus Messaging on TCP/IP Implementation Guide V1.0b (MBAP header) and the Modbus
Application Protocol Specification V1.1b3 (PDUs, exception responses). An ADU is the 7-byte
MBAP header followed by the PDU (function code + data, at most 253 bytes):

| bytes | field | rule |
|---|---|---|
| 0-1 | transaction id | copied into the response |
| 2-3 | protocol id | 0 = Modbus; anything else is a bad frame |
| 4-5 | length | unit id + PDU bytes: 2..254, else a bad frame |
| 6 | unit id | copied into the response |

:func:`parse_request` turns a PDU into a :class:`Request` or the exception code the spec's
state diagrams give for it: 01 for a function (or MEI type) this server does not implement,
03 for a quantity outside the function's limits, a byte count ≠ 2 × quantity or a PDU whose
length does not match its function. Address (02) and value checks are the register map's
(:func:`protocol.modbus_map.check_request`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from cmm_comp.compensation.errors import CmmCompError

from .modbus_map import (
    FC_READ_DEVICE_ID,
    FC_READ_HOLDING,
    FC_READ_INPUT,
    FC_WRITE_MULTIPLE,
    FC_WRITE_SINGLE,
    MAX_READ_COUNT,
    MAX_WRITE_COUNT,
    MEI_READ_DEVICE_ID,
    ExceptionCode,
)

MBAP = struct.Struct(
    ">H"  # transaction id: chosen by the client, echoed by the server
    "H"  # protocol id: 0 for Modbus
    "H"  # length: number of following bytes (unit id + PDU)
    "B"  # unit id: routing field, echoed by the server
)
MBAP_SIZE = MBAP.size
"""7 bytes."""
MAX_PDU_SIZE = 253
"""Largest PDU (function code + data), bytes (serial-line ADU limit 256 − address − CRC)."""
MIN_LENGTH = 2
"""Smallest MBAP length field: unit id + function code."""
MAX_LENGTH = 1 + MAX_PDU_SIZE
"""Largest MBAP length field: unit id + the largest PDU (254)."""

_ADDR_COUNT = struct.Struct(">BHH")  # function code, starting address, quantity (or value)
_WRITE_MULTIPLE_HEAD = struct.Struct(">BHHB")  # function code, address, quantity, byte count
_MEI_REQUEST = struct.Struct(">BBBB")  # 0x2B, MEI type, read device id code, object id


class FrameError(CmmCompError, ValueError):
    """An MBAP header that is not Modbus: the connection cannot be resynchronised."""


@dataclass(frozen=True, slots=True)
class Header:
    """A checked MBAP header."""

    transaction_id: int
    length: int
    """Unit id + PDU bytes (2..254)."""
    unit_id: int


def parse_header(data: bytes | bytearray | memoryview, offset: int = 0) -> Header:
    """The MBAP header at ``offset`` (7 bytes needed); FrameError naming the bad field."""
    tid, protocol_id, length, unit = MBAP.unpack_from(data, offset)
    if protocol_id != 0:
        raise FrameError(f"protocol id {protocol_id:#06x}, expected 0 (Modbus)")
    if not MIN_LENGTH <= length <= MAX_LENGTH:
        raise FrameError(f"length field {length}, allowed {MIN_LENGTH}..{MAX_LENGTH}")
    return Header(tid, length, unit)


def adu(transaction_id: int, unit_id: int, pdu: bytes) -> bytes:
    """MBAP header + ``pdu``: a complete frame."""
    return MBAP.pack(transaction_id, 0, len(pdu) + 1, unit_id) + pdu


@dataclass(frozen=True, slots=True)
class Request:
    """A request PDU that passed the function-level checks (quantity, byte count, length).

    ``address``/``count``: first register and number of registers (FC3/4/6/16; 1 for FC6).
    ``values``: registers to write (FC6/16), None for reads. For FC43/14 ``address`` is the
    read device id code and ``count`` the object id.
    """

    function_code: int
    address: int
    count: int
    values: tuple[int, ...] | None = None

    @property
    def is_write(self) -> bool:
        """True for FC6/FC16."""
        return self.values is not None


def parse_request(pdu: bytes) -> Request | ExceptionCode:
    """Decode a request PDU, or the exception code to answer (01 or 03, see the module doc)."""
    fc = pdu[0]
    size = len(pdu)
    if fc in (FC_READ_HOLDING, FC_READ_INPUT):
        if size != _ADDR_COUNT.size:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        _, address, count = _ADDR_COUNT.unpack(pdu)
        if not 1 <= count <= MAX_READ_COUNT:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        return Request(fc, address, count)
    if fc == FC_WRITE_SINGLE:
        if size != _ADDR_COUNT.size:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        _, address, value = _ADDR_COUNT.unpack(pdu)
        return Request(fc, address, 1, (value,))
    if fc == FC_WRITE_MULTIPLE:
        head = _WRITE_MULTIPLE_HEAD.size
        if size < head:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        _, address, count, byte_count = _WRITE_MULTIPLE_HEAD.unpack_from(pdu)
        if (
            not 1 <= count <= MAX_WRITE_COUNT
            or byte_count != 2 * count
            or size != head + byte_count
        ):
            return ExceptionCode.ILLEGAL_DATA_VALUE
        return Request(fc, address, count, struct.unpack_from(f">{count}H", pdu, head))
    if fc == FC_READ_DEVICE_ID and size >= 2 and pdu[1] == MEI_READ_DEVICE_ID:
        if size != _MEI_REQUEST.size:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        _, _, read_code, object_id = _MEI_REQUEST.unpack(pdu)
        return Request(fc, read_code, object_id)
    return ExceptionCode.ILLEGAL_FUNCTION  # incl. FC43 with another MEI type


def exception_pdu(function_code: int, code: int) -> bytes:
    """Exception response: the request's function code with bit 7 set, then the code."""
    return bytes(((function_code | 0x80) & 0xFF, code))


def read_response(function_code: int, registers: list[int]) -> bytes:
    """FC3/FC4 response: function code, byte count, registers big-endian."""
    n = len(registers)
    return struct.pack(f">BB{n}H", function_code, 2 * n, *registers)


def write_single_response(address: int, value: int) -> bytes:
    """FC6 response: an echo of the request."""
    return _ADDR_COUNT.pack(FC_WRITE_SINGLE, address, value)


def write_multiple_response(address: int, count: int) -> bytes:
    """FC16 response: function code, starting address, quantity written."""
    return _ADDR_COUNT.pack(FC_WRITE_MULTIPLE, address, count)
