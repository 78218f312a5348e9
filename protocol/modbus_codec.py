"""Pack/unpack the Modbus register blocks of :mod:`protocol.modbus_map` (pure, no I/O).

Registers are Python ints 0..65535. Multi-register integers use big-endian word order (most
significant word at the lowest address), two's complement for signed types.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Self

from . import modbus_map as mm
from .codes import (
    APPLIED_MASK,
    UNCERTAINTY_SATURATED,
    UNCERTAINTY_UNKNOWN,
    Applied,
    DaemonState,
    Direction,
    Status,
    celsius_from_mC,
    correction_raw_from_um,
    latency_raw_from_us,
    mm3_from_nm,
    nm3_from_mm,
    raw_from_unit_vector,
    um_from_uncertainty_raw,
    uncertainty_raw3_from_um,
    unit_vector_from_raw,
)

Vec3i = tuple[int, int, int]


def int_to_registers(value: int, words: int, signed: bool = True) -> list[int]:
    """``value`` as ``words`` registers, most significant word first; ValueError if it won't fit."""
    try:
        raw = value.to_bytes(2 * words, "big", signed=signed)
    except OverflowError:
        kind = "int" if signed else "uint"
        raise ValueError(f"{value} does not fit {kind}{16 * words}") from None
    return [int.from_bytes(raw[i : i + 2], "big") for i in range(0, len(raw), 2)]


def int_from_registers(regs: Sequence[int], signed: bool = True) -> int:
    """Inverse of :func:`int_to_registers` (the word count is ``len(regs)``)."""
    raw = b"".join(_word(r).to_bytes(2, "big") for r in regs)
    return int.from_bytes(raw, "big", signed=signed)


def _word(value: int) -> int:
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"register value {value} out of range 0..65535")
    return value


def _check_len(name: str, regs: Sequence[int], size: int) -> None:
    if len(regs) != size:
        raise ValueError(f"{name} needs {size} registers, got {len(regs)}")


def _int64_triplet(regs: Sequence[int], first: int) -> Vec3i:
    """Three consecutive int64 values starting at index ``first``."""
    x, y, z = (int_from_registers(regs[i : i + 4]) for i in (first, first + 4, first + 8))
    return (x, y, z)


def _i16(reg: int) -> int:
    return int_from_registers([reg], signed=True)


def _u16(value: int, name: str) -> int:
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"{name} {value} out of range 0..65535")
    return value


