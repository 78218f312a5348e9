"""The process writer's child side: run a :class:`.thread_writer.McapLogger` fed over a pipe.

:class:`.process_writer.McapProcessLogger` starts a fresh interpreter that calls
:func:`child_entry`; the first message on the pipe holds the :class:`.logger.LogSettings` and
the CPU priority, then batches of pickled ``(topic, payload, log_time_ns)`` follow until the
sentinel :data:`STOP` (or EOF: the parent died). The child reports its counters, files and
errors back on the same duplex pipe. See :mod:`.process_writer` for the whole design.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import os
import pickle
import signal
import time
from multiprocessing.connection import Connection
from typing import cast

from cmm_comp.compensation.errors import CmmCompError

from .. import memory
from ..osthread import expected_priority, lower_priority, name_os_thread
from .logger import LogSettings, QueuedMessage
from .thread_writer import McapLogger

_log = logging.getLogger(__name__)

REPORT_S = 0.1
"""The child reports its counters at most this often while they change, s."""
STOP = b""
"""Sentinel batch: no more messages, finish the file and exit."""


class McapWriterProcessError(CmmCompError, RuntimeError):
    """An error of the writer child that could not be passed on as its own exception type."""


def _portable_exc(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a :class:`McapWriterProcessError` with its repr."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return McapWriterProcessError(repr(exc))
    return exc


HELP_HIGH = 8192
"""Backlog (messages) at which the child's main thread starts writing itself…"""
HELP_LOW = 1024
"""…until this many are left."""


MMAP_THRESHOLD_BYTES = memory.MMAP_THRESHOLD_BYTES
"""Allocations of this size and more (chunk buffers, batches) are mapped and given back to the
OS when freed. glibc's default raises the threshold after the first such free, and freed chunk
buffers then stay in the heap: the writer child's RSS crept (~20 MiB/h at 1 kHz)."""


def tune_malloc() -> bool:
    """glibc only (else nothing, False): a fixed mmap threshold of
    :data:`MMAP_THRESHOLD_BYTES` and at most two malloc arenas (not one per thread)."""
    return memory.fix_mmap_threshold(MMAP_THRESHOLD_BYTES, None) and memory.limit_arenas(2)


def child_entry(fd: int, parent_pid: int) -> None:
    """Child process entry (``python -c``): the pipe end is ``fd``; the first message on it
    holds the :class:`LogSettings` and the CPU priority."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    name_os_thread("mcap-child")
    tune_malloc()
    conn = Connection(fd)
    try:
        settings, priority = pickle.loads(conn.recv_bytes())
    except (EOFError, OSError):
        conn.close()
        return
    metadata = {**settings.metadata, "writer_priority": expected_priority(priority)}
    child_main(conn, dataclasses.replace(settings, metadata=metadata), parent_pid, priority)


def child_main(
    conn: Connection, settings: LogSettings, parent_pid: int, priority: str = "normal"
) -> None:
    """Run a McapLogger fed from ``conn`` until the sentinel or EOF, reporting back on it.

    The logger's writer thread runs at ``priority``; this (main) thread keeps the normal
    priority, takes the batches off the pipe at once, and writes itself while more than
    :data:`HELP_HIGH` messages wait (a loaded machine can starve an idle-priority writer)."""
    errors: collections.deque[BaseException] = collections.deque()
    metadata = {**settings.metadata, "writer_pid": str(os.getpid())}
    settings = dataclasses.replace(settings, metadata=metadata)

    def writer_setup() -> None:
        took = lower_priority(priority)
        if took != expected_priority(priority):
            _log.warning("MCAP writer priority %r not available: %s", priority, took)

    try:
        logger = McapLogger.from_settings(settings, errors.append, writer_setup=writer_setup)
    except BaseException as exc:
        conn.send_bytes(pickle.dumps(("init_error", _portable_exc(exc))))
        conn.close()
        return
    received = 0

    def report(kind: str) -> None:
        while errors:
            exc = errors.popleft()
            # the logger's error stops it; anything else (a message that could not be
            # encoded) is a warning: counted, recorded, the log goes on
            level = "error" if exc is logger.error else "warning"
            conn.send_bytes(pickle.dumps((level, _portable_exc(exc))))
        st = logger.own_stats()  # the parent adds its own drops
        conn.send_bytes(
            pickle.dumps(
                (
                    kind,
                    {
                        "received": received,
                        "written": st.written,
                        "dropped": st.dropped,
                        "encode_errors": st.encode_errors,
                        "files": st.files,
                        "queue_len": st.queue_len,
                        "healthy": logger.healthy,
                        "dropped_by_topic": dict(st.dropped_by_topic),
                        "encode_errors_by_topic": dict(st.encode_errors_by_topic),
                        "written_by_topic": dict(st.written_by_topic),
                        "flushed": st.flushed,
                    },
                )
            )
        )

    parent_alive = True
    try:
        report("stats")  # "ready": the first file is open
        last_report = time.monotonic()
        last_counts: tuple[int, ...] = ()
        while True:
            if conn.poll(REPORT_S / 2):
                data = conn.recv_bytes()
                if data == STOP:
                    break
                upstream_drops, batch = pickle.loads(data)
                batch = cast(list[QueuedMessage], batch)
                logger.set_upstream_drops(upstream_drops)
                logger.enqueue(batch)
                received += len(batch)
                logger.kick()  # write now, in the gap the daemon's kick announced
                if logger.backlog > HELP_HIGH:
                    logger.drain_to(HELP_LOW)
            elif os.getppid() != parent_pid:  # reparented: the parent died, pipe held elsewhere
                parent_alive = False
                break
            now = time.monotonic()
            if errors or now - last_report >= REPORT_S:
                st = logger.stats()
                counts = (received, st.written, st.dropped, len(st.files), st.flushed)
                if errors or counts != last_counts:
                    report("stats")
                    last_counts = counts
                last_report = now
    except (EOFError, OSError):  # the parent died (EOF or broken pipe): finish the file
        parent_alive = False
    finally:
        # drain and finish the file here, at this thread's normal priority: the writer thread
        # at SCHED_IDLE gets next to no CPU on a saturated machine (the parent bounds the wait)
        logger.finish_here(1.0)
        if parent_alive:
            with contextlib.suppress(OSError):
                report("done")
        conn.close()
