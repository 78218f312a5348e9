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
:func:`grid_header` and :func:`save_grid` write what a grid holds (anything shaped like
:class:`GridRecord`), :func:`read_grid` reads it back as :class:`.nodes.NodeData` for
``CorrectionGrid.load``.
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
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from ..errors import GridFileError
from ..formats.atomic import atomic_output
from .inputs import GridSignal
from .nodes import NodeData

if TYPE_CHECKING:  # imported where a file carries U: numba stays out of `grid sign` and the like
    from .uncertainty import GridUncertainty

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
    "GridRecord",
    "StoredGrid",
    "grid_header",
    "payload_sha256",
    "read_grid",
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
#: Header keys a loaded grid keeps in its metadata (written back unchanged on a save).
METADATA_KEYS = (
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


class GridRecord(Protocol):
    """What the file holds of a grid (:class:`~.correction_grid.CorrectionGrid` is one)."""

    lower_mm: NDArray[np.float64]
    upper_mm: NDArray[np.float64]
    steps: tuple[int, int, int]
    q_work_stylus: NDArray[np.float64]
    translation_um: NDArray[np.float64]
    signals: tuple[GridSignal, ...]
    sensitivity_translation_um: NDArray[np.float64]
    sensitivity_rotation_urad: NDArray[np.float64]
    metadata: dict[str, Any]
    outside: str
    uncertainty: GridUncertainty | None


class StoredGrid(NamedTuple):
    """A grid file read and checked (:func:`read_grid`): the node data, the outside policy and
    the uncertainty it was saved with, and its SHA-256."""

    nodes: NodeData
    outside: str
    uncertainty: GridUncertainty | None
    sha256: str


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


def grid_header(grid: GridRecord) -> dict[str, Any]:
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


def save_grid(grid: GridRecord, path: str | Path) -> str:
    """Write ``grid`` to ``path`` atomically; return the file's SHA-256. The build time and
    library version the header gets are kept in ``grid.metadata`` (a later save repeats them)."""
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
    return write_grid_file(path, header, arrays)


def read_grid(
    path: str | Path,
    expect_machine: Any = None,
    verify: Callable[[GridContents], None] | None = None,
) -> StoredGrid:
    """Read a grid file; :class:`GridFileError` (a ``ValueError``) names file and problem.

    ``expect_machine``: a machine (anything with ``identity_sha256()``) or a sha256 hex
    string; the file must have been built from that machine description. ``verify``: called
    with the checked file contents before anything is taken from them (e.g. a signature check,
    which raises :class:`GridFileError`); it sees exactly the bytes the grid is built from.
    The node values themselves are checked when the grid is constructed.
    """
    contents = read_grid_contents(path)
    if verify is not None:
        verify(contents)
    header, arrays = contents.header, contents.arrays
    try:
        uncertainty = None
        if UNCERTAINTY_MEMBER in arrays:
            from .uncertainty import GridUncertainty

            uncertainty = GridUncertainty.from_header(
                header["uncertainty"], arrays[UNCERTAINTY_MEMBER]
            )
        sigs = [
            GridSignal(str(s["name"]), float(s["reference"]), bool(s["needed"]))
            for s in header["signals"]
        ]
        nodes = NodeData(
            header["volume"]["lower_mm"],
            header["volume"]["upper_mm"],
            arrays["q_work_stylus"],
            arrays["translation_um"],
            sigs,
            arrays["sensitivity_translation_um"],
            arrays["sensitivity_rotation_urad"],
            {k: v for k, v in header.items() if k in METADATA_KEYS},
        )
        steps = arrays["q_work_stylus"].shape[:3]
        if list(steps) != list(header["steps"]):
            raise ValueError(f"header steps {header['steps']} do not match the arrays {steps}")
        machine = header["machine"]
    except (KeyError, TypeError, ValueError) as exc:
        raise GridFileError(f"{path}: invalid grid content ({exc})") from None
    _check_machine(path, machine, expect_machine)
    return StoredGrid(nodes, header.get("outside_policy", "refuse"), uncertainty, contents.sha256)


def _check_machine(path: str | Path, machine: Mapping[str, Any], expect_machine: Any) -> None:
    """GridFileError unless the grid was built for ``expect_machine`` (None: any machine)."""
    if expect_machine is None:
        return
    want = expect_machine if isinstance(expect_machine, str) else expect_machine.identity_sha256()
    if machine.get("sha256") != want:
        raise GridFileError(
            f"{path}: grid was built for machine {machine.get('name')!r} "
            f"(description sha256 {str(machine.get('sha256'))[:12]}…), "
            f"not for the expected one (sha256 {want[:12]}…); rebuild the grid"
        )
