"""Read Device Identification (FC43 / MEI 14): raw bytes from the spec, and pymodbus' decoder.

Oracles: Modbus Application Protocol V1.1b3 §6.21 (response layout: 0x2B 0x0E, read device id
code, conformity level, more follows, next object id, number of objects, then id/length/value
triples; stream access restarts at object 0 for an unknown object id; individual access to an
absent object is exception 02; a read device id code outside 01..04 is 03), the pymodbus client
decoding our responses, and a parser written here independently of our encoder.
"""

from __future__ import annotations

import asyncio
import struct

import pytest
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu.mei_message import ReadDeviceInformationResponse
from test_protocol_modbus_support import RawClient, threaded_server

from cmm_comp.protocol import DeviceIdentity, MapDevice, MbapServer, device_id_response
from cmm_comp.protocol.modbus_devid import object_value

IDENTITY = DeviceIdentity(
    "cmm-comp project", "cmm-comp", "0.1.0", "https://example.invalid/cmm", "daemon", "map v1"
)
OBJECTS = {**IDENTITY.objects(), 0x80: b"ab" * 32}


def parse(pdu: bytes) -> tuple[int, int, int, int, dict[int, bytes]]:
    """(read code, conformity, more follows, next id, objects) of a response PDU, by hand."""
    assert pdu[:2] == b"\x2b\x0e"
    code, conformity, more, next_id, n = pdu[2:7]
    objects, pos = {}, 7
    for _ in range(n):
        oid, size = pdu[pos], pdu[pos + 1]
        objects[oid] = pdu[pos + 2 : pos + 2 + size]
        pos += 2 + size
    assert pos == len(pdu)
    return code, conformity, more, next_id, objects


def test_basic_stream_byte_for_byte() -> None:
    expected = (
        bytes([0x2B, 0x0E, 0x01, 0x83, 0x00, 0x00, 0x03])
        + bytes([0x00, 16]) + b"cmm-comp project"
        + bytes([0x01, 8]) + b"cmm-comp"
        + bytes([0x02, 5]) + b"0.1.0"
    )  # fmt: skip
    device = MapDevice(identity=lambda: OBJECTS)
    with threaded_server(device) as served, RawClient(served.port) as raw:
        assert raw.request(b"\x2b\x0e\x01\x00") == expected


@pytest.mark.parametrize(
    ("code", "object_id", "ids"),
    [
        (1, 0, [0, 1, 2]),
        (1, 2, [2]),
        (1, 4, [0, 1, 2]),  # not a basic object: restart at the beginning
        (2, 0, [0, 1, 2, 3, 4, 5]),
        (2, 4, [4, 5]),
        (2, 0x80, [0, 1, 2, 3, 4, 5]),
        (3, 0, [0, 1, 2, 3, 4, 5, 0x80]),
        (3, 0x80, [0x80]),
        (3, 0x42, [0, 1, 2, 3, 4, 5, 0x80]),  # unknown object
        (4, 0x80, [0x80]),
        (4, 3, [3]),
    ],
)
def test_stream_and_individual_access(code: int, object_id: int, ids: list[int]) -> None:
    response = device_id_response(OBJECTS, code, object_id)
    assert isinstance(response, bytes)
    rcode, conformity, more, next_id, objects = parse(response)
    assert (rcode, conformity, more, next_id) == (code, 0x83, 0, 0)
    assert objects == {i: OBJECTS[i] for i in ids}


def test_more_follows_splits_long_streams() -> None:
    many = {**OBJECTS, **{0x80 + i: bytes([65 + i]) * 200 for i in range(4)}}
    seen: dict[int, bytes] = {}
    object_id, rounds = 0, 0
    while True:
        rcode, _, more, next_id, objects = parse(device_id_response(many, 3, object_id))  # type: ignore[arg-type]
        assert rcode == 3 and objects and not seen.keys() & objects.keys()
        seen.update(objects)
        rounds += 1
        if more == 0:
            assert next_id == 0
            break
        assert more == 0xFF and next_id not in objects and next_id in many
        object_id = next_id
    assert seen == many and rounds == 5  # the short objects, then one 200-byte object each


def test_exceptions() -> None:
    device = MapDevice(identity=lambda: OBJECTS)
    with threaded_server(device) as served, RawClient(served.port) as raw:
        assert raw.request(b"\x2b\x0e\x04\x06") == b"\xab\x02"  # absent object, individual
        assert raw.request(b"\x2b\x0e\x05\x00") == b"\xab\x03"  # read device id code 5
        assert raw.request(b"\x2b\x0e\x00\x00") == b"\xab\x03"
        assert raw.request(b"\x2b\x0e\x01") == b"\xab\x03"  # request PDU too short
        assert raw.request(b"\x2b\x0e\x01\x00\x00") == b"\xab\x03"  # too long
        assert raw.request(b"\x2b") == b"\xab\x01"  # no MEI type
    with threaded_server(MapDevice()) as served, RawClient(served.port) as raw:
        assert raw.request(b"\x2b\x0e\x01\x00") == b"\xab\x01"  # device without identification


def test_object_values_are_checked() -> None:
    with pytest.raises(ValueError, match="not ASCII"):
        object_value("µm")
    with pytest.raises(ValueError, match="245 bytes > 244"):
        object_value("x" * 245)
    assert set(DeviceIdentity("v", "p", "1").objects()) == {0, 1, 2}  # empty optionals left out


def test_pymodbus_client_decodes_every_access() -> None:
    async def main() -> None:
        device = MapDevice(identity=lambda: OBJECTS)
        server = MbapServer(device.handle_pdu, unit_ids={1})
        await server.start("127.0.0.1", 0)
        client = AsyncModbusTcpClient("127.0.0.1", port=server.port, timeout=2, retries=0)
        try:
            assert await client.connect()
            for code, object_id, ids in [
                (1, 0, [0, 1, 2]),
                (2, 0, [0, 1, 2, 3, 4, 5]),
                (3, 0, [0, 1, 2, 3, 4, 5, 0x80]),
                (4, 0x80, [0x80]),
            ]:
                rr = await client.read_device_information(
                    read_code=code, object_id=object_id, device_id=1
                )
                assert isinstance(rr, ReadDeviceInformationResponse)
                assert (rr.read_code, rr.conformity, rr.more_follows) == (code, 0x83, 0)
                assert rr.information == {i: OBJECTS[i] for i in ids}
            rr = await client.read_device_information(read_code=4, object_id=0x81, device_id=1)
            assert rr.isError() and rr.exception_code == 2
        finally:
            client.close()
            await server.close()

    asyncio.run(main())


def test_header_layout_constant() -> None:
    # The response header is 7 bytes; so a single object may hold at most 253 - 7 - 2 bytes.
    from cmm_comp.protocol.modbus_devid import MAX_OBJECT_SIZE

    assert MAX_OBJECT_SIZE == 244 == 253 - struct.calcsize(">7B") - 2
