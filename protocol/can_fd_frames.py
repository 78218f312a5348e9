"""The CAN FD message pair: a whole reading in one frame, its whole answer in one frame.

On classic CAN a reading takes three 8-byte frames (RAW_X/Y/Z) and its answer four or five
(CORRECTED_X/Y/Z, the uncertainty, the status): the wire carries ~1,100 readings/s at 1 Mbit/s,
and every frame costs each receiver a wake-up. A controller on CAN FD sends **RAW_XYZ** (20
bytes) instead, and the daemon answers it with **CORRECTED_XYZ** (32 bytes: the three corrected
positions, the status, what was applied, the latency, the correction's length and the expanded
uncertainty U of each axis): two frames a reading instead of seven or eight. The daemon answers
each reading in the form it came in, so a node may mix both. Same scalings as the classic
frames (:mod:`.codes`), little-endian (Intel), standard 11-bit ids in the node's block
(offsets 0x5 and 0xD); ``cmm_comp.dbc`` describes both (``VFrameFormat`` StandardCAN_FD).

Layouts (byte offsets):

RAW_XYZ, 20 bytes: 0–4 X, 5–9 Y, 10–14 Z (int40, nm); 15–16 seq (uint16); 17 directions
(bits 0–1 X, 2–3 Y, 4–5 Z: 0 unknown, 1 positive, 2 negative; bits 6–7 reserved); 18 valid
(bit 0 X, 1 Y, 2 Z; bits 3–7 reserved); 19 reserved.

CORRECTED_XYZ, 32 bytes: 0–14 corrected X, Y, Z (int40, nm; the indicated ones when the status
says not corrected); 15–16 seq; 17 status (:class:`.Status`); 18 applied (:class:`.Applied`
mask); 19 reserved; 20–21 latency (µs, saturating); 22–23 |correction| (0.01 µm, saturating);
24–25, 26–27, 28–29 Ux, Uy, Uz (0.01 µm, rounded up; 0xFFFF unknown, 0xFFFE more than
655.33 µm); 30–31 reserved. Reserved bits are sent as 0 and ignored on receive.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar, Self

from .can_ids import MessageKind
from .codes import (
    APPLIED_MASK,
    UNCERTAINTY_SATURATED,
    UNCERTAINTY_UNKNOWN,
    Applied,
    Direction,
    Status,
    correction_raw_from_um,
    latency_raw_from_us,
    mm3_from_nm,
    um_from_correction_raw,
    um_from_uncertainty_raw,
    uncertainty_raw_from_um,
)

RAW_XYZ_SIZE = 20
CORRECTED_XYZ_SIZE = 32
_INT40_MIN, _INT40_MAX = -(1 << 39), (1 << 39) - 1

RAW_XYZ_LAYOUT = struct.Struct(
    "<"
    "5s5s5s"  # bytes 0-14: X, Y, Z indicated, int40 each, nm
    "H"  # bytes 15-16: seq, uint16
    "B"  # byte 17: directions, 2 bits per axis (X bits 0-1, Y 2-3, Z 4-5)
    "B"  # byte 18: valid bits (X bit 0, Y bit 1, Z bit 2)
    "x"  # byte 19: reserved (0)
)
CORRECTED_XYZ_LAYOUT = struct.Struct(
    "<"
    "5s5s5s"  # bytes 0-14: X, Y, Z corrected, int40 each, nm
    "H"  # bytes 15-16: seq, uint16, the reading this answers
    "B"  # byte 17: status code
    "B"  # byte 18: applied mask (bit 5 = U known)
    "x"  # byte 19: reserved (0)
    "H"  # bytes 20-21: latency, µs, saturating
    "H"  # bytes 22-23: |correction|, 0.01 µm, saturating
    "HHH"  # bytes 24-29: Ux, Uy, Uz, 0.01 µm rounded up; 0xFFFF unknown, 0xFFFE saturated
    "2x"  # bytes 30-31: reserved (0)
)
assert RAW_XYZ_LAYOUT.size == RAW_XYZ_SIZE and CORRECTED_XYZ_LAYOUT.size == CORRECTED_XYZ_SIZE


def _int40(value: int, name: str) -> bytes:
    if (
        not isinstance(value, int)
        or isinstance(value, bool)
        or not _INT40_MIN <= value <= _INT40_MAX
    ):
        raise ValueError(f"{name} {value!r} out of range {_INT40_MIN}..{_INT40_MAX} nm")
    return value.to_bytes(5, "little", signed=True)


def _u16(value: int, name: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 0xFFFF:
        raise ValueError(f"{name} {value!r} out of range 0..65535")
    return value


def _nm3(x: bytes, y: bytes, z: bytes) -> tuple[int, int, int]:
    """The three int40 fields the layout unpacked, as nm."""
    f = int.from_bytes
    return (f(x, "little", signed=True), f(y, "little", signed=True), f(z, "little", signed=True))


def _check_len(name: str, data: bytes | bytearray | memoryview, size: int) -> None:
    if len(data) != size:
        raise ValueError(f"{name} payload must be {size} bytes (CAN FD), got {len(data)}")


@dataclass(frozen=True, slots=True)
class RawReading:
    """One whole raw reading, controller → daemon, in one CAN FD frame (RAW_XYZ)."""

    kind: ClassVar[MessageKind] = MessageKind.RAW_XYZ
    seq: int
    """Reading sequence counter, uint16."""
    position_nm: tuple[int, int, int]
    """Indicated X, Y, Z, nm (int40 each)."""
    directions: tuple[Direction, Direction, Direction] = (
        Direction.UNKNOWN,
        Direction.UNKNOWN,
        Direction.UNKNOWN,
    )
    """Direction each axis last travelled."""
    valid: tuple[bool, bool, bool] = (True, True, True)
    """False where the controller knows a scale reading is bad."""

    def __post_init__(self) -> None:
        _u16(self.seq, "seq")
        for name, v in zip("XYZ", self.position_nm, strict=True):
            _int40(v, f"position_nm {name}")
        dirs = tuple(Direction(int(d)) for d in self.directions)
        if len(dirs) != 3 or len(self.valid) != 3:
            raise ValueError("directions and valid need one entry per axis (X, Y, Z)")
        object.__setattr__(self, "directions", dirs)
        object.__setattr__(self, "valid", tuple(bool(v) for v in self.valid))

    @property
    def position_mm(self) -> tuple[float, float, float]:
        """Indicated X, Y, Z, mm."""
        return mm3_from_nm(self.position_nm)

    def encode(self) -> bytes:
        """20-byte payload."""
        x, y, z = (_int40(v, "position_nm") for v in self.position_nm)
        d = self.directions
        dirs = int(d[0]) | int(d[1]) << 2 | int(d[2]) << 4
        valid = int(self.valid[0]) | int(self.valid[1]) << 1 | int(self.valid[2]) << 2
        return RAW_XYZ_LAYOUT.pack(x, y, z, self.seq, dirs, valid)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on a bad length or an undefined direction."""
        _check_len(cls.__name__, data, RAW_XYZ_SIZE)
        x, y, z, seq, dirs, valid = RAW_XYZ_LAYOUT.unpack(data)
        codes = (dirs & 3, dirs >> 2 & 3, dirs >> 4 & 3)
        for axis, code in zip("XYZ", codes, strict=True):
            if code == 3:
                raise ValueError(f"direction code 3 of {axis} is not defined; allowed: 0, 1, 2")
        return cls(
            seq,
            _nm3(x, y, z),
            (Direction(codes[0]), Direction(codes[1]), Direction(codes[2])),
            (bool(valid & 1), bool(valid & 2), bool(valid & 4)),
        )


