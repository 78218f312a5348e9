"""Atomic file output: a file is either the complete new content or left as it was.

Every writer of user-facing files (machine TOML, grid files, CLI outputs) goes through
:func:`atomic_output`: the content is written to a temporary file in the same folder, then
renamed over the target; on any failure the temporary file is removed and nothing already
written is lost.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_output", "write_text_atomic"]


@contextlib.contextmanager
def atomic_output(
    path: str | os.PathLike[str], mode: str = "w", *, fsync: bool = False
) -> Iterator[IO[Any]]:
    """Open a temporary sibling of ``path`` (``mode`` ``"w"`` text UTF-8 or ``"wb"``); on a clean
    exit it replaces ``path`` (after ``fsync`` if asked), on an exception it is removed."""
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    try:
        encoding = None if "b" in mode else "utf-8"
        with os.fdopen(fd, mode, encoding=encoding, newline="" if encoding else None) as fh:
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
