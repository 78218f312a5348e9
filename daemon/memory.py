"""Process memory: big buffers in their own mappings, given back to the OS when freed.

glibc serves an allocation of at least its *mmap threshold* (128 KiB at start) from a mapping
of its own, unmapped when freed. But the threshold is dynamic: the first time such a mapped
block is freed, glibc raises the threshold to that block's size (up to 32 MiB), so from then on
blocks of that size come from the heap of the allocating thread's arena, and freed heap memory
mostly stays in the process. In the daemon that is the grid reload: the prepared grid arrives
from the reload worker as a pickle of a few MiB and becomes numpy arrays; after the first
reload every later one left its buffers in the reload thread's arena, so the daemon's resident
memory rose in steps with reloads (measured, 60 reloads from threads that come and go: +29 MiB
with glibc's default; +2 MiB once, then flat, with the daemon's fixed thresholds; the 1 h
soak's daemon grew ~2 MiB/h in such steps). Setting the threshold explicitly turns the dynamic
adjustment off: grids and other big arrays live in their own mappings and leave with them.

Process-wide: called by the process entry points (``DaemonService.run_forever``, the MCAP
writer child), never at import. Only the threshold here: limiting the number of arenas (what the
writer child also does) made reply-path threads share allocator locks.
"""

from __future__ import annotations

import ctypes

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_ARENA_MAX = -1, -3, -8  # glibc mallopt() (malloc.h)
MMAP_THRESHOLD_BYTES = 128 * 1024
"""glibc's initial mmap threshold (what the MCAP writer child keeps fixed)."""
DAEMON_MMAP_THRESHOLD_BYTES = 512 * 1024
"""The daemon's fixed mmap threshold, bytes: above 256 KiB because python-can's
``udp_multicast`` packs every frame sent with a new ``msgpack.Packer``, whose buffer is 256 KiB:
with the 128 KiB threshold each answer frame cost an ``mmap`` + ``munmap`` and fresh pages
(measured +80 µs p50 reply latency, same run; strace: 2.3 maps a reading on the reply
thread)."""


def _mallopt(param: int, value: int) -> bool:
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl, macOS): nothing to do
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(param, value))


TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024
"""Free memory at the top of the heap kept for reuse before glibc gives it back, bytes."""


def fix_mmap_threshold(
    threshold_bytes: int = MMAP_THRESHOLD_BYTES, trim_bytes: int | None = TRIM_THRESHOLD_BYTES
) -> bool:
    """glibc only (else nothing, False): a fixed mmap threshold of ``threshold_bytes`` and,
    unless ``trim_bytes`` is None, a fixed trim threshold of ``trim_bytes``.

    Fixing the mmap threshold also stops glibc's dynamic trim threshold, leaving it at 128 KiB:
    the heap top is then given back and taken again (``brk``, fresh zeroed pages) whenever the
    small-object working set swings by that much, which the reply path paid in latency. The
    heap keeps up to ``trim_bytes`` free at its top instead; big blocks are mapped anyway."""
    if threshold_bytes <= 0:
        raise ValueError(f"mmap threshold {threshold_bytes} bytes; must be > 0")
    if trim_bytes is not None and trim_bytes <= 0:
        raise ValueError(f"trim threshold {trim_bytes} bytes; must be > 0")
    ok = _mallopt(M_MMAP_THRESHOLD, threshold_bytes)
    if trim_bytes is not None:
        ok = _mallopt(M_TRIM_THRESHOLD, trim_bytes) and ok
    return ok


def limit_arenas(n: int) -> bool:
    """glibc only (else nothing, False): at most ``n`` malloc arenas (not one per thread)."""
    if n <= 0:
        raise ValueError(f"{n} malloc arenas; must be > 0")
    return _mallopt(M_ARENA_MAX, n)
