"""CAN frames of the CMM compensation message set: classic 8-byte payloads, little-endian
(the CAN FD pair RAW_XYZ / CORRECTED_XYZ is in :mod:`.can_fd_frames`; :data:`FRAME_CLASS` and
:data:`PAYLOAD_SIZES` cover both).

Each frame is a frozen dataclass with ``encode() -> bytes`` and ``decode(data) -> Self``; the
layout is a named :class:`struct.Struct` with one comment per field. Fields hold raw integer
values (exact on the wire); properties give physical values (``position_mm``, ``temp_C``, …).
``cmm_comp.dbc`` describes the same layouts for node 0 (tests cross-check both with cantools).

``decode`` raises ValueError on a wrong length or a code outside its enum; reserved bits are
ignored on decode and sent as 0. For input from a bus use :func:`protocol.decode_message`,
which never raises.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import Any, ClassVar, Self, TypeVar

from .can_fd_frames import CORRECTED_XYZ_SIZE, RAW_XYZ_SIZE, CorrectedReading, RawReading
from .can_ids import CORRECTED_KIND, RAW_KIND, MessageKind
from .codes import (
    APPLIED_MASK,
    UNCERTAINTY_SATURATED,
    Applied,
    Axis,
    DaemonState,
    Direction,
    Status,
    celsius_from_mC,
    grid_id_from_sha256,
    mC_from_celsius,
    mm_from_nm,
    raw_from_unit_vector,
    um_from_correction_raw,
    um_from_uncertainty_raw,
    uncertainty_raw3_from_um,
    unit_vector_from_raw,
)

PAYLOAD_SIZE = 8
INT40_MIN = -(1 << 39)
INT40_MAX = (1 << 39) - 1
"""Position range: ±549.76 m at 1 nm resolution."""

AXIS_LAYOUT = struct.Struct(
    "<"
    "5s"  # bytes 0-4: position, int40 little-endian, raw unit 1 nm (mm = raw · 1e-6)
    "H"  # bytes 5-6: seq, uint16, reading sequence counter (wraps at 2**16)
    "B"  # byte 7: flags, see RAW_FLAGS / CORRECTED_FLAGS bit fields below
)
# raw axis flags byte: bits 0-1 axis (0 X, 1 Y, 2 Z), bits 2-3 Direction (0 unknown,
# 1 positive, 2 negative), bit 4 valid (1 = scale reading valid), bits 5-7 reserved (0).
# corrected axis flags byte: bits 0-1 axis, bits 2-7 Status code (0..63).

PROBE_DIRECTION_LAYOUT = struct.Struct(
    "<"
    "H"  # bytes 0-1: seq, uint16, the reading this probing direction belongs to
    "h"  # bytes 2-3: nx, int16, factor 2**-14 (unit vector component; 0,0,0 = none)
    "h"  # bytes 4-5: ny, int16, factor 2**-14
    "h"  # bytes 6-7: nz, int16, factor 2**-14
)

TEMPERATURE_LAYOUT = struct.Struct(
    "<"
    "B"  # byte 0: sensor id, uint8 (id → role mapping lives in the daemon's config)
    "B"  # byte 1: flags, bit 0 valid (1 = sensor reading valid), bits 1-7 reserved (0)
    "H"  # bytes 2-3: counter, uint16, incremented per new sample of this sensor (wraps)
    "i"  # bytes 4-7: temperature, int32, raw unit 0.001 °C (°C = raw · 0.001)
)

CORRECTION_STATUS_LAYOUT = struct.Struct(
    "<"
    "H"  # bytes 0-1: seq, uint16, the reading this answers
    "B"  # byte 2: status, uint8, Status code
    "B"  # byte 3: applied, uint8, Applied bit mask (bit 5 = U known; bits 6-7 reserved)
    "H"  # bytes 4-5: latency, uint16, µs from last input frame to answer (saturating)
    "H"  # bytes 6-7: |correction|, uint16, raw unit 0.01 µm (saturating at 655.35 µm)
)

CORRECTION_UNCERTAINTY_LAYOUT = struct.Struct(
    "<"
    "H"  # bytes 0-1: seq, uint16, the reading this answers
    "H"  # bytes 2-3: Ux, uint16, expanded uncertainty (k = 2) of X, 0.01 µm, rounded up;
    #      0xFFFF unknown, 0xFFFE more than 655.33 µm
    "H"  # bytes 4-5: Uy, uint16, likewise
    "H"  # bytes 6-7: Uz, uint16, likewise
)

HEARTBEAT_LAYOUT = struct.Struct(
    "<"
    "B"  # byte 0: state, uint8, DaemonState code
    "H"  # bytes 1-2: answered, uint16, readings answered (mod 2**16)
    "H"  # bytes 3-4: not_ok, uint16, answers with status != ok (mod 2**16)
    "3s"  # bytes 5-7: grid id, uint24 little-endian, first 24 bits of the grid SHA-256
)


def _check(name: str, value: int, lo: int, hi: int) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        raise ValueError(f"{name} {value!r} out of range {lo}..{hi}")


def _check_len(cls_name: str, data: bytes | bytearray | memoryview) -> None:
    if len(data) != PAYLOAD_SIZE:
        raise ValueError(f"{cls_name} payload must be {PAYLOAD_SIZE} bytes, got {len(data)}")


_E = TypeVar("_E", bound=enum.IntEnum)


def _enum(enum_cls: type[_E], name: str, code: int) -> _E:
    try:
        return enum_cls(code)
    except ValueError:
        allowed = ", ".join(f"{m.value} ({m.name.lower()})" for m in enum_cls)
        raise ValueError(f"{name} code {code} is not defined; allowed: {allowed}") from None


def _raw_flags_table() -> tuple[tuple[Axis, Direction, bool] | None, ...]:
    """Raw axis flags byte → (axis, direction, valid); None where a code is undefined."""
    out: list[tuple[Axis, Direction, bool] | None] = []
    for flags in range(256):
        try:
            out.append((Axis(flags & 0x3), Direction(flags >> 2 & 0x3), bool(flags >> 4 & 1)))
        except ValueError:
            out.append(None)
    return tuple(out)


_RAW_FLAGS = _raw_flags_table()


@dataclass(frozen=True, slots=True)
class RawAxis:
    """Raw scale reading of one axis, controller → daemon (RAW_X/Y/Z)."""

    axis: Axis
    seq: int
    """Reading sequence counter, uint16; X, Y and Z of one instant share it."""
    position_nm: int
    """Indicated position, nm, int40."""
    direction: Direction = Direction.UNKNOWN
    """Direction this axis last travelled."""
    valid: bool = True
    """False when the controller knows the scale reading is bad."""

    def __post_init__(self) -> None:
        _check("seq", self.seq, 0, 0xFFFF)
        _check("position_nm", self.position_nm, INT40_MIN, INT40_MAX)
        object.__setattr__(self, "axis", _enum(Axis, "axis", self.axis))
        object.__setattr__(self, "direction", _enum(Direction, "direction", self.direction))

    @property
    def kind(self) -> MessageKind:
        """Message kind (selects the CAN id)."""
        return RAW_KIND[self.axis]

    @property
    def position_mm(self) -> float:
        """Indicated position, mm."""
        return mm_from_nm(self.position_nm)

    def encode(self) -> bytes:
        """8-byte payload."""
        flags = int(self.axis) | int(self.direction) << 2 | int(self.valid) << 4
        pos = self.position_nm.to_bytes(5, "little", signed=True)
        return AXIS_LAYOUT.pack(pos, self.seq, flags)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on bad length or codes."""
        _check_len(cls.__name__, data)
        pos, seq, flags = AXIS_LAYOUT.unpack(data)
        fields = _RAW_FLAGS[flags]
        if fields is None:  # name the undefined code
            _enum(Direction, "direction", flags >> 2 & 0x3)
            _enum(Axis, "axis", flags & 0x3)
        assert fields is not None
        if cls is not RawAxis:  # a subclass gets its own __init__ checks
            return cls(fields[0], seq, int.from_bytes(pos, "little", signed=True), *fields[1:])
        # hot path (the daemon decodes three per reading): every field is in range by
        # construction (uint16 seq, 40-bit position, codes from the table), so the
        # validating __init__ is skipped and the slots are set directly
        obj = _new(cls)
        _RAW_SET[0](obj, fields[0])
        _RAW_SET[1](obj, seq)
        _RAW_SET[2](obj, int.from_bytes(pos, "little", signed=True))
        _RAW_SET[3](obj, fields[1])
        _RAW_SET[4](obj, fields[2])
        return obj


