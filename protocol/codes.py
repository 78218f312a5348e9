"""Codes and scalings shared by the CAN message set and the Modbus register map.

Every enum here has stable integer codes: they are on the wire, never renumber them; add new
members at unused codes only. String labels (``Status.label``) are the status strings of
``docs/formats.md`` (``"ok"``, ``"outside_volume"``, …), used in CSV output and the MCAP log.

Raw ↔ physical scalings (physical = raw · factor + offset, offset always 0 here):

| quantity | raw type | factor | unit |
|---|---|---|---|
| position | int40 (CAN) / int64 (Modbus) | 1e-6 | mm (raw unit: nm) |
| temperature | int32 | 0.001 | °C (raw unit: m°C) |
| probing direction component | int16 | 2**-14 | 1 (unit vector component) |
| correction magnitude | uint16 | 0.01 | µm (raw unit: 10 nm), saturating |
| expanded uncertainty U (k = 2, per component) | uint16 | 0.01 | µm, rounded **up**; 0xFFFF unknown, 0xFFFE more than 655.33 µm |
| latency | uint16 | 1 | µs, saturating |

Each factor is defined here once, and every raw ↔ physical conversion of the project goes
through the helpers below (or the frame/block properties built on them): the daemon's
endpoints, its log records and the simulated controller never scale by hand.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence

NM_PER_MM = 1_000_000
"""Raw position unit: 1 nm; physical mm = raw · 1e-6."""
MC_PER_C = 1000
"""Raw temperature units (m°C) per °C."""
TEMP_C_PER_LSB = 1 / MC_PER_C
"""Raw temperature unit: 0.001 °C (m°C)."""
DIRECTION_LSB = 2.0**-14
"""Raw probing direction unit: 2**-14 (exact in binary and decimal, so DBC factors are exact)."""
CORRECTION_LSB_PER_UM = 100
"""Raw correction-magnitude units (10 nm) per µm."""
CORRECTION_UM_PER_LSB = 1 / CORRECTION_LSB_PER_UM
"""Raw correction-magnitude unit: 0.01 µm = 10 nm."""
UINT16_MAX = 0xFFFF
UNCERTAINTY_LSB_PER_UM = CORRECTION_LSB_PER_UM
"""Raw uncertainty units (10 nm) per µm: the same 0.01 µm as the correction magnitude."""
UNCERTAINTY_UNKNOWN = 0xFFFF
"""Raw uncertainty code: U unknown (status not ok, or the grid carries no U)."""
UNCERTAINTY_SATURATED = 0xFFFE
"""Raw uncertainty code: U larger than the field holds (more than 655.33 µm): "at least"."""
UNCERTAINTY_RAW_MAX = UNCERTAINTY_SATURATED - 1
"""Largest raw uncertainty that is a value (655.33 µm)."""
_U_TOP_UM = UNCERTAINTY_RAW_MAX / UNCERTAINTY_LSB_PER_UM
SEQ_MODULUS = 1 << 16
"""Sequence counters and event counters wrap modulo 2**16."""


class Axis(enum.IntEnum):
    """Machine axis; code is the 2-bit axis field of axis frames."""

    X = 0
    Y = 1
    Z = 2


class Direction(enum.IntEnum):
    """Direction an axis last travelled before the reading (2-bit code on the wire)."""

    UNKNOWN = 0
    POSITIVE = 1
    NEGATIVE = 2

    @property
    def sign(self) -> int:
        """+1, −1, or 0 for unknown (the ``dir_x`` convention of docs/formats.md)."""
        return {0: 0, 1: 1, 2: -1}[int(self)]

    @classmethod
    def from_sign(cls, sign: int) -> Direction:
        """Map +1 → POSITIVE, −1 → NEGATIVE, 0 → UNKNOWN; anything else raises ValueError."""
        try:
            return {0: cls.UNKNOWN, 1: cls.POSITIVE, -1: cls.NEGATIVE}[sign]
        except KeyError:
            raise ValueError(f"direction sign {sign!r} is not one of +1, -1, 0") from None


class Status(enum.IntEnum):
    """Outcome of correcting one reading. Code fits in 6 bits (0..63).

    ``label`` is the docs/formats.md status string. ``OK`` means fully corrected; every other status
    says why the output is not (fully) corrected: then the daemon's output positions carry the
    indicated (raw) position unchanged, except ``NOT_THERMALLY_CORRECTED`` and
    ``MISSING_DIRECTION`` where the geometric correction was applied but a term was left out.
    """

    OK = 0
    OUTSIDE_VOLUME = 1
    NO_TEMPERATURE = 2
    STALE_TEMPERATURE = 3
    IMPLAUSIBLE_TEMPERATURE = 4
    NO_GRID = 5
    INCOMPLETE_READING = 6
    CORRECTION_LIMIT = 7
    NOT_THERMALLY_CORRECTED = 8
    MISSING_DIRECTION = 9
    INVALID_READING = 10
    """The controller flagged a scale reading as invalid (valid bit clear)."""
    STALE_READING = 11
    """The reading was too old when the daemon got to it (overload, queueing)."""
    OVERLOAD = 12
    """Reading dropped or answered late because the daemon is saturated."""
    NOT_READY = 13
    """The daemon is starting or stopping."""
    INTERNAL_ERROR = 63

    @property
    def label(self) -> str:
        """docs/formats.md status string, e.g. ``"outside_volume"``."""
        return self.name.lower()

    @property
    def geometric_correction_applied(self) -> bool:
        """True when the output positions include the geometric (grid) correction."""
        return self in _GEOMETRY_APPLIED

    @classmethod
    def from_label(cls, label: str) -> Status:
        """Inverse of ``label``; raises ValueError naming the label and the allowed ones."""
        try:
            return cls[label.upper()]
        except KeyError:
            allowed = ", ".join(s.label for s in cls)
            raise ValueError(f"unknown status {label!r}; allowed: {allowed}") from None


_GEOMETRY_APPLIED = frozenset({Status.OK, Status.NOT_THERMALLY_CORRECTED, Status.MISSING_DIRECTION})


class DaemonState(enum.IntEnum):
    """State of the compensation daemon (heartbeat frame, Modbus daemon block)."""

    STARTING = 0
    READY = 1
    DEGRADED = 2
    """Running, but some answers are not ``ok`` (e.g. temperatures stale)."""
    NO_GRID = 3
    FAULT = 4
    STOPPING = 5

    @property
    def label(self) -> str:
        """Lower-case name, used as ``state`` in the MCAP ``/cmm/status`` topic."""
        return self.name.lower()


class Applied(enum.IntFlag):
    """Which correction terms went into an answer (bit mask, 8 bits on the wire)."""

    NONE = 0
    GEOMETRY = 0x01
    SCALE_THERMAL = 0x02
    WORKPIECE_THERMAL = 0x04
    REVERSAL = 0x08
    """Direction-dependent (reversal) term, needs travel directions."""
    PROBE_DIRECTION = 0x10
    """Probing-direction-dependent term (lobing), needs the probing direction."""
    UNCERTAINTY = 0x20
    """Not a correction term: the answer's expanded uncertainty U is known (the status is
    ``ok`` and the grid carries U; docs/uncertainty.md)."""


APPLIED_MASK = 0x3F


def grid_id_from_sha256(sha256_hex: str) -> int:
    """Short grid id: the first 24 bits (6 hex digits) of the grid file's SHA-256.

    >>> hex(grid_id_from_sha256("a1b2c3" + "0" * 58))
    '0xa1b2c3'
    """
    if len(sha256_hex) != 64:
        raise ValueError(f"sha256 hex digest must have 64 characters, got {len(sha256_hex)}")
    return int(sha256_hex[:6], 16)


def saturate_u16(value: int) -> int:
    """Clamp a non-negative count to 0..65535 (saturating fields: latency, correction)."""
    return max(0, min(UINT16_MAX, int(value)))


def seq_distance(newer: int, older: int) -> int:
    """Forward distance ``newer − older`` modulo 2**16 (0..65535)."""
    return (newer - older) % SEQ_MODULUS


# --------------------------------------------------------------------------- raw <-> physical


def mm_from_nm(position_nm: int) -> float:
    """Position, mm, of a raw position in nm."""
    return position_nm / NM_PER_MM


def mm3_from_nm(position_nm: Sequence[int]) -> tuple[float, float, float]:
    """X, Y, Z, mm, of raw X, Y, Z in nm."""
    x, y, z = position_nm
    return (x / NM_PER_MM, y / NM_PER_MM, z / NM_PER_MM)


def nm3_from_mm(position_mm: Sequence[float]) -> tuple[int, int, int]:
    """Raw X, Y, Z, nm (rounded to the nearest nm), of X, Y, Z in mm."""
    x, y, z = position_mm
    return (round(x * NM_PER_MM), round(y * NM_PER_MM), round(z * NM_PER_MM))


def celsius_from_mC(temp_mC: int) -> float:
    """Temperature, °C, of a raw temperature in 0.001 °C."""
    return temp_mC / MC_PER_C


def mC_from_celsius(temp_C: float) -> int:
    """Raw temperature, 0.001 °C (rounded), of a temperature in °C."""
    return round(temp_C / TEMP_C_PER_LSB)


def unit_vector_from_raw(raw: Sequence[int]) -> tuple[float, float, float]:
    """Probing unit vector (dimensionless) of raw int16 components × 2**-14."""
    x, y, z = raw
    return (x * DIRECTION_LSB, y * DIRECTION_LSB, z * DIRECTION_LSB)


def raw_from_unit_vector(unit_vector: Sequence[float]) -> tuple[int, int, int]:
    """Raw int16 components (units of 2**-14, rounded) of a probing unit vector."""
    x, y, z = unit_vector
    return (round(x / DIRECTION_LSB), round(y / DIRECTION_LSB), round(z / DIRECTION_LSB))


def um_from_correction_raw(correction_10nm: int) -> float:
    """Correction magnitude, µm, of its raw value in 0.01 µm."""
    return correction_10nm / CORRECTION_LSB_PER_UM


def correction_raw_from_um(correction_um: float) -> int:
    """Raw correction magnitude, 0.01 µm, rounded and saturated to 0..65535."""
    return saturate_u16(round(correction_um * CORRECTION_LSB_PER_UM))


def uncertainty_raw_from_um(u_um: float) -> int:
    """Raw expanded uncertainty, 0.01 µm, of U (µm): rounded **up**, so the wire never states
    less than U: the smallest raw with ``raw · 0.01 ≥ U`` and ``raw / 100 ≥ U`` in floating
    point (the two ways a reader scales it). NaN or a negative U (no valid value) gives :data:`UNCERTAINTY_UNKNOWN`;
    a U above 655.33 µm (``inf`` included) :data:`UNCERTAINTY_SATURATED`.

    >>> uncertainty_raw_from_um(1.234), uncertainty_raw_from_um(0.0), uncertainty_raw_from_um(1e-9)
    (124, 0, 1)
    """
    if not u_um >= 0.0:  # NaN or negative: no value to state
        return UNCERTAINTY_UNKNOWN
    if u_um > _U_TOP_UM:
        return UNCERTAINTY_SATURATED
    raw = math.ceil(u_um * 100)  # 100 = UNCERTAINTY_LSB_PER_UM (the reply path: no lookups)
    # the product is within an ulp of U·100: the smallest raw whose value read back (raw / 100
    # or raw · 0.01) is not below U is raw − 1, raw or raw + 1
    if raw and (raw - 1) / 100 >= u_um and (raw - 1) * 0.01 >= u_um:
        raw -= 1
    elif raw / 100 < u_um or raw * 0.01 < u_um:
        raw += 1
    return raw if raw <= UNCERTAINTY_RAW_MAX else UNCERTAINTY_SATURATED


def um_from_uncertainty_raw(u_raw: int) -> float:
    """U (µm) of a raw uncertainty: NaN for :data:`UNCERTAINTY_UNKNOWN`, ``inf`` for
    :data:`UNCERTAINTY_SATURATED` (an upper bound is not known), else ``raw / 100``."""
    if u_raw == UNCERTAINTY_UNKNOWN:
        return math.nan
    if u_raw == UNCERTAINTY_SATURATED:
        return math.inf
    return u_raw / UNCERTAINTY_LSB_PER_UM


def uncertainty_raw3_from_um(
    u_um: Sequence[float] | None,
) -> tuple[int, int, int]:
    """Raw (Ux, Uy, Uz) of :func:`uncertainty_raw_from_um` each; None: all unknown."""
    if u_um is None:
        return (UNCERTAINTY_UNKNOWN, UNCERTAINTY_UNKNOWN, UNCERTAINTY_UNKNOWN)
    x, y, z = u_um
    return (uncertainty_raw_from_um(x), uncertainty_raw_from_um(y), uncertainty_raw_from_um(z))


def latency_raw_from_us(latency_us: float) -> int:
    """Raw latency, µs, rounded and saturated to 0..65535."""
    return saturate_u16(round(latency_us))
