"""MCAP records as bytes, written from the format's specification (mcap.dev/spec, version 0).

Every record is ``opcode (uint8) · length of the body (uint64) · body``, little-endian. Strings
are ``uint32 byte length · UTF-8``; maps ``uint32 byte length · entries``; arrays ``uint32 byte
length · items``. The session log's writer (:mod:`.mcapfile`) builds its files from these
functions only, so it depends on the published format, not on any library's internals; the
tests check the bytes against the ``mcap`` package's own writer and read the files with the
official TypeScript reader (``tests/mcap_ts``).

The Message record, the one written per logged message, is packed inline by the writer with
:data:`MESSAGE_HEAD` (the hot path); everything else is built here.
"""

from __future__ import annotations

import struct
import sys
import zlib
from array import array
from collections.abc import Iterable, Mapping

MAGIC = b"\x89MCAP0\r\n"
"""Starts and ends every MCAP file."""


class Op:
    """Record opcodes."""

    HEADER = 0x01
    FOOTER = 0x02
    SCHEMA = 0x03
    CHANNEL = 0x04
    MESSAGE = 0x05
    CHUNK = 0x06
    MESSAGE_INDEX = 0x07
    CHUNK_INDEX = 0x08
    ATTACHMENT = 0x09
    ATTACHMENT_INDEX = 0x0A
    STATISTICS = 0x0B
    METADATA = 0x0C
    METADATA_INDEX = 0x0D
    SUMMARY_OFFSET = 0x0E
    DATA_END = 0x0F


RECORD_HEAD = struct.Struct("<BQ")
"""Opcode and body length of any record."""
MESSAGE_HEAD = struct.Struct("<BQHIQQ")
"""A whole Message record up to its data: opcode, length (22 + data), channel id, sequence,
log time, publish time (ns)."""
MESSAGE_FIXED = 22
"""Body bytes of a Message record before its data."""
FOOTER_HEAD = struct.Struct("<BQQQ")
"""A Footer record up to its CRC: opcode, length (20), summary start, summary offset start (the
summary CRC covers the summary section and these bytes)."""
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_U16_U64 = struct.Struct("<HQ")


def record(opcode: int, body: bytes) -> bytes:
    """One record: ``opcode``, the length of ``body``, ``body``."""
    return RECORD_HEAD.pack(opcode, len(body)) + body


def string(value: str) -> bytes:
    """An MCAP String: uint32 byte length, UTF-8."""
    data = value.encode()
    return _U32.pack(len(data)) + data


def string_map(values: Mapping[str, str]) -> bytes:
    """A ``Map<string, string>`` in the mapping's order."""
    body = b"".join(string(k) + string(v) for k, v in values.items())
    return _U32.pack(len(body)) + body


def u16_u64_map(values: Mapping[int, int]) -> bytes:
    """A ``Map<uint16, uint64>`` in the mapping's order."""
    return _U32.pack(10 * len(values)) + b"".join(_U16_U64.pack(k, v) for k, v in values.items())


def header(profile: str, library: str) -> bytes:
    """Header record."""
    return record(Op.HEADER, string(profile) + string(library))


def footer(summary_start: int, summary_offset_start: int, summary_crc: int) -> bytes:
    """Footer record (offsets 0 when there is no summary / no summary offsets)."""
    return FOOTER_HEAD.pack(Op.FOOTER, 20, summary_start, summary_offset_start) + _U32.pack(
        summary_crc
    )


def schema(schema_id: int, name: str, encoding: str, data: bytes) -> bytes:
    """Schema record."""
    body = _U16.pack(schema_id) + string(name) + string(encoding) + _U32.pack(len(data)) + data
    return record(Op.SCHEMA, body)


def channel(
    channel_id: int,
    schema_id: int,
    topic: str,
    message_encoding: str,
    metadata: Mapping[str, str],
) -> bytes:
    """Channel record."""
    body = (
        _U16.pack(channel_id)
        + _U16.pack(schema_id)
        + string(topic)
        + string(message_encoding)
        + string_map(metadata)
    )
    return record(Op.CHANNEL, body)


CHUNK_FIXED = struct.Struct("<QQQI")
"""Chunk body up to its compression string: message start/end time, uncompressed size and
CRC-32 of the uncompressed records."""