_new = object.__new__


def _slot_setters(cls: type, names: tuple[str, ...]) -> tuple[Any, ...]:
    """The slot descriptors' ``__set__`` of ``names`` (bypass a frozen dataclass' __init__)."""
    return tuple(cls.__dict__[n].__set__ for n in names)


_RAW_SET = _slot_setters(RawAxis, ("axis", "seq", "position_nm", "direction", "valid"))


@dataclass(frozen=True, slots=True)
class CorrectedAxis:
    """Corrected coordinate of one axis, daemon → controller (CORRECTED_X/Y/Z)."""

    axis: Axis
    seq: int
    """Seq of the reading this answers."""
    position_nm: int
    """Corrected position, nm, int40 (the indicated one when the status says not corrected)."""
    status: Status = Status.OK

    def __post_init__(self) -> None:
        _check("seq", self.seq, 0, 0xFFFF)
        _check("position_nm", self.position_nm, INT40_MIN, INT40_MAX)
        object.__setattr__(self, "axis", _enum(Axis, "axis", self.axis))
        object.__setattr__(self, "status", _enum(Status, "status", self.status))

    @property
    def kind(self) -> MessageKind:
        """Message kind (selects the CAN id)."""
        return CORRECTED_KIND[self.axis]

    @property
    def position_mm(self) -> float:
        """Corrected position, mm."""
        return mm_from_nm(self.position_nm)

    def encode(self) -> bytes:
        """8-byte payload."""
        flags = int(self.axis) | int(self.status) << 2
        pos = self.position_nm.to_bytes(5, "little", signed=True)
        return AXIS_LAYOUT.pack(pos, self.seq, flags)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on bad length or codes."""
        _check_len(cls.__name__, data)
        pos, seq, flags = AXIS_LAYOUT.unpack(data)
        status = _enum(Status, "status", flags >> 2)
        return cls(
            _enum(Axis, "axis", flags & 0x3),
            seq,
            int.from_bytes(pos, "little", signed=True),
            status,
        )


@dataclass(frozen=True, slots=True)
class ProbeDirection:
    """Probing direction of reading ``seq``: unit vector, raw int16 components × 2**-14."""

    kind: ClassVar[MessageKind] = MessageKind.PROBE_DIRECTION
    seq: int
    nx_raw: int
    ny_raw: int
    nz_raw: int

    def __post_init__(self) -> None:
        _check("seq", self.seq, 0, 0xFFFF)
        for name in ("nx_raw", "ny_raw", "nz_raw"):
            _check(name, getattr(self, name), -0x8000, 0x7FFF)

    @classmethod
    def from_unit_vector(cls, seq: int, n: tuple[float, float, float]) -> Self:
        """Quantise a unit vector (components in −1..1) to raw units of 2**-14."""
        return cls(seq, *raw_from_unit_vector(n))

    @property
    def present(self) -> bool:
        """False for (0, 0, 0), the code for "no probing direction"."""
        return bool(self.nx_raw or self.ny_raw or self.nz_raw)

    @property
    def unit_vector(self) -> tuple[float, float, float]:
        """(nx, ny, nz), dimensionless."""
        return unit_vector_from_raw((self.nx_raw, self.ny_raw, self.nz_raw))

    def encode(self) -> bytes:
        """8-byte payload."""
        return PROBE_DIRECTION_LAYOUT.pack(self.seq, self.nx_raw, self.ny_raw, self.nz_raw)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on bad length."""
        _check_len(cls.__name__, data)
        return cls(*PROBE_DIRECTION_LAYOUT.unpack(data))


