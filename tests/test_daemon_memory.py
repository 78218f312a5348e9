"""The daemon's allocator setting: big buffers stay in their own mappings after the first free.

Oracle: glibc's own accounting (``mallinfo2().hblkhd``, bytes in mmapped blocks), read in a
fresh interpreter (the setting is process-wide): a 4 MiB block allocated after an equal block was
freed is mapped with the fixed threshold, and comes from the heap with glibc's dynamic default.
"""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from cmm_comp.daemon.memory import fix_mmap_threshold, limit_arenas

PROBE = """
import ctypes, sys
class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]
libc = ctypes.CDLL(None)
libc.mallinfo2.restype = MallInfo2
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
if sys.argv[1] == "fixed":
    from cmm_comp.daemon.memory import fix_mmap_threshold
    assert fix_mmap_threshold()
p = libc.malloc(4 << 20)
libc.free(p)  # glibc's default now raises its threshold to 4 MiB
before = libc.mallinfo2().hblkhd
p = libc.malloc(4 << 20)
print(libc.mallinfo2().hblkhd - before)
libc.free(p)
"""


def _mapped_delta(mode: str) -> int:
    out = subprocess.run(
        [sys.executable, "-c", PROBE, mode], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    return int(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc allocator only")
def test_a_big_block_is_mapped_again_after_a_free_only_with_the_fixed_threshold() -> None:
    try:
        default = _mapped_delta("default")
    except AssertionError as exc:  # glibc older than 2.33 has no mallinfo2
        pytest.skip(f"no mallinfo2: {exc}")
    assert default == 0  # the dynamic threshold: the second block came from the heap
    assert _mapped_delta("fixed") >= 4 << 20  # its own mapping, unmapped when freed


@pytest.mark.parametrize("bad", [0, -1, -(2**31)])
def test_bad_settings_are_refused_with_the_allowed_range(bad: int) -> None:
    with pytest.raises(ValueError, match="must be > 0"):
        fix_mmap_threshold(bad)
    with pytest.raises(ValueError, match="must be > 0"):
        limit_arenas(bad)