@dataclass(frozen=True, slots=True)
class ReadingBlock:
    """READING block (100..119): one raw reading, written by the controller."""

    seq: int
    position_nm: Vec3i
    """Indicated X, Y, Z, nm (int64)."""
    directions: tuple[Direction, Direction, Direction] = (Direction.UNKNOWN,) * 3
    probe_raw: Vec3i = (0, 0, 0)
    """Probing direction, int16 × 2**-14; (0, 0, 0) = none."""
    valid: tuple[bool, bool, bool] = (True, True, True)

    @classmethod
    def from_mm(
        cls,
        seq: int,
        position_mm: tuple[float, float, float],
        directions: tuple[int, int, int] = (0, 0, 0),
        probe: tuple[float, float, float] | None = None,
        valid: tuple[bool, bool, bool] = (True, True, True),
    ) -> Self:
        """Build from mm, direction signs (+1/−1/0) and an optional probing unit vector."""
        pos = nm3_from_mm(position_mm)
        dirs = tuple(Direction.from_sign(s) for s in directions)
        probe_raw = (0, 0, 0) if probe is None else raw_from_unit_vector(probe)
        return cls(seq, pos, dirs, probe_raw, valid)  # type: ignore[arg-type]

    @property
    def position_mm(self) -> tuple[float, float, float]:
        """Indicated X, Y, Z, mm."""
        return mm3_from_nm(self.position_nm)

    @property
    def probe(self) -> tuple[float, float, float] | None:
        """Probing direction unit vector (dimensionless), or None for (0, 0, 0)."""
        raw = self.probe_raw
        return None if raw == (0, 0, 0) else unit_vector_from_raw(raw)

    def to_registers(self) -> list[int]:
        """20 registers for addresses 100..119 (SEQ last, so one write commits)."""
        regs: list[int] = []
        for p in self.position_nm:
            regs += int_to_registers(p, 4)
        regs += [int(Direction(d)) for d in self.directions]
        for c in self.probe_raw:
            regs += int_to_registers(c, 1)
        flags = sum(1 << i for i, v in enumerate(self.valid) if v)
        regs += [flags, _u16(self.seq, "seq")]
        return regs

    @classmethod
    def from_registers(cls, regs: Sequence[int]) -> Self:
        """Inverse of :meth:`to_registers`; ValueError on an undefined direction code."""
        _check_len("READING block", regs, mm.READING_SIZE)
        pos = _int64_triplet(regs, 0)
        dirs = tuple(Direction(_word(r)) for r in regs[12:15])
        probe = tuple(_i16(r) for r in regs[15:18])
        flags = _word(regs[18])
        valid = tuple(bool(flags >> i & 1) for i in range(3))
        return cls(_word(regs[19]), pos, dirs, probe, valid)  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class TemperatureSlot:
    """One TEMPERATURE slot (4 registers at :func:`temperature_address` (sensor))."""

    sensor: int
    temp_mC: int
    """Temperature, 0.001 °C (int32)."""
    valid: bool = True
    counter: int = 0

    @property
    def address(self) -> int:
        """First register of this slot."""
        return mm.temperature_address(self.sensor)

    @property
    def temp_C(self) -> float:
        """Temperature, °C."""
        return celsius_from_mC(self.temp_mC)

    def to_registers(self) -> list[int]:
        """4 registers: temperature (2, MSW first), flags, counter."""
        mm.temperature_address(self.sensor)  # validates the sensor id
        return [*int_to_registers(self.temp_mC, 2), int(self.valid), _u16(self.counter, "counter")]

    @classmethod
    def from_registers(cls, sensor: int, regs: Sequence[int]) -> Self:
        """Inverse of :meth:`to_registers`."""
        _check_len("temperature slot", regs, mm.TEMPERATURE_SLOT_SIZE)
        return cls(sensor, int_from_registers(regs[0:2]), bool(_word(regs[2]) & 1), _word(regs[3]))


_U_UNKNOWN3: Vec3i = (UNCERTAINTY_UNKNOWN, UNCERTAINTY_UNKNOWN, UNCERTAINTY_UNKNOWN)