@dataclass(frozen=True, slots=True)
class TemperatureSample:
    """One temperature sample, controller → daemon."""

    kind: ClassVar[MessageKind] = MessageKind.TEMPERATURE
    sensor: int
    """Sensor id, uint8; the daemon's config maps it to a role (T_x, T_wp, …)."""
    temp_mC: int
    """Temperature, 0.001 °C, int32."""
    counter: int = 0
    """Per-sensor sample counter, uint16 (wraps); a repeated counter means no new sample."""
    valid: bool = True

    def __post_init__(self) -> None:
        _check("sensor", self.sensor, 0, 0xFF)
        _check("temp_mC", self.temp_mC, -(1 << 31), (1 << 31) - 1)
        _check("counter", self.counter, 0, 0xFFFF)

    @classmethod
    def from_celsius(cls, sensor: int, temp_C: float, counter: int = 0, valid: bool = True) -> Self:
        """Quantise ``temp_C`` (°C) to 0.001 °C."""
        return cls(sensor, mC_from_celsius(temp_C), counter, valid)

    @property
    def temp_C(self) -> float:
        """Temperature, °C."""
        return celsius_from_mC(self.temp_mC)

    def encode(self) -> bytes:
        """8-byte payload."""
        return TEMPERATURE_LAYOUT.pack(self.sensor, int(self.valid), self.counter, self.temp_mC)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on bad length."""
        _check_len(cls.__name__, data)
        sensor, flags, counter, temp = TEMPERATURE_LAYOUT.unpack(data)
        return cls(sensor, temp, counter, bool(flags & 1))


@dataclass(frozen=True, slots=True)
class CorrectionStatus:
    """Per-reading outcome, daemon → controller, sent after the three corrected axis frames."""

    kind: ClassVar[MessageKind] = MessageKind.CORRECTION_STATUS
    seq: int
    status: Status
    applied: Applied = Applied.NONE
    latency_us: int = 0
    """µs from the last input frame of the reading to the answer, saturating at 65535."""
    correction_10nm: int = 0
    """Length of the applied correction vector, 0.01 µm, saturating at 65535."""

    def __post_init__(self) -> None:
        _check("seq", self.seq, 0, 0xFFFF)
        _check("latency_us", self.latency_us, 0, 0xFFFF)
        _check("correction_10nm", self.correction_10nm, 0, 0xFFFF)
        object.__setattr__(self, "status", _enum(Status, "status", self.status))
        _check("applied", int(self.applied), 0, APPLIED_MASK)
        object.__setattr__(self, "applied", Applied(int(self.applied)))

    @property
    def correction_um(self) -> float:
        """Length of the applied correction, µm."""
        return um_from_correction_raw(self.correction_10nm)

    def encode(self) -> bytes:
        """8-byte payload."""
        return CORRECTION_STATUS_LAYOUT.pack(
            self.seq, int(self.status), int(self.applied), self.latency_us, self.correction_10nm
        )

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on bad length or status code."""
        _check_len(cls.__name__, data)
        seq, status, applied, latency, corr = CORRECTION_STATUS_LAYOUT.unpack(data)
        st = _enum(Status, "status", status)
        return cls(seq, st, Applied(applied & APPLIED_MASK), latency, corr)


