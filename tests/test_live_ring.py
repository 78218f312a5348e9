"""The shared memory between the daemon and the live view's process (daemon/live/ring.py).
Oracle: a plain list of what was written, in order; every record read back must equal it byte
for byte, across wraps, with a full ring refusing (never overwriting) and a record whose bytes
are not (yet) right held back, then skipped and counted."""

from __future__ import annotations

import os
import pickle
import random
import struct
from collections.abc import Iterator

import pytest

from cmm_comp.daemon.ring import (
    CORRUPT_POLLS,
    HEADER_BYTES,
    STATUS_MAX,
    STATUS_OFF,
    SharedRing,
    ring_bytes,
    shared_file,
)


@pytest.fixture
def pair() -> Iterator[tuple[SharedRing, SharedRing]]:
    """A writer and a reader mapping the same shared file (4 KiB of ring)."""
    cap = 4096
    fd = shared_file(HEADER_BYTES + cap)
    try:
        w, r = SharedRing(fd, cap), SharedRing(fd, cap)
    finally:
        os.close(fd)
    yield w, r
    w.close()
    r.close()


def test_records_come_back_in_order_across_many_wraps(pair: tuple[SharedRing, SharedRing]) -> None:
    w, r = pair
    rng = random.Random(7)
    written: list[tuple[int, bytes]] = []
    got: list[tuple[int, bytes]] = []
    refused = 0
    for i in range(5000):
        data = rng.randbytes(rng.randint(0, 600))
        if w.write(data, i % 5 + 1):
            written.append((i % 5 + 1, data))
        else:
            refused += 1
        if rng.random() < 0.3:  # the reader polls now and then
            got += list(r.read())
    got += list(r.read())
    assert got == written
    assert refused > 0  # the ring did fill up now and then: refused, never overwritten
    assert r.backlog_bytes() == 0 and r.corrupt_skipped == 0


def test_a_full_ring_refuses_and_a_read_makes_room(pair: tuple[SharedRing, SharedRing]) -> None:
    w, r = pair
    taken = 0
    while w.write(b"x" * 100, 1):
        taken += 1
    assert taken == 4096 // 128  # 16-byte header + 100 bytes padded to 112
    assert not w.write(b"", 1)
    assert len(list(r.read())) == taken
    assert w.write(b"x" * 100, 1)
    assert not w.write(b"y" * 2049, 1)  # more than half the ring: never fits


def test_a_record_not_yet_right_is_held_back_then_skipped(
    pair: tuple[SharedRing, SharedRing],
) -> None:
    w, r = pair
    assert w.write(b"first", 1) and w.write(b"second", 1)
    w.mm[HEADER_BYTES + 16] ^= 0xFF  # the first record's bytes, as if not yet visible
    for _ in range(CORRUPT_POLLS - 1):
        assert list(r.read()) == []  # held back, the tail stays
    assert list(r.read()) == []  # given up: everything up to the head skipped, counted
    assert r.corrupt_skipped == 2 * 32 and r.backlog_bytes() == 0
    assert w.write(b"third", 1)
    assert list(r.read()) == [(1, b"third")]


def test_status_round_trip_and_a_torn_status_is_not_read(
    pair: tuple[SharedRing, SharedRing],
) -> None:
    w, r = pair
    assert w.status() is None  # nothing written yet
    r.set_status(pickle.dumps({"a": 1}))
    assert w.status() == {"a": 1}
    seq = struct.unpack_from("<Q", w.mm, STATUS_OFF)[0]
    struct.pack_into("<Q", w.mm, STATUS_OFF, seq + 1)  # odd: being written
    assert w.status() is None
    struct.pack_into("<Q", w.mm, STATUS_OFF, seq)
    w.mm[STATUS_OFF + 16] ^= 0xFF  # bytes that do not match their CRC
    assert w.status() is None
    assert not r.set_status(b"z" * (STATUS_MAX + 1))
    r.set_wanted(0b101)
    r.beat(123)
    assert (w.wanted(), w.heartbeat_ns()) == (0b101, 123)


def test_sizes_and_bad_capacity() -> None:
    assert ring_bytes(1) == 64 * 1024 and ring_bytes(4096) == 1024 * 1024
    assert ring_bytes(4097) % 16 == 0
    fd = shared_file(HEADER_BYTES + 64)
    try:
        with pytest.raises(ValueError, match="multiple of 16"):
            SharedRing(fd, 40)
    finally:
        os.close(fd)
