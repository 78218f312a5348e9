"""The shared memory between the daemon and one of its child processes (:mod:`.childproc`: the
MCAP writer, the live view): a byte ring of records (daemon → child) and a status block
(child → daemon). No system call, no wake-up, no lock
shared between the processes: each side reads and writes plain memory at its own pace.

Layout of one mapping (a ``memfd``, else an unlinked temporary file; the process gets its
descriptor at start):

========  =====================================================================================
offset    content
========  =====================================================================================
0         ``head``: u64, bytes ever written into the ring (the daemon writes it)
8         ``tail``: u64, bytes ever consumed (the process writes it)
16        ``wanted``: u8, bit mask of the topics some client watches (the process writes it)
24        ``heartbeat``: u64, ``CLOCK_MONOTONIC`` ns of the process's last loop (system-wide clock)
64        status block: u64 sequence (odd while being written), u32 length, u32 CRC-32, pickled
          status (the process writes it, the daemon reads it when asked for statistics)
65536     the ring: records of ``u32 length, u32 CRC-32, u32 messages, u32 0`` + data, each
          padded to 16 bytes; a length of ``0xFFFFFFFF`` means "continue at the ring's start"
========  =====================================================================================

One writer per field. The daemon never waits: a record that does not fit is refused (the caller
drops and counts it). The reader trusts a record only when its CRC-32 matches, so a record whose
bytes are not yet visible to it (memory order on weakly ordered CPUs) is read on the next poll,
never half; a record still wrong after :data:`CORRUPT_POLLS` polls is skipped and counted.
"""

from __future__ import annotations

import mmap
import os
import pickle
import struct
import tempfile
import zlib
from collections.abc import Iterator
from typing import Any

HEADER_BYTES = 65536
HEAD_OFF, TAIL_OFF, WANTED_OFF, HEARTBEAT_OFF, STATUS_OFF = 0, 8, 16, 24, 64
STATUS_MAX = HEADER_BYTES - STATUS_OFF - 16
"""Largest pickled status, bytes."""
_U64 = struct.Struct("<Q")
_REC = struct.Struct("<IIII")
_STATUS = struct.Struct("<QII")
WRAP = 0xFFFFFFFF
CORRUPT_POLLS = 10
"""Polls a record may fail its CRC (not yet visible) before it is skipped as corrupt."""


def _padded(n: int) -> int:
    return (n + 15) & ~15


def shared_file(size: int) -> int:
    """A file descriptor of ``size`` zeroed bytes that another process can map: a ``memfd``
    (Linux; no backing store) or else an unlinked temporary file."""
    try:
        fd = os.memfd_create("cmm-comp-child", 0)
    except (AttributeError, OSError):
        shm = "/dev/shm" if os.path.isdir("/dev/shm") else None
        with tempfile.TemporaryFile(dir=shm) as f:
            fd = os.dup(f.fileno())
    try:
        os.ftruncate(fd, size)
    except OSError:
        os.close(fd)
        raise
    return fd


def ring_bytes(queue: int, message_bytes: int = 256) -> int:
    """Ring capacity for ``queue`` messages of ``message_bytes`` each (a pickled one-record
    batch is ~150-250 bytes; a compact record within a batch ~60), at least 64 KiB, a multiple
    of 16 (every record starts 16-byte aligned, so a wrap marker always fits)."""
    return _padded(max(64 * 1024, message_bytes * int(queue)))


