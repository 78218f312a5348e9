"""The correction grid file: versioned, self-describing, checksummed, written atomically.

Layout: a NumPy ``.npz`` (zip) archive, read with ``allow_pickle=False``, holding

* ``header``: UTF-8 JSON (as uint8) with ``format = "cmm-grid"``, ``format_version = 1``, the
  machine (name, model, sha256 of its description), volume, steps, units, reference values of
  the runtime signals, stylus convention, build time and library version;
* the payload arrays named in :data:`PAYLOAD_ARRAYS` (node quaternions (w, x, y, z),
  translations µm, per-signal sensitivity grids);
* version 2 only (a grid carrying U): ``uncertainty_covariance`` (nx, ny, nz, 15), the residual
  pose covariance per node, and the header object ``uncertainty`` (:mod:`.uncertainty`); it is a
  payload array like the others (in the SHA-256, hence under the signature);
* ``sha256``: the hex SHA-256 (as uint8) over every payload array (name, dtype, shape, bytes,
  in sorted order) followed by the header bytes;
* optionally ``signature``: UTF-8 JSON (as uint8), an Ed25519 signature over the SHA-256 and the
  header bytes (added by ``cmm-comp grid sign``; :mod:`.signing`). It is not part of the SHA-256,
  so signing never changes a grid's identity.

Any problem on reading raises a single :class:`GridFileError` naming the file and the problem.
:func:`grid_header`, :func:`save_grid` and :func:`load_grid` convert between a
:class:`CorrectionGrid` and this file (``CorrectionGrid.header/save/load`` delegate here).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from ..errors import GridFileError
from ..formats.atomic import atomic_output
from .inputs import GridSignal

if TYPE_CHECKING:
    from .correction_grid import CorrectionGrid

G = TypeVar("G", bound="CorrectionGrid")

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "FORMAT_VERSION_UNCERTAINTY",
    "OPTIONAL_ARRAYS",
    "PAYLOAD_ARRAYS",
    "SIGNATURE_MEMBER",
    "SUPPORTED_VERSIONS",
    "UNCERTAINTY_MEMBER",
    "GridContents",
    "GridFileError",
    "grid_header",
    "load_grid",
    "payload_sha256",
    "read_grid_contents",
    "read_grid_file",
    "save_grid",
    "write_grid_file",
    "write_grid_members",
]

FORMAT_NAME = "cmm-grid"
FORMAT_VERSION = 1
#: Version 2 = version 1 + the ``uncertainty`` header object and the ``uncertainty_covariance``
#: member (a grid carrying U). A grid without U is still written as version 1, byte for byte as
#: before, so readers that know only version 1 keep reading it.
FORMAT_VERSION_UNCERTAINTY = 2
SUPPORTED_VERSIONS = (FORMAT_VERSION, FORMAT_VERSION_UNCERTAINTY)
UNCERTAINTY_MEMBER = "uncertainty_covariance"  # (nx, ny, nz, 15), see .uncertainty
OPTIONAL_ARRAYS = (UNCERTAINTY_MEMBER,)
PAYLOAD_ARRAYS = (
    "q_work_stylus",  # (nx, ny, nz, 4) unit quaternions (w, x, y, z) of the error rotation
    "translation_um",  # (nx, ny, nz, 3) error translation at stylus offset 0, µm
    "sensitivity_translation_um",  # (S, nx, ny, nz, 3) µm per unit of each signal
    "sensitivity_rotation_urad",  # (S, nx, ny, nz, 3) rotation vector, µrad per unit of signal
)
SIGNATURE_MEMBER = "signature"


@dataclass(frozen=True)
class GridContents:
    """A grid file as read and checked (format, version, dtypes, SHA-256), not yet a grid."""

    source: Path
    header: dict[str, Any]
    header_bytes: bytes
    """The header exactly as stored (what the SHA-256 and the signature cover)."""
    arrays: dict[str, NDArray[np.float64]]
    sha256: str
    signature: bytes | None
    """The ``signature`` member (JSON bytes), None when the file is unsigned."""


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
    payload = {
        name: np.ascontiguousarray(arrays[name], dtype=np.float64)
        for name in (*PAYLOAD_ARRAYS, *OPTIONAL_ARRAYS)
        if name in arrays
    }
    header_bytes = json.dumps(dict(header), sort_keys=True, indent=1).encode()
    sha = payload_sha256(payload, header_bytes)
    write_grid_members(path, header_bytes, payload, sha, None)
    return sha


def write_grid_members(
    path: str | Path,
    header_bytes: bytes,
    arrays: Mapping[str, NDArray[np.float64]],
    sha256: str,
    signature: bytes | None,
) -> None:
    """Write the archive members as given (atomically, fsync); signing rewrites a file so."""
    members: dict[str, Any] = {
        name: arrays[name] for name in (*PAYLOAD_ARRAYS, *OPTIONAL_ARRAYS) if name in arrays
    }
    members["header"] = np.frombuffer(header_bytes, dtype=np.uint8)
    members["sha256"] = np.frombuffer(sha256.encode(), dtype=np.uint8)
    if signature is not None:
        members[SIGNATURE_MEMBER] = np.frombuffer(signature, dtype=np.uint8)
    with atomic_output(Path(path), "wb", fsync=True) as fh:
        np.savez(fh, **members)


def read_grid_file(path: str | Path) -> tuple[dict[str, Any], dict[str, NDArray[np.float64]], str]:
    """Read and verify a grid file: ``(header, payload arrays, sha256)``; :class:`GridFileError`."""
    contents = read_grid_contents(path)
    return contents.header, contents.arrays, contents.sha256


def read_grid_contents(path: str | Path) -> GridContents:
    """Read a grid file once (one read of its bytes: a file replaced meanwhile cannot mix two
    versions) and check format, version, dtypes and SHA-256; :class:`GridFileError`."""
    source = Path(path)
    if not source.is_file():
        raise GridFileError(f"{source}: no such grid file")
    try:
        data = source.read_bytes()
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            names = set(npz.files)
            missing = [n for n in ("header", "sha256", *PAYLOAD_ARRAYS) if n not in names]
            if missing:
                raise GridFileError(
                    f"{source}: not a complete cmm-comp grid file (missing {', '.join(missing)})"
                )
            header_bytes = npz["header"].tobytes()
            stored_sha = npz["sha256"].tobytes().decode("ascii", errors="replace")
            arrays = {
                name: np.asarray(npz[name])
                for name in (*PAYLOAD_ARRAYS, *OPTIONAL_ARRAYS)
                if name in names
            }
            signature = npz[SIGNATURE_MEMBER].tobytes() if SIGNATURE_MEMBER in names else None
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
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise GridFileError(f"{source}: header is not valid JSON ({exc!s:.200})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        fmt = header.get("format") if isinstance(header, dict) else None
        raise GridFileError(
            f"{source}: not a cmm-comp grid (format {fmt!r}, expected {FORMAT_NAME!r})"
        )
    version = header.get("format_version")
    if isinstance(version, bool) or version not in SUPPORTED_VERSIONS:
        raise GridFileError(
            f"{source}: unsupported grid format version {version!r} "
            f"(this library reads versions {', '.join(map(str, SUPPORTED_VERSIONS))})"
        )
    has_u = UNCERTAINTY_MEMBER in arrays
    if (version == FORMAT_VERSION_UNCERTAINTY) != has_u or (has_u != ("uncertainty" in header)):
        raise GridFileError(
            f"{source}: grid format version {version} "
            + (
                "needs the uncertainty member and header object"
                if version == FORMAT_VERSION_UNCERTAINTY
                else "cannot carry an uncertainty member or header object (that is version 2)"
            )
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
    return GridContents(source, header, header_bytes, arrays, actual, signature)


def _library_version() -> str:
    try:
        from importlib.metadata import version

        return version("cmm-comp")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


def grid_header(grid: CorrectionGrid) -> dict[str, Any]:
    """The self-describing file header of ``grid`` (JSON-serialisable)."""
    meta = dict(grid.metadata)
    machine = meta.pop("machine", {"name": "", "model": "", "sha256": ""})
    ref_c = next((s.reference for s in grid.signals if s.is_temperature), 20.0)
    extra: dict[str, Any] = {}
    if grid.uncertainty is not None:
        extra["uncertainty"] = grid.uncertainty.to_header()
    return {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION
        if grid.uncertainty is None
        else FORMAT_VERSION_UNCERTAINTY,
        "machine": machine,
        "volume": {"lower_mm": grid.lower_mm.tolist(), "upper_mm": grid.upper_mm.tolist()},
        "steps": list(grid.steps),
        "units": {
            "position": "mm",
            "translation": "um",
            "rotation": "unit quaternion (w, x, y, z)",
            "sensitivity_translation": "um per signal unit",
            "sensitivity_rotation": "urad (rotation vector) per signal unit",
        },
        "reference_C": ref_c,
        "stylus_convention": (
            "error_um = translation_um + 1000 (R - I) p, p = stylus offset (mm) from the "
            "point the translation refers to; corrected = indicated + error; "
            "error = true - indicated"
        ),
        "interpolation": {
            "rotation": "tensor-product Squad x, y, z; quadratic end control points",
            "translation": "tricubic not-a-knot B-spline (C2)",
        },
        "signals": [
            {"name": s.name, "reference": s.reference, "needed": s.needed} for s in grid.signals
        ],
        "outside_policy": grid.outside,
        "built_utc": meta.pop("built_utc", _dt.datetime.now(_dt.UTC).isoformat()),
        "library_version": meta.pop("library_version", _library_version()),
        **meta,
        **extra,
    }


def save_grid(grid: CorrectionGrid, path: str | Path) -> str:
    """Write ``grid`` to ``path`` atomically; return the file's SHA-256 (also set on the grid)."""
    header = grid_header(grid)
    grid.metadata.setdefault("built_utc", header["built_utc"])
    grid.metadata.setdefault("library_version", header["library_version"])
    arrays = {
        "q_work_stylus": grid.q_work_stylus,
        "translation_um": grid.translation_um,
        "sensitivity_translation_um": grid.sensitivity_translation_um,
        "sensitivity_rotation_urad": grid.sensitivity_rotation_urad,
    }
    if grid.uncertainty is not None:
        arrays[UNCERTAINTY_MEMBER] = grid.uncertainty.covariance
    grid.sha256 = write_grid_file(path, header, arrays)
    return grid.sha256


