"""Read MCAP session logs for replay and tests, including files cut by a crash.

The seeking reader (``mcap.reader.make_reader``) needs the summary at the end of the file, which a
killed writer never wrote; this module walks the file front to back with the stream reader
instead, stops at the break and reports ``truncated=True`` with everything read up to it. A set
of rolled files (a directory or a glob) reads as one session, in file order.
"""

from __future__ import annotations

import glob
import json
import re
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Footer, McapRecord, Message, Metadata
from mcap.stream_reader import StreamReader

from cmm_comp.protocol.session_topics import ns_from_stamp

TRUNCATION_ERRORS: tuple[type[BaseException], ...] = (
    McapError,
    struct.error,
    EOFError,
    ValueError,  # includes the stream reader's CRCValidationError
    zlib.error,
)
try:  # a half-written zstd chunk fails in the decompressor
    import zstandard

    TRUNCATION_ERRORS += (zstandard.ZstdError,)
except ImportError:  # pragma: no cover - mcap depends on it for zstd
    pass

_NUMBERED = re.compile(r"^(.*?)(\d+)\.mcap$")


def intact_records(f: IO[bytes], cut: list[str], **options: Any) -> Iterator[McapRecord]:
    """The records of ``f`` front to back (``StreamReader`` with CRCs checked, ``options``
    passed on) up to the first that cannot be read: its error text is appended to ``cut``."""
    records = StreamReader(f, validate_crcs=True, **options).records
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except TRUNCATION_ERRORS as exc:
            cut.append(f"{type(exc).__name__}: {exc}")
            return
        yield record


@dataclass(frozen=True)
class LoggedMessage:
    """One decoded message: ``log_time_ns`` is MCAP's integer ns, ``payload`` the JSON object."""

    topic: str
    log_time_ns: int
    payload: dict[str, Any]


class MessageStream:
    """Iterate the messages of one or more MCAP files front to back, surviving a cut file.

    After (or during) iteration ``truncated`` is True when any file ended without its footer,
    ``error`` holds the text of the error met at the break, and ``metadata`` the metadata records
    as ``(name, dict)``. Iterate once.

    :param files: MCAP paths, read in the given order.
    :param topics: only these topics; all when None.
    """

    def __init__(self, files: Iterable[str | Path], topics: Iterable[str] | None = None) -> None:
        self.files = tuple(Path(f) for f in files)
        self.topics = None if topics is None else frozenset(topics)
        self.truncated = False
        self.errors: list[str] = []
        self.metadata: list[tuple[str, dict[str, str]]] = []

    @property
    def error(self) -> str | None:
        """The first error met at a break, or None."""
        return self.errors[0] if self.errors else None

    def __iter__(self) -> Iterator[LoggedMessage]:
        for path in self.files:
            yield from self._iter_file(path)

    def _iter_file(self, path: Path) -> Iterator[LoggedMessage]:
        channels: dict[int, Channel] = {}
        complete = False
        cut: list[str] = []
        with open(path, "rb") as f:
            for record in intact_records(f, cut):
                if isinstance(record, Message):
                    channel = channels.get(record.channel_id)
                    if channel is None:
                        self.errors.append(
                            f"{path}: message on unknown channel {record.channel_id}"
                        )
                        continue
                    if self.topics is not None and channel.topic not in self.topics:
                        continue
                    yield LoggedMessage(channel.topic, record.log_time, json.loads(record.data))
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Metadata):
                    self.metadata.append((record.name, dict(record.metadata)))
                elif isinstance(record, Footer):
                    complete = True
        if cut:  # even a footer without its closing magic is a cut file
            self.errors.append(f"{path}: {cut[0]}")
            complete = False
        if not complete:
            self.truncated = True


@dataclass(frozen=True)
class ReadResult:
    """All messages read, in file order, and whether a file was cut."""

    messages: list[LoggedMessage]
    truncated: bool
    files: tuple[Path, ...]
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    error: str | None = None


def session_files(source: str | Path | Iterable[str | Path]) -> tuple[Path, ...]:
    """Resolve a file, a directory of ``*.mcap`` or a glob pattern to files in session order.

    Files ending in a number (``session-…-NNN.mcap``) sort numerically within their prefix, so
    ``-1000`` follows ``-999``. Raises FileNotFoundError naming the source if nothing matches.
    """
    if not isinstance(source, str | Path):
        return tuple(Path(p) for p in source)
    p = Path(source)
    if p.is_dir():
        found = list(p.glob("*.mcap"))
    elif p.is_file():
        return (p,)
    else:
        found = [Path(x) for x in glob.glob(str(source))]
    if not found:
        raise FileNotFoundError(f"{source}: no MCAP file (expected a file, directory or glob)")

    def key(path: Path) -> tuple[str, int, str]:
        m = _NUMBERED.match(path.name)
        return (m.group(1), int(m.group(2)), path.name) if m else (path.name, -1, path.name)

    return tuple(sorted(found, key=key))


