"""OS-level traits of the daemon's threads: their names and their CPU priority.

Names: OS threads are named after their Python threads, so ``top -H``, ``ps -L`` and ``perf``
show which part of the daemon a thread is (``can-endpoint``, ``mcap-writer``, …) instead of
``python``. Linux only (``prctl(PR_SET_NAME)``, 15 characters); elsewhere, or if it fails,
nothing happens: a name is a diagnostic aid, never a reason to stop.

Priority: :func:`lower_priority` puts background work (the MCAP writer, the grid loader
process) at Linux ``SCHED_IDLE`` so the reply path always comes first.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
import sys
import threading
from collections.abc import Callable

_PR_SET_NAME = 15


@functools.cache
def _prctl() -> Callable[..., int] | None:
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


def expected_priority(priority: str) -> str:
    """What :func:`lower_priority` will achieve here: ``idle``, ``nice 19`` or ``normal``."""
    if priority == "normal":
        return "normal"
    return "idle" if hasattr(os, "SCHED_IDLE") else "nice 19"


def lower_priority(priority: str) -> str:
    """Lower the calling thread's CPU priority (Linux: policy and nice are per thread);
    returns what took effect. ``idle``: Linux ``SCHED_IDLE`` (a woken normal task always
    preempts it, so the writer never delays the daemon's reply path), else nice 19 where
    SCHED_IDLE is missing; ``normal``: unchanged (the grid loader redoing a reload the idle
    worker could not do on a saturated machine). Why not nice 19 alone: measured over
    ``udp_multicast`` with SIGHUPs every ~0.2 s (a grid whose load takes ~0.5 s of CPU, so the
    loader never rests), with the loader at nice 19 the daemon's reply p50 rose from 279 to
    461 µs and its p99 4.8×; at ``SCHED_IDLE`` reloads made no difference (``bench_daemon.py``,
    same run)."""
    if priority == "normal":
        return "normal"
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        return "idle"
    except (AttributeError, OSError):
        pass
    try:
        os.nice(19 - os.nice(0))
        return "nice 19"
    except (AttributeError, OSError):
        return "normal"
