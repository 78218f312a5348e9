"""The correction grid file: versioned, self-describing, checksummed, written atomically.

Layout: a NumPy ``.npz`` (zip) archive, read with ``allow_pickle=False``, holding

* ``header``: UTF-8 JSON (as uint8) with ``format = "cmm-grid"``, ``format_version = 1``, the
  machine (name, model, sha256 of its description), volume, steps, units, reference values of
  the runtime signals, stylus convention, build time and library version;
* the payload arrays named in :data:`PAYLOAD_ARRAYS` (node quaternions (w, x, y, z),
  translations µm, per-signal sensitivity grids);
* ``sha256``: the hex SHA-256 (as uint8) over every payload array (name, dtype, shape, bytes,
  in sorted order) followed by the header bytes.

Any problem on reading raises a single :class:`GridFileError` naming the file and the problem.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "PAYLOAD_ARRAYS",
    "GridFileError",
    "payload_sha256",
    "read_grid_file",
    "write_grid_file",
]

FORMAT_NAME = "cmm-grid"
FORMAT_VERSION = 1
PAYLOAD_ARRAYS = (
    "q_work_stylus",  # (nx, ny, nz, 4) unit quaternions (w, x, y, z) of the error rotation
    "translation_um",  # (nx, ny, nz, 3) error translation at stylus offset 0, µm
    "sensitivity_translation_um",  # (S, nx, ny, nz, 3) µm per unit of each signal
    "sensitivity_rotation_urad",  # (S, nx, ny, nz, 3) rotation vector, µrad per unit of signal
)


class GridFileError(ValueError):
    """A grid file cannot be used: the message names the file and the problem."""


def payload_sha256(arrays: Mapping[str, NDArray[Any]], header_bytes: bytes) -> str:
    """SHA-256 (hex) over the payload arrays (sorted by name) and the header bytes."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        digest.update(name.encode())
        digest.update(arr.dtype.str.encode())
        digest.update(repr(arr.shape).encode())
        digest.update(arr.tobytes())
    digest.update(header_bytes)
    return digest.hexdigest()


def write_grid_file(path: str | Path, header: Mapping[str, Any], arrays: Mapping[str, Any]) -> str:
    """Write atomically (temp file in the same folder, fsync, rename); return the SHA-256."""
    target = Path(path)
    payload = {
        name: np.ascontiguousarray(arrays[name], dtype=np.float64) for name in PAYLOAD_ARRAYS
    }
    header_bytes = json.dumps(dict(header), sort_keys=True, indent=1).encode()
    sha = payload_sha256(payload, header_bytes)
    members: dict[str, Any] = dict(payload)
    members["header"] = np.frombuffer(header_bytes, dtype=np.uint8)
    members["sha256"] = np.frombuffer(sha.encode(), dtype=np.uint8)
    folder = target.parent if str(target.parent) else Path(".")
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **members)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        raise
    return sha


def read_grid_file(path: str | Path) -> tuple[dict[str, Any], dict[str, NDArray[np.float64]], str]:
    """Read and verify a grid file: ``(header, payload arrays, sha256)``; :class:`GridFileError`."""
    source = Path(path)
    if not source.is_file():
        raise GridFileError(f"{source}: no such grid file")
    try:
        with open(source, "rb") as fh, np.load(fh, allow_pickle=False) as npz:
            names = set(npz.files)
            missing = [n for n in ("header", "sha256", *PAYLOAD_ARRAYS) if n not in names]
            if missing:
                raise GridFileError(
                    f"{source}: not a complete cmm-comp grid file (missing {', '.join(missing)})"
                )
            header_bytes = npz["header"].tobytes()
            stored_sha = npz["sha256"].tobytes().decode("ascii", errors="replace")
            arrays = {name: np.asarray(npz[name]) for name in PAYLOAD_ARRAYS}
    except GridFileError:
        raise
    except (
        OSError,
        ValueError,
        EOFError,
        TypeError,
        AttributeError,
        zipfile.BadZipFile,
        KeyError,
    ) as exc:
        raise GridFileError(
            f"{source}: not a readable grid file (truncated or corrupt: {exc})"
        ) from None
    try:
        header = json.loads(header_bytes.decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise GridFileError(f"{source}: header is not valid JSON ({exc})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        fmt = header.get("format") if isinstance(header, dict) else None
        raise GridFileError(
            f"{source}: not a cmm-comp grid (format {fmt!r}, expected {FORMAT_NAME!r})"
        )
    version = header.get("format_version")
    if version != FORMAT_VERSION:
        raise GridFileError(
            f"{source}: unsupported grid format version {version!r} "
            f"(this library reads version {FORMAT_VERSION})"
        )
    for name, arr in arrays.items():
        if arr.dtype != np.float64:
            raise GridFileError(f"{source}: array {name!r} has dtype {arr.dtype}, expected float64")
    actual = payload_sha256(arrays, header_bytes)
    if actual != stored_sha:
        raise GridFileError(
            f"{source}: SHA-256 mismatch, the file is corrupt or was modified "
            f"(stored {stored_sha[:16]}…, computed {actual[:16]}…)"
        )
    return header, arrays, actual