@dataclass(frozen=True, slots=True)
class AnswerBlock:
    """The daemon's answer to the last committed reading: the ANSWER block (300..316) and the
    UNCERTAINTY registers (324..326, map version 2) that are stored with it."""

    seq: int
    status: Status
    position_nm: Vec3i
    """Corrected X, Y, Z, nm (int64); the indicated ones if the status says not corrected."""
    applied: Applied = Applied.NONE
    latency_us: int = 0
    correction_10nm: int = 0
    uncertainty_10nm: Vec3i = _U_UNKNOWN3
    """Raw (Ux, Uy, Uz): 0.01 µm rounded up, 0xFFFF unknown, 0xFFFE more than 655.33 µm."""

    @classmethod
    def from_physical(
        cls,
        seq: int,
        status: Status,
        position_nm: Vec3i,
        applied: Applied,
        latency_us: float,
        correction_um: float,
        uncertainty_um: tuple[float, float, float] | None = None,
    ) -> Self:
        """Build from the latency in µs and the correction length in µm (both rounded to
        their raw units and saturated at 65535) and U (k = 2) in µm, rounded **up** (None or
        NaN: unknown; :func:`codes.uncertainty_raw_from_um`)."""
        return cls(
            seq,
            status,
            position_nm,
            applied,
            latency_raw_from_us(latency_us),
            correction_raw_from_um(correction_um),
            uncertainty_raw3_from_um(uncertainty_um),
        )

    @property
    def uncertainty_um(self) -> tuple[float, float, float]:
        """(Ux, Uy, Uz), µm: NaN where unknown, ``inf`` where saturated (never less than U)."""
        x, y, z = self.uncertainty_10nm
        return (um_from_uncertainty_raw(x), um_from_uncertainty_raw(y), um_from_uncertainty_raw(z))

    @property
    def uncertainty_known(self) -> bool:
        """True when Ux, Uy and Uz are all values (neither unknown nor saturated)."""
        return max(self.uncertainty_10nm) < UNCERTAINTY_SATURATED

    @property
    def position_mm(self) -> tuple[float, float, float]:
        """Corrected X, Y, Z, mm."""
        return mm3_from_nm(self.position_nm)

    def to_registers(self) -> list[int]:
        """17 registers for addresses 300..316."""
        regs = [_u16(self.seq, "seq"), int(Status(self.status))]
        for p in self.position_nm:
            regs += int_to_registers(p, 4)
        regs += [
            int(self.applied) & APPLIED_MASK,
            _u16(self.latency_us, "latency_us"),
            _u16(self.correction_10nm, "correction_10nm"),
        ]
        return regs

    def uncertainty_registers(self) -> list[int]:
        """3 registers for addresses 324..326 (Ux, Uy, Uz raw)."""
        x, y, z = self.uncertainty_10nm
        return [_u16(x, "ux_10nm"), _u16(y, "uy_10nm"), _u16(z, "uz_10nm")]

    @classmethod
    def from_registers(cls, regs: Sequence[int], u_regs: Sequence[int] | None = None) -> Self:
        """Inverse of :meth:`to_registers` (and :meth:`uncertainty_registers`: ``u_regs``,
        None = not read, unknown); ValueError on an undefined status code."""
        _check_len("ANSWER block", regs, mm.ANSWER_SIZE)
        pos = _int64_triplet(regs, 2)
        applied = Applied(_word(regs[14]) & APPLIED_MASK)
        u = _U_UNKNOWN3
        if u_regs is not None:
            _check_len("UNCERTAINTY block", u_regs, mm.UNCERTAINTY_SIZE)
            u = (_word(u_regs[0]), _word(u_regs[1]), _word(u_regs[2]))
        return cls(
            _word(regs[0]),
            Status(_word(regs[1])),
            pos,
            applied,
            _word(regs[15]),
            _word(regs[16]),
            u,
        )


@dataclass(frozen=True, slots=True)
class DaemonBlock:
    """DAEMON block (317..323): daemon state and counters."""

    state: DaemonState
    answered: int = 0
    not_ok: int = 0
    grid_id: int = 0
    heartbeat: int = 0
    input_errors: int = 0

    def to_registers(self) -> list[int]:
        """7 registers for addresses 317..323."""
        return [
            int(DaemonState(self.state)),
            _u16(self.answered, "answered"),
            _u16(self.not_ok, "not_ok"),
            *int_to_registers(self.grid_id, 2, signed=False),
            _u16(self.heartbeat, "heartbeat"),
            _u16(self.input_errors, "input_errors"),
        ]

    @classmethod
    def from_registers(cls, regs: Sequence[int]) -> Self:
        """Inverse of :meth:`to_registers`; ValueError on an undefined state code."""
        _check_len("DAEMON block", regs, mm.DAEMON_SIZE)
        return cls(
            DaemonState(_word(regs[0])),
            _word(regs[1]),
            _word(regs[2]),
            int_from_registers(regs[3:5], signed=False),
            _word(regs[5]),
            _word(regs[6]),
        )


def decode_output(regs: Sequence[int]) -> tuple[AnswerBlock, DaemonBlock]:
    """Split a read of 300..326 (27 registers) into the answer (ANSWER + UNCERTAINTY) and the
    DAEMON block; a map-version-1 read of 300..323 (24 registers) gives U unknown."""
    if len(regs) != mm.OUTPUT_SIZE_V1:
        _check_len("ANSWER+DAEMON+UNCERTAINTY read", regs, mm.OUTPUT_SIZE)
    daemon_end = mm.ANSWER_SIZE + mm.DAEMON_SIZE
    u_regs = regs[daemon_end:] if len(regs) == mm.OUTPUT_SIZE else None
    return (
        AnswerBlock.from_registers(regs[: mm.ANSWER_SIZE], u_regs),
        DaemonBlock.from_registers(regs[mm.ANSWER_SIZE : daemon_end]),
    )


def info_registers() -> list[int]:
    """Contents of the INFO block (0..2)."""
    return [mm.MAP_VERSION, mm.MAGIC, mm.TEMPERATURE_SLOTS]