def chunk_head(
    start_ns: int, end_ns: int, uncompressed: int, crc: int, compression: str, compressed: int
) -> bytes:
    """A Chunk record up to its records (``compressed`` bytes of them follow)."""
    fixed = CHUNK_FIXED.pack(start_ns, end_ns, uncompressed, crc) + string(compression)
    return RECORD_HEAD.pack(Op.CHUNK, len(fixed) + 8 + compressed) + fixed + _U64.pack(compressed)


_NATIVE_U64 = array("Q").itemsize == 8
_SWAP = sys.byteorder != "little"


def u64_array(values: list[int]) -> bytes:
    """``values`` as consecutive little-endian uint64 (OverflowError if one does not fit)."""
    if not _NATIVE_U64:
        return struct.pack(f"<{len(values)}Q", *values)
    packed = array("Q", values)
    if _SWAP:
        packed.byteswap()
    return packed.tobytes()


def message_index(channel_id: int, times_offsets: list[int]) -> bytes:
    """Message Index record of one channel in one chunk; ``times_offsets`` holds the
    ``(log time, offset in the uncompressed chunk)`` pairs flattened: ``[t0, o0, t1, o1, …]``."""
    n = len(times_offsets)
    body = _U16.pack(channel_id) + _U32.pack(8 * n) + u64_array(times_offsets)
    return record(Op.MESSAGE_INDEX, body)


_CHUNK_INDEX_FIXED = struct.Struct("<QQQQ")


def chunk_index(
    start_ns: int,
    end_ns: int,
    chunk_start: int,
    chunk_length: int,
    message_index_offsets: Mapping[int, int],
    message_index_length: int,
    compression: str,
    compressed: int,
    uncompressed: int,
) -> bytes:
    """Chunk Index record (offsets are from the start of the file, bytes)."""
    body = (
        _CHUNK_INDEX_FIXED.pack(start_ns, end_ns, chunk_start, chunk_length)
        + u16_u64_map(message_index_offsets)
        + _U64.pack(message_index_length)
        + string(compression)
        + _U64.pack(compressed)
        + _U64.pack(uncompressed)
    )
    return record(Op.CHUNK_INDEX, body)


def attachment(log_ns: int, create_ns: int, name: str, media_type: str, data: bytes) -> bytes:
    """Attachment record, with the CRC-32 of everything in its body before the CRC."""
    body = (
        _U64.pack(log_ns)
        + _U64.pack(create_ns)
        + string(name)
        + string(media_type)
        + _U64.pack(len(data))
        + data
    )
    return record(Op.ATTACHMENT, body + _U32.pack(zlib.crc32(body)))


def attachment_index(
    offset: int, length: int, log_ns: int, create_ns: int, size: int, name: str, media_type: str
) -> bytes:
    """Attachment Index record."""
    body = struct.pack("<QQQQQ", offset, length, log_ns, create_ns, size)
    return record(Op.ATTACHMENT_INDEX, body + string(name) + string(media_type))


def metadata(name: str, values: Mapping[str, str]) -> bytes:
    """Metadata record."""
    return record(Op.METADATA, string(name) + string_map(values))


def metadata_index(offset: int, length: int, name: str) -> bytes:
    """Metadata Index record."""
    return record(Op.METADATA_INDEX, struct.pack("<QQ", offset, length) + string(name))


_STATISTICS_FIXED = struct.Struct("<QHIIIIQQ")


def statistics(
    message_count: int,
    schema_count: int,
    channel_count: int,
    attachment_count: int,
    metadata_count: int,
    chunk_count: int,
    start_ns: int,
    end_ns: int,
    channel_message_counts: Mapping[int, int],
) -> bytes:
    """Statistics record."""
    body = _STATISTICS_FIXED.pack(
        message_count,
        schema_count,
        channel_count,
        attachment_count,
        metadata_count,
        chunk_count,
        start_ns,
        end_ns,
    ) + u16_u64_map(channel_message_counts)
    return record(Op.STATISTICS, body)


def summary_offset(group_opcode: int, group_start: int, group_length: int) -> bytes:
    """Summary Offset record: where the summary group of ``group_opcode`` records is."""
    return record(Op.SUMMARY_OFFSET, struct.pack("<BQQ", group_opcode, group_start, group_length))


def data_end(data_section_crc: int = 0) -> bytes:
    """Data End record (CRC 0: not computed)."""
    return record(Op.DATA_END, _U32.pack(data_section_crc))


def joined(records: Iterable[bytes]) -> bytes:
    """Several records as one bytes object."""
    return b"".join(records)
