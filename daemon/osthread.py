"""Name OS threads after their Python threads, so ``top -H``, ``ps -L`` and ``perf`` show which
part of the daemon a thread is (``can-endpoint``, ``mcap-writer``, …) instead of ``python``.

Linux only (``prctl(PR_SET_NAME)``, 15 characters); elsewhere, or if it fails, nothing happens:
a name is a diagnostic aid, never a reason to stop.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys
import threading

_PR_SET_NAME = 15


@functools.cache
def _prctl() -> ctypes._CFuncPtr | None:  # type: ignore[name-defined]
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


def name_os_thread(name: str | None = None) -> bool:
    """Give the calling OS thread ``name`` (default: the Python thread's name), cut to 15
    bytes. Returns True when the name was set."""
    prctl = _prctl()
    if prctl is None:
        return False
    raw = (name or threading.current_thread().name).encode("utf-8", "replace")[:15]
    try:
        return int(prctl(_PR_SET_NAME, ctypes.c_char_p(raw), 0, 0, 0)) == 0
    except (OSError, ctypes.ArgumentError):
        return False