class SharedRing:
    """One side's view of the mapping. ``fd``: from :func:`shared_file`; ``capacity``: ring
    bytes (the mapping is :data:`HEADER_BYTES` + ``capacity``). ``populate``: map every page
    now (the daemon's side), so that no write into the ring ever takes a page fault (one per
    new 4 KiB page otherwise: measured at the writer's p99 until the ring had wrapped once)."""

    def __init__(self, fd: int, capacity: int, populate: bool = False) -> None:
        if capacity <= 0 or capacity % 16:
            raise ValueError(f"ring capacity {capacity} must be a positive multiple of 16")
        self.capacity = capacity
        size = HEADER_BYTES + capacity
        flags = mmap.MAP_SHARED | (getattr(mmap, "MAP_POPULATE", 0) if populate else 0)
        self.mm = mmap.mmap(fd, size, flags=flags)
        if populate:  # and write each page once: a write fault is not left for later either
            for off in range(0, size, mmap.PAGESIZE):
                self.mm[off] = self.mm[off]
        self._head = _U64.unpack_from(self.mm, HEAD_OFF)[0]
        self._tail = _U64.unpack_from(self.mm, TAIL_OFF)[0]
        self._status_seq = 0
        self._bad_polls = 0
        self.corrupt_skipped = 0
        """Bytes skipped because a record stayed wrong (reader side)."""

    def close(self) -> None:
        """Unmap (views of it must be gone)."""
        self.mm.close()

    # ------------------------------------------------------------------ the daemon (writer)
    def write(self, data: bytes, messages: int) -> bool:
        """Append one record of ``messages`` messages; False (nothing written) when it does not
        fit now. One writer at a time (the caller holds its lock)."""
        cap = self.capacity
        need = _REC.size + _padded(len(data))
        if need > cap // 2:
            return False
        head = self._head
        pos = head % cap
        skip = cap - pos if cap - pos < need else 0
        tail = _U64.unpack_from(self.mm, TAIL_OFF)[0]
        if head + skip + need - tail > cap:
            return False
        mm = self.mm
        if skip:
            _REC.pack_into(mm, HEADER_BYTES + pos, WRAP, 0, 0, 0)
            pos = 0
        start = HEADER_BYTES + pos + _REC.size
        mm[start : start + len(data)] = data
        _REC.pack_into(mm, HEADER_BYTES + pos, len(data), zlib.crc32(data), messages, 0)
        self._head = head + skip + need
        _U64.pack_into(mm, HEAD_OFF, self._head)
        return True

    def used_bytes(self) -> int:
        """Bytes written and not yet consumed (the writer's view)."""
        return int(self._head - _U64.unpack_from(self.mm, TAIL_OFF)[0])

    def wanted(self) -> int:
        """The process's topic bit mask."""
        return self.mm[WANTED_OFF]

    def heartbeat_ns(self) -> int:
        """The process's last loop, ``time.monotonic_ns()``; 0 before its first."""
        return int(_U64.unpack_from(self.mm, HEARTBEAT_OFF)[0])

    def status(self) -> Any:
        """The newest complete status the process wrote, or None (none yet, or it is being
        written: ask again later)."""
        mm = self.mm
        seq, n, crc = _STATUS.unpack_from(mm, STATUS_OFF)
        if seq == 0 or seq & 1 or n > STATUS_MAX:
            return None
        data = mm[STATUS_OFF + _STATUS.size : STATUS_OFF + _STATUS.size + n]
        if _U64.unpack_from(mm, STATUS_OFF)[0] != seq or zlib.crc32(data) != crc:
            return None
        return pickle.loads(data)

    # ------------------------------------------------------------------ the process (reader)
    def read(self) -> Iterator[tuple[int, bytes]]:
        """Every complete record written since the last call: ``(messages, data)``; the tail
        advances past each one taken."""
        cap, mm = self.capacity, self.mm
        head = _U64.unpack_from(mm, HEAD_OFF)[0]
        tail = self._tail
        while tail < head:
            pos = tail % cap
            n, crc, messages, _ = _REC.unpack_from(mm, HEADER_BYTES + pos)
            if n == WRAP:
                tail += cap - pos
                continue
            start = HEADER_BYTES + pos + _REC.size
            data = mm[start : start + n] if n <= cap - pos - _REC.size else b""
            if n > cap - pos - _REC.size or zlib.crc32(data) != crc:
                self._bad_polls += 1
                if self._bad_polls < CORRUPT_POLLS:
                    break  # not visible yet: next poll
                self.corrupt_skipped += head - tail
                tail = head
                break
            self._bad_polls = 0
            tail += _REC.size + _padded(n)
            self._tail = tail
            _U64.pack_into(mm, TAIL_OFF, tail)
            yield messages, data
        self._tail = tail
        _U64.pack_into(mm, TAIL_OFF, tail)

    def backlog_bytes(self) -> int:
        """Bytes written and not yet read."""
        return int(_U64.unpack_from(self.mm, HEAD_OFF)[0] - self._tail)

    def set_wanted(self, mask: int) -> None:
        self.mm[WANTED_OFF] = mask & 0xFF

    def beat(self, now_ns: int) -> None:
        _U64.pack_into(self.mm, HEARTBEAT_OFF, now_ns)

    def set_status(self, data: bytes) -> bool:
        """Publish a pickled status (False: larger than :data:`STATUS_MAX`, not written)."""
        if len(data) > STATUS_MAX:
            return False
        mm = self.mm
        self._status_seq += 1
        _U64.pack_into(mm, STATUS_OFF, 2 * self._status_seq - 1)  # odd: being written
        start = STATUS_OFF + _STATUS.size
        mm[start : start + len(data)] = data
        _STATUS.pack_into(mm, STATUS_OFF, 2 * self._status_seq - 1, len(data), zlib.crc32(data))
        _U64.pack_into(mm, STATUS_OFF, 2 * self._status_seq)
        return True