@dataclass(frozen=True, slots=True)
class CorrectionUncertainty:
    """Expanded uncertainty U (k = 2, per component) of a corrected reading, daemon →
    controller, sent after the three corrected axis frames and before the correction status
    (only with ``[can] send_uncertainty``; docs/can.md). Raw 0.01 µm, rounded up; the codes
    ``0xFFFF`` (unknown) and ``0xFFFE`` (more than 655.33 µm) are not values."""

    kind: ClassVar[MessageKind] = MessageKind.CORRECTION_UNCERTAINTY
    seq: int
    ux_10nm: int
    uy_10nm: int
    uz_10nm: int

    def __post_init__(self) -> None:
        _check("seq", self.seq, 0, 0xFFFF)
        for name in ("ux_10nm", "uy_10nm", "uz_10nm"):
            _check(name, getattr(self, name), 0, 0xFFFF)

    @classmethod
    def from_um(cls, seq: int, u_um: tuple[float, float, float] | None) -> Self:
        """Quantise (Ux, Uy, Uz) µm, rounding up (NaN: unknown; None: all unknown)."""
        return cls(seq, *uncertainty_raw3_from_um(u_um))

    @property
    def u_um(self) -> tuple[float, float, float]:
        """(Ux, Uy, Uz), µm: NaN where unknown, ``inf`` where saturated (never less than U)."""
        return (
            um_from_uncertainty_raw(self.ux_10nm),
            um_from_uncertainty_raw(self.uy_10nm),
            um_from_uncertainty_raw(self.uz_10nm),
        )

    @property
    def known(self) -> bool:
        """True when every component is a value (neither unknown nor saturated)."""
        return max(self.ux_10nm, self.uy_10nm, self.uz_10nm) < UNCERTAINTY_SATURATED

    def encode(self) -> bytes:
        """8-byte payload."""
        return CORRECTION_UNCERTAINTY_LAYOUT.pack(
            self.seq, self.ux_10nm, self.uy_10nm, self.uz_10nm
        )

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on a bad length."""
        _check_len(cls.__name__, data)
        return cls(*CORRECTION_UNCERTAINTY_LAYOUT.unpack(data))


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """Daemon heartbeat, sent periodically (docs/can.md: 10 Hz) and on state change."""

    kind: ClassVar[MessageKind] = MessageKind.HEARTBEAT
    state: DaemonState
    answered: int = 0
    """Readings answered, mod 2**16."""
    not_ok: int = 0
    """Answers whose status was not ok, mod 2**16."""
    grid_id: int = 0
    """First 24 bits of the loaded grid's SHA-256 (0 = no grid), see grid_id_from_sha256."""

    def __post_init__(self) -> None:
        _check("answered", self.answered, 0, 0xFFFF)
        _check("not_ok", self.not_ok, 0, 0xFFFF)
        _check("grid_id", self.grid_id, 0, 0xFFFFFF)
        object.__setattr__(self, "state", _enum(DaemonState, "state", self.state))

    @classmethod
    def with_grid_sha256(
        cls, state: DaemonState, answered: int, not_ok: int, sha256_hex: str
    ) -> Self:
        """Build from full counters (reduced mod 2**16) and the grid's SHA-256 hex digest."""
        return cls(state, answered & 0xFFFF, not_ok & 0xFFFF, grid_id_from_sha256(sha256_hex))

    def encode(self) -> bytes:
        """8-byte payload."""
        grid = self.grid_id.to_bytes(3, "little")
        return HEARTBEAT_LAYOUT.pack(int(self.state), self.answered, self.not_ok, grid)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Inverse of :meth:`encode`; ValueError on bad length or state code."""
        _check_len(cls.__name__, data)
        state, answered, not_ok, grid = HEARTBEAT_LAYOUT.unpack(data)
        st = _enum(DaemonState, "state", state)
        return cls(st, answered, not_ok, int.from_bytes(grid, "little"))


Frame = (
    RawAxis
    | CorrectedAxis
    | ProbeDirection
    | TemperatureSample
    | CorrectionStatus
    | CorrectionUncertainty
    | Heartbeat
    | RawReading
    | CorrectedReading
)
"""Any frame of the message set (classic and CAN FD)."""

FRAME_CLASS: dict[MessageKind, type[Frame]] = {
    MessageKind.RAW_X: RawAxis,
    MessageKind.RAW_Y: RawAxis,
    MessageKind.RAW_Z: RawAxis,
    MessageKind.PROBE_DIRECTION: ProbeDirection,
    MessageKind.TEMPERATURE: TemperatureSample,
    MessageKind.CORRECTED_X: CorrectedAxis,
    MessageKind.CORRECTED_Y: CorrectedAxis,
    MessageKind.CORRECTED_Z: CorrectedAxis,
    MessageKind.CORRECTION_STATUS: CorrectionStatus,
    MessageKind.CORRECTION_UNCERTAINTY: CorrectionUncertainty,
    MessageKind.HEARTBEAT: Heartbeat,
    MessageKind.RAW_XYZ: RawReading,
    MessageKind.CORRECTED_XYZ: CorrectedReading,
}
PAYLOAD_SIZES: dict[MessageKind, int] = {kind: PAYLOAD_SIZE for kind in FRAME_CLASS} | {
    MessageKind.RAW_XYZ: RAW_XYZ_SIZE,
    MessageKind.CORRECTED_XYZ: CORRECTED_XYZ_SIZE,
}
"""Data bytes of each message (8 for the classic frames; the CAN FD pair: 20 and 32)."""