@dataclass(frozen=True, slots=True)
class CorrectedReading:
    """One whole answer, daemon → controller, in one CAN FD frame (CORRECTED_XYZ)."""

    kind: ClassVar[MessageKind] = MessageKind.CORRECTED_XYZ
    seq: int
    position_nm: tuple[int, int, int]
    """Corrected X, Y, Z, nm (the indicated ones when the status says not corrected)."""
    status: Status = Status.OK
    applied: Applied = Applied.NONE
    latency_us: int = 0
    """µs from the reading's frame to the answer, saturating at 65535."""
    correction_10nm: int = 0
    """Length of the applied correction vector, 0.01 µm, saturating at 65535."""
    u_10nm: tuple[int, int, int] = (UNCERTAINTY_UNKNOWN,) * 3
    """Ux, Uy, Uz raw (0.01 µm, rounded up; 0xFFFF unknown, 0xFFFE more than 655.33 µm)."""

    def __post_init__(self) -> None:
        _u16(self.seq, "seq")
        for name, v in zip("XYZ", self.position_nm, strict=True):
            _int40(v, f"position_nm {name}")
        object.__setattr__(self, "status", Status(int(self.status)))
        if not 0 <= int(self.applied) <= APPLIED_MASK:
            raise ValueError(f"applied {int(self.applied)} out of range 0..{APPLIED_MASK}")
        object.__setattr__(self, "applied", Applied(int(self.applied)))
        _u16(self.latency_us, "latency_us")
        _u16(self.correction_10nm, "correction_10nm")
        for name, v in zip(("ux", "uy", "uz"), self.u_10nm, strict=True):
            _u16(v, f"{name}_10nm")

    @property
    def position_mm(self) -> tuple[float, float, float]:
        """Corrected X, Y, Z, mm."""
        return mm3_from_nm(self.position_nm)

    @property
    def correction_um(self) -> float:
        """Length of the applied correction, µm."""
        return um_from_correction_raw(self.correction_10nm)

    @property
    def u_um(self) -> tuple[float, float, float]:
        """(Ux, Uy, Uz), µm: NaN where unknown, ``inf`` where saturated."""
        u = self.u_10nm
        f = um_from_uncertainty_raw
        return (f(u[0]), f(u[1]), f(u[2]))

    @property
    def u_known(self) -> bool:
        """True when every component of U is a value (neither unknown nor saturated)."""
        return max(self.u_10nm) < UNCERTAINTY_SATURATED

    def encode(self) -> bytes:
        """32-byte payload."""
        x, y, z = (_int40(v, "position_nm") for v in self.position_nm)
        return CORRECTED_XYZ_LAYOUT.pack(
            x,
            y,
            z,
            self.seq,
            int(self.status),
            int(self.applied),
            self.latency_us,
            self.correction_10nm,
            *self.u_10nm,
        )

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on a bad length or an undefined status."""
        _check_len(cls.__name__, data, CORRECTED_XYZ_SIZE)
        x, y, z, seq, status, applied, latency, corr, ux, uy, uz = CORRECTED_XYZ_LAYOUT.unpack(data)
        try:
            st = Status(status)
        except ValueError:
            raise ValueError(f"status code {status} is not defined") from None
        return cls(
            seq,
            _nm3(x, y, z),
            st,
            Applied(applied & APPLIED_MASK),
            latency,
            corr,
            (ux, uy, uz),
        )


_FD_PACK = CORRECTED_XYZ_LAYOUT.pack


def encode_corrected_reading(
    seq: int,
    status: int,
    applied: int,
    position_nm: tuple[int, int, int],
    latency_us: float,
    correction_um: float,
    u_um: tuple[float, float, float] | None,
) -> bytes:
    """CORRECTED_XYZ payload from physical values, byte-equal to
    :meth:`CorrectedReading.encode` of the quantised frame (the daemon's reply path: no frame
    object; OverflowError/struct.error on an out-of-range value).

    :param latency_us: reply latency, µs (rounded, saturated at 65535).
    :param correction_um: length of the applied correction, µm (0.01 µm raw, saturated).
    :param u_um: expanded uncertainties (k = 2) of X, Y, Z, µm, or None when unknown (each
        rounded up to 0.01 µm: :func:`codes.uncertainty_raw_from_um`).
    """
    x, y, z = position_nm
    if u_um is None:
        ux = uy = uz = UNCERTAINTY_UNKNOWN
    else:
        raw = uncertainty_raw_from_um
        ux, uy, uz = raw(u_um[0]), raw(u_um[1]), raw(u_um[2])
    return _FD_PACK(
        x.to_bytes(5, "little", signed=True),
        y.to_bytes(5, "little", signed=True),
        z.to_bytes(5, "little", signed=True),
        seq,
        status,
        applied,
        latency_raw_from_us(latency_us),
        correction_raw_from_um(correction_um),
        ux,
        uy,
        uz,
    )
