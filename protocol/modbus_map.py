"""Modbus TCP holding-register map of the compensation daemon (server) — addresses + validation.

Addresses are 0-based PDU addresses (``4xxxx`` notation = address + 40001). Every register is
a 16-bit word sent big-endian (Modbus standard); multi-register values are sent **most
significant word first** (big-endian word order), so an int64 in registers r0..r3 is
``r0 << 48 | r1 << 32 | r2 << 16 | r3`` in two's complement. See docs/modbus.md.

| block | addresses | access | contents |
|---|---|---|---|
| INFO | 0..2 | read | map version, magic ``0x434D``, number of temperature slots |
| READING | 100..119 | read/write | raw X/Y/Z (int64 nm), directions, probing direction, valid flags, SEQ (commit) |
| TEMPERATURE | 200..263 | read/write | 16 slots × 4 registers: int32 m°C, flags, counter |
| ANSWER | 300..316 | read | seq answered, status, corrected X/Y/Z (int64 nm), applied, latency, |correction| |
| DAEMON | 317..323 | read | state, answered, not_ok, grid id (uint32), heartbeat, input errors |
| UNCERTAINTY | 324..326 | read | U of the answer (k = 2) in X, Y, Z: uint16 0.01 µm rounded up, 0xFFFF unknown |

Commit: a write request that includes ``SEQ`` (119) commits the reading block as it is after
that request; write 100..119 in one FC16 request, or the values first and ``SEQ`` last.
Reads may use FC3 or FC4 (same registers); writes FC6 or FC16; FC43/MEI 14 reads the device
identification (:mod:`protocol.modbus_devid`); any other function code is ILLEGAL_FUNCTION.
One read of 300..326 (27 registers) returns ANSWER, DAEMON and UNCERTAINTY together; the
UNCERTAINTY registers belong to the answer in ANSWER (they are replaced with it, in one step).
Map versions only add registers: a client written for version v works with any server ≥ v.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from .codes import Direction


class ExceptionCode(enum.IntEnum):
    """Standard Modbus exception codes this server produces (Modbus Application Protocol V1.1b3
    section 7; same values as pymodbus ExcCodes)."""

    ILLEGAL_FUNCTION = 1
    ILLEGAL_DATA_ADDRESS = 2
    ILLEGAL_DATA_VALUE = 3
    SERVER_DEVICE_FAILURE = 4


MAP_VERSION = 2
"""1: the original map; 2: UNCERTAINTY (324..326) and APPLIED bit 5 (U known) added."""
MAGIC = 0x434D
"""``"CM"``: lets a controller check it talks to a cmm-comp daemon."""
TEMPERATURE_SLOTS = 16
"""Sensor ids 0..15 have a slot; the id → role mapping is daemon configuration."""

FC_READ_HOLDING = 3
FC_READ_INPUT = 4
FC_WRITE_SINGLE = 6
FC_WRITE_MULTIPLE = 16
FC_READ_DEVICE_ID = 0x2B
"""Encapsulated Interface Transport (43); served only with MEI type 14."""
MEI_READ_DEVICE_ID = 0x0E
"""MEI type 14: Read Device Identification."""
READ_FUNCTIONS = frozenset({FC_READ_HOLDING, FC_READ_INPUT})
WRITE_FUNCTIONS = frozenset({FC_WRITE_SINGLE, FC_WRITE_MULTIPLE})
MAX_READ_COUNT = 125
"""Modbus limit for FC3/FC4 quantity."""
MAX_WRITE_COUNT = 123
"""Modbus limit for FC16 quantity."""

# --- INFO (read-only) -------------------------------------------------------------------
INFO_START = 0
REG_MAP_VERSION = 0  # uint16, MAP_VERSION
REG_MAGIC = 1  # uint16, MAGIC
REG_TEMPERATURE_SLOTS = 2  # uint16, TEMPERATURE_SLOTS
INFO_SIZE = 3

# --- READING (read/write, controller writes) --------------------------------------------
READING_START = 100
REG_X_NM = 100  # 100-103: raw X, int64, 1 nm (mm = raw · 1e-6)
REG_Y_NM = 104  # 104-107: raw Y, int64, 1 nm
REG_Z_NM = 108  # 108-111: raw Z, int64, 1 nm
REG_DIR_X = 112  # Direction code of X: 0 unknown, 1 positive, 2 negative
REG_DIR_Y = 113  # Direction code of Y
REG_DIR_Z = 114  # Direction code of Z
REG_PROBE_NX = 115  # probing direction nx, int16, factor 2**-14 (0,0,0 = none)
REG_PROBE_NY = 116  # ny, int16, factor 2**-14
REG_PROBE_NZ = 117  # nz, int16, factor 2**-14
REG_READING_FLAGS = 118  # bit 0/1/2: X/Y/Z scale reading valid; bits 3-15 reserved (0)
REG_SEQ = 119  # uint16 reading seq; a write including this register commits the reading
READING_SIZE = 20
READING_FLAGS_MASK = 0x7

# --- TEMPERATURE (read/write, controller writes) ----------------------------------------
TEMPERATURE_START = 200
TEMPERATURE_SLOT_SIZE = 4
# slot i at 200 + 4·i: +0,+1 temperature int32 0.001 °C; +2 flags (bit 0 valid, others 0);
# +3 counter uint16, incremented by the controller per new sample (staleness detection)
TEMPERATURE_SIZE = TEMPERATURE_SLOTS * TEMPERATURE_SLOT_SIZE
TEMPERATURE_FLAGS_MASK = 0x1

# --- ANSWER (read-only, daemon writes) --------------------------------------------------
ANSWER_START = 300
REG_ANSWER_SEQ = 300  # uint16, seq of the reading this answer belongs to
REG_STATUS = 301  # uint16, Status code
REG_CX_NM = 302  # 302-305: corrected X, int64, 1 nm
REG_CY_NM = 306  # 306-309: corrected Y, int64, 1 nm
REG_CZ_NM = 310  # 310-313: corrected Z, int64, 1 nm
REG_APPLIED = 314  # uint16, Applied bit mask
REG_LATENCY_US = 315  # uint16, µs from commit to answer, saturating
REG_CORRECTION_10NM = 316  # uint16, |correction| in 0.01 µm, saturating
ANSWER_SIZE = 17

# --- DAEMON (read-only, daemon writes) --------------------------------------------------
DAEMON_START = 317
REG_STATE = 317  # uint16, DaemonState code
REG_ANSWERED = 318  # uint16, answers produced, mod 2**16 (changes with every answer)
REG_NOT_OK = 319  # uint16, answers with status != ok, mod 2**16
REG_GRID_ID = 320  # 320-321: uint32 (24 bits used), first 24 bits of the grid SHA-256
REG_HEARTBEAT = 322  # uint16, incremented by the daemon at 10 Hz: a frozen value = dead daemon
REG_INPUT_ERRORS = 323  # uint16, rejected writes and unusable commits, mod 2**16
DAEMON_SIZE = 7

# --- UNCERTAINTY (read-only, daemon writes with ANSWER; map version 2) -------------------
UNCERTAINTY_START = 324
REG_UX_10NM = 324  # uint16, expanded uncertainty (k = 2) of the answer's X, 0.01 µm, rounded
#                    up; 0xFFFF unknown (status not ok, or no U in the grid), 0xFFFE > 655.33 µm
REG_UY_10NM = 325  # uint16, likewise for Y
REG_UZ_10NM = 326  # uint16, likewise for Z
UNCERTAINTY_SIZE = 3

OUTPUT_START = ANSWER_START
OUTPUT_SIZE = ANSWER_SIZE + DAEMON_SIZE + UNCERTAINTY_SIZE
"""ANSWER, DAEMON and UNCERTAINTY are contiguous: read 300..326 in one request."""
OUTPUT_SIZE_V1 = ANSWER_SIZE + DAEMON_SIZE
"""The map-version-1 output read, 300..323 (still served: U is then not read)."""


@dataclass(frozen=True, slots=True)
class RegisterBlock:
    """A contiguous range of defined registers."""

    name: str
    start: int
    size: int
    writable: bool

    @property
    def stop(self) -> int:
        """One past the last address."""
        return self.start + self.size

    def contains(self, address: int, count: int = 1) -> bool:
        """True if ``address .. address+count-1`` lies inside the block."""
        return self.start <= address and address + count <= self.stop


BLOCKS: tuple[RegisterBlock, ...] = (
    RegisterBlock("INFO", INFO_START, INFO_SIZE, writable=False),
    RegisterBlock("READING", READING_START, READING_SIZE, writable=True),
    RegisterBlock("TEMPERATURE", TEMPERATURE_START, TEMPERATURE_SIZE, writable=True),
    RegisterBlock("ANSWER", ANSWER_START, ANSWER_SIZE, writable=False),
    RegisterBlock("DAEMON", DAEMON_START, DAEMON_SIZE, writable=False),
    RegisterBlock("UNCERTAINTY", UNCERTAINTY_START, UNCERTAINTY_SIZE, writable=False),
)


def _spans(address: int, count: int, writable: bool) -> bool:
    """True if every register of the range is defined (and writable, if asked)."""
    end = address + count
    pos = address
    for block in BLOCKS:  # sorted; ANSWER, DAEMON, UNCERTAINTY adjacent, the others not
        if block.start <= pos < block.stop:
            if writable and not block.writable:
                return False
            pos = block.stop
            if pos >= end:
                return True
    return False


def check_request(function_code: int, address: int, count: int) -> ExceptionCode | None:
    """Validate a request's function code, quantity and address range; None if acceptable.

    ILLEGAL_FUNCTION for codes other than 3, 4, 6, 16; ILLEGAL_DATA_VALUE for a quantity
    outside 1..125 (reads), 1..123 (FC16), ≠ 1 (FC6); ILLEGAL_DATA_ADDRESS when any register
    of the range is undefined, or for a write touching a read-only register.
    """
    if function_code in READ_FUNCTIONS:
        max_count = MAX_READ_COUNT
    elif function_code == FC_WRITE_MULTIPLE:
        max_count = MAX_WRITE_COUNT
    elif function_code == FC_WRITE_SINGLE:
        max_count = 1
    else:
        return ExceptionCode.ILLEGAL_FUNCTION
    if not 1 <= count <= max_count:
        return ExceptionCode.ILLEGAL_DATA_VALUE
    if not 0 <= address <= 0xFFFF or not _spans(address, count, function_code in WRITE_FUNCTIONS):
        return ExceptionCode.ILLEGAL_DATA_ADDRESS
    return None


def _check_value(address: int, value: int) -> bool:
    if not 0 <= value <= 0xFFFF:
        return False
    if address in (REG_DIR_X, REG_DIR_Y, REG_DIR_Z):
        return value in {int(d) for d in Direction}
    if address == REG_READING_FLAGS:
        return not value & ~READING_FLAGS_MASK
    in_temps = TEMPERATURE_START <= address < TEMPERATURE_START + TEMPERATURE_SIZE
    if in_temps and (address - TEMPERATURE_START) % TEMPERATURE_SLOT_SIZE == 2:
        return not value & ~TEMPERATURE_FLAGS_MASK
    return True


def check_write(function_code: int, address: int, values: list[int]) -> ExceptionCode | None:
    """Validate a write request including its values; None if it may be applied.

    Besides :func:`check_request`: ILLEGAL_DATA_VALUE for a value outside 0..65535, a
    direction code other than 0/1/2, or reserved flag bits set. Positions, seq and
    temperatures accept any bit pattern.
    """
    if function_code not in WRITE_FUNCTIONS:
        return ExceptionCode.ILLEGAL_FUNCTION
    if code := check_request(function_code, address, len(values)):
        return code
    for i, value in enumerate(values):
        if not _check_value(address + i, value):
            return ExceptionCode.ILLEGAL_DATA_VALUE
    return None


def commits_reading(function_code: int, address: int, count: int) -> bool:
    """True if this (already validated) request writes REG_SEQ, i.e. commits a reading."""
    return function_code in WRITE_FUNCTIONS and address <= REG_SEQ < address + count


def temperature_address(sensor: int) -> int:
    """First register of ``sensor``'s temperature slot."""
    if not 0 <= sensor < TEMPERATURE_SLOTS:
        raise ValueError(f"sensor {sensor} has no Modbus slot; allowed 0..{TEMPERATURE_SLOTS - 1}")
    return TEMPERATURE_START + TEMPERATURE_SLOT_SIZE * sensor


def describe_exception(code: int) -> str:
    """Name of an exception code, e.g. ``"ILLEGAL_DATA_ADDRESS (2)"``."""
    try:
        return f"{ExceptionCode(code).name} ({code})"
    except ValueError:
        return f"exception code {code}"
