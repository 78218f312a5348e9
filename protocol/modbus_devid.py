"""Read Device Identification (FC43 / MEI type 14), Modbus Application Protocol V1.1b3 §6.21.

Objects (id → ASCII value) in three categories: basic 0x00..0x02 (mandatory), regular
0x03..0x7F, extended 0x80..0xFF (private). Read device id codes:

| code | access | objects returned |
|---|---|---|
| 01 | stream | basic objects from the requested object id |
| 02 | stream | basic + regular objects from the requested object id |
| 03 | stream | basic + regular + extended objects from the requested object id |
| 04 | individual | the requested object only (absent object → exception 02) |

Stream access whose object id is not an object of that stream restarts at object 0 (the spec:
"as if object 0 were pointed out"). Objects that do not fit one 253-byte response are left for
the next request: ``more follows`` = 0xFF and ``next object id`` names the first one left out.
A read device id code other than 01..04 or a request PDU not exactly 4 bytes long is
exception 03. The conformity level is 0x83 (extended identification, stream and individual
access).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass

from .modbus_map import FC_READ_DEVICE_ID, MEI_READ_DEVICE_ID, ExceptionCode

READ_BASIC = 0x01
READ_REGULAR = 0x02
READ_EXTENDED = 0x03
READ_INDIVIDUAL = 0x04
CONFORMITY_LEVEL = 0x83
"""Extended identification level, stream and individual access supported."""
MORE_FOLLOWS = 0xFF

OBJ_VENDOR_NAME = 0x00
OBJ_PRODUCT_CODE = 0x01
OBJ_MAJOR_MINOR_REVISION = 0x02
OBJ_VENDOR_URL = 0x03
OBJ_PRODUCT_NAME = 0x04
OBJ_MODEL_NAME = 0x05
OBJ_GRID_SHA256 = 0x80
"""Private object: SHA-256 (hex) of the loaded grid file; empty while no grid is loaded."""

_LAST_OBJECT = {READ_BASIC: 0x02, READ_REGULAR: 0x7F, READ_EXTENDED: 0xFF}
_RESPONSE_HEAD = struct.Struct(
    ">B"  # function code 0x2B
    "B"  # MEI type 0x0E
    "B"  # read device id code, as requested
    "B"  # conformity level
    "B"  # more follows: 0x00 or 0xFF
    "B"  # next object id (0 unless more follows)
    "B"  # number of objects in this response
)
MAX_OBJECT_SIZE = 253 - _RESPONSE_HEAD.size - 2
"""Longest object value that fits one response with its id and length bytes (244)."""


@dataclass(frozen=True, slots=True)
class DeviceIdentity:
    """The static identification objects (empty optional strings are left out)."""

    vendor_name: str
    product_code: str
    revision: str
    """MajorMinorRevision, e.g. the package version ``0.1.0``."""
    vendor_url: str = ""
    product_name: str = ""
    model_name: str = ""

    def objects(self) -> dict[int, bytes]:
        """Object id → ASCII value; ValueError for a value that is not ASCII or too long."""
        fields = {
            OBJ_VENDOR_NAME: self.vendor_name,
            OBJ_PRODUCT_CODE: self.product_code,
            OBJ_MAJOR_MINOR_REVISION: self.revision,
            OBJ_VENDOR_URL: self.vendor_url,
            OBJ_PRODUCT_NAME: self.product_name,
            OBJ_MODEL_NAME: self.model_name,
        }
        return {
            oid: object_value(text)
            for oid, text in fields.items()
            if text or oid <= OBJ_MAJOR_MINOR_REVISION
        }


def object_value(text: str) -> bytes:
    """``text`` as an object value; ValueError if not ASCII or longer than 244 bytes."""
    try:
        raw = text.encode("ascii")
    except UnicodeEncodeError:
        raise ValueError(f"device identification value {text!r} is not ASCII") from None
    if len(raw) > MAX_OBJECT_SIZE:
        raise ValueError(f"device identification value of {len(raw)} bytes > {MAX_OBJECT_SIZE}")
    return raw


def device_id_response(
    objects: Mapping[int, bytes], read_code: int, object_id: int
) -> bytes | ExceptionCode:
    """Response PDU to a Read Device Identification request, or its exception code."""
    if read_code == READ_INDIVIDUAL:
        if object_id not in objects:
            return ExceptionCode.ILLEGAL_DATA_ADDRESS
        ids = [object_id]
    elif read_code in _LAST_OBJECT:
        last = _LAST_OBJECT[read_code]
        ids = sorted(oid for oid in objects if oid <= last)
        if object_id not in ids:
            object_id = 0  # restart at the beginning
        ids = [oid for oid in ids if oid >= object_id]
    else:
        return ExceptionCode.ILLEGAL_DATA_VALUE
    room = 253 - _RESPONSE_HEAD.size
    body = bytearray()
    count = more = next_id = 0
    for oid in ids:
        value = objects[oid]
        if 2 + len(value) > room:
            more, next_id = MORE_FOLLOWS, oid
            break
        body += bytes((oid, len(value))) + value
        room -= 2 + len(value)
        count += 1
    head = _RESPONSE_HEAD.pack(
        FC_READ_DEVICE_ID, MEI_READ_DEVICE_ID, read_code, CONFORMITY_LEVEL, more, next_id, count
    )
    return head + bytes(body)