def read_messages(
    source: str | Path | Iterable[str | Path], topics: Iterable[str] | None = None
) -> ReadResult:
    """Read every message of ``topics`` (all when None) from a file, directory or glob."""
    stream = MessageStream(session_files(source), topics)
    messages = list(stream)
    return ReadResult(messages, stream.truncated, stream.files, stream.metadata, stream.error)


# --------------------------------------------------------------------------- columns


@dataclass(frozen=True)
class RawColumns:
    """``/cmm/raw`` as arrays: seq (N,) int64, stamp_ns (N,) int64, xyz_mm (N, 3) float64."""

    seq: np.ndarray
    stamp_ns: np.ndarray
    xyz_mm: np.ndarray


@dataclass(frozen=True)
class CorrectedColumns:
    """``/cmm/corrected``: seq, stamp_ns, xyz_mm (N, 3) mm, status (N,) str, d_um (N, 3) µm
    and latency_us (N,) µs (NaN where a message had no such field)."""

    seq: np.ndarray
    stamp_ns: np.ndarray
    xyz_mm: np.ndarray
    status: np.ndarray
    d_um: np.ndarray
    latency_us: np.ndarray


@dataclass(frozen=True)
class TemperatureColumns:
    """``/cmm/temperature``: sensor (N,) str, role (N,) str, temp_C (N,) °C, stamp_ns (N,)."""

    sensor: np.ndarray
    role: np.ndarray
    temp_C: np.ndarray
    stamp_ns: np.ndarray


@dataclass(frozen=True)
class Session:
    """A logged session as columns, plus where it came from and whether it was cut."""

    raw: RawColumns
    corrected: CorrectedColumns
    temperature: TemperatureColumns
    truncated: bool
    files: tuple[Path, ...]
    metadata: list[tuple[str, dict[str, str]]]


def _num(d: dict[str, Any], key: str) -> float:
    v = d.get(key)
    return float("nan") if v is None else float(v)


def _stamps(payloads: list[dict[str, Any]]) -> np.ndarray:
    return np.array([ns_from_stamp(p["stamp"]) for p in payloads], dtype=np.int64)


def _xyz(payloads: list[dict[str, Any]], keys: tuple[str, str, str]) -> np.ndarray:
    return np.array([[_num(p, k) for k in keys] for p in payloads], dtype=float).reshape(-1, 3)


def _str(payloads: list[dict[str, Any]], key: str) -> np.ndarray:
    return np.array([str(p[key]) for p in payloads], dtype=str)


def load_session(source: str | Path | Iterable[str | Path]) -> Session:
    """Read ``/cmm/raw``, ``/cmm/corrected`` and ``/cmm/temperature`` into numpy columns."""
    res = read_messages(source, ("/cmm/raw", "/cmm/corrected", "/cmm/temperature"))
    by: dict[str, list[dict[str, Any]]] = {
        "/cmm/raw": [],
        "/cmm/corrected": [],
        "/cmm/temperature": [],
    }
    for m in res.messages:
        by[m.topic].append(m.payload)
    raw, cor, tmp = by["/cmm/raw"], by["/cmm/corrected"], by["/cmm/temperature"]
    return Session(
        raw=RawColumns(
            seq=np.array([p["seq"] for p in raw], dtype=np.int64),
            stamp_ns=_stamps(raw),
            xyz_mm=_xyz(raw, ("x_mm", "y_mm", "z_mm")),
        ),
        corrected=CorrectedColumns(
            seq=np.array([p["seq"] for p in cor], dtype=np.int64),
            stamp_ns=_stamps(cor),
            xyz_mm=_xyz(cor, ("x_mm", "y_mm", "z_mm")),
            status=_str(cor, "status"),
            d_um=_xyz(cor, ("dx_um", "dy_um", "dz_um")),
            latency_us=np.array([_num(p, "latency_us") for p in cor], dtype=float),
        ),
        temperature=TemperatureColumns(
            sensor=_str(tmp, "sensor"),
            role=_str(tmp, "role"),
            temp_C=np.array([float(p["temp_C"]) for p in tmp], dtype=float),
            stamp_ns=_stamps(tmp),
        ),
        truncated=res.truncated,
        files=res.files,
        metadata=res.metadata,
    )