def load_grid(
    cls: type[G],
    path: str | Path,
    expect_machine: Any = None,
    outside: str | None = None,
    verify: Callable[[GridContents], None] | None = None,
) -> G:
    """Read a grid file; :class:`GridFileError` (a ``ValueError``) names file and problem.

    ``expect_machine``: a machine (anything with ``identity_sha256()``) or a sha256 hex
    string; the file must have been built from that machine description. ``verify``: called
    with the checked file contents before the grid is built (e.g. a signature check, which
    raises :class:`GridFileError`); it sees exactly the bytes the grid is built from.
    """
    contents = read_grid_contents(path)
    if verify is not None:
        verify(contents)
    header, arrays, sha = contents.header, contents.arrays, contents.sha256
    try:
        uncertainty = None
        if UNCERTAINTY_MEMBER in arrays:
            from .uncertainty import GridUncertainty

            uncertainty = GridUncertainty.from_header(
                header["uncertainty"], arrays[UNCERTAINTY_MEMBER]
            )
        machine = header["machine"]
        sigs = [
            GridSignal(str(s["name"]), float(s["reference"]), bool(s["needed"]))
            for s in header["signals"]
        ]
        grid = cls(
            header["volume"]["lower_mm"],
            header["volume"]["upper_mm"],
            arrays["q_work_stylus"],
            arrays["translation_um"],
            sigs,
            arrays["sensitivity_translation_um"],
            arrays["sensitivity_rotation_urad"],
            {
                k: v
                for k, v in header.items()
                if k
                in (
                    "machine",
                    "source",
                    "reference_mm",
                    "probe_offset_mm",
                    "signal_filters",
                    "nonlinearity",
                    "unresolved_effects",
                    "built_utc",
                    "library_version",
                )
            },
            outside or header.get("outside_policy", "refuse"),
            uncertainty,
        )
        if list(grid.steps) != list(header["steps"]):
            raise ValueError(f"header steps {header['steps']} do not match the arrays {grid.steps}")
    except (KeyError, TypeError, ValueError) as exc:
        raise GridFileError(f"{path}: invalid grid content ({exc})") from None
    if expect_machine is not None:
        want = (
            expect_machine if isinstance(expect_machine, str) else expect_machine.identity_sha256()
        )
        if machine.get("sha256") != want:
            raise GridFileError(
                f"{path}: grid was built for machine {machine.get('name')!r} "
                f"(description sha256 {str(machine.get('sha256'))[:12]}…), "
                f"not for the expected one (sha256 {want[:12]}…); rebuild the grid"
            )
    grid.sha256 = sha
    return grid
