"""Atomic file output: a file is either the complete new content or left as it was.

Every writer of user-facing files (machine TOML, grid files, CLI outputs) goes through
:func:`atomic_output`: the content is written to a temporary file in the same folder, then
renamed over the target; on any failure the temporary file is removed and nothing already
written is lost.

Modes: ``tempfile.mkstemp`` creates its file 0600 whatever the umask; before the rename the file
gets the mode a plain ``open(path, "w")`` would have given it (``0o666 & ~umask``, e.g. 0644 under
the usual umask 022), so a grid, a table or an ``export.html`` can be read by the controller's
account or a web server exactly as the user's umask allows. A caller writing a secret passes
``mode=0o600`` (the umask still applies on top).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_output", "current_umask", "write_text_atomic"]


def current_umask() -> int:
    """This process's umask, read without changing it (Linux ≥ 4.7: ``/proc/self/status``);
    elsewhere set and restored at once (``os.umask`` has no read-only form)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(
    path: str | os.PathLike[str],
    mode: str = "w",
    *,
    fsync: bool = False,
    permissions: int = 0o666,
) -> Iterator[IO[Any]]:
    """Open a temporary sibling of ``path`` (``mode`` ``"w"`` text UTF-8 or ``"wb"``); on a clean
    exit it replaces ``path`` (after ``fsync`` if asked), on an exception it is removed.

    The file gets ``permissions & ~umask`` (the default 0o666: what ``open()`` gives)."""
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    try:
        encoding = None if "b" in mode else "utf-8"
        with os.fdopen(fd, mode, encoding=encoding, newline="" if encoding else None) as fh:
            os.fchmod(fh.fileno(), permissions & ~current_umask())  # mkstemp made it 0600
            yield fh
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_output`)."""
    with atomic_output(path) as fh:
        fh.write(text)
