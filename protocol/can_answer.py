"""The daemon's answer frames packed straight from physical values: its reply path.

No frame objects and no validation beyond the packing's own (``OverflowError`` /
``struct.error`` on an out-of-range value): each function gives exactly the bytes of the frame
class's ``encode()`` (:mod:`.can_frames`) for the same values quantised by :mod:`.codes`, which
``tests/test_daemon_can_reply.py`` and ``tests/test_protocol_uncertainty.py`` check against
cantools on the DBC.
"""

from __future__ import annotations

from .can_frames import AXIS_LAYOUT, CORRECTION_STATUS_LAYOUT, CORRECTION_UNCERTAINTY_LAYOUT
from .codes import (
    UNCERTAINTY_UNKNOWN,
    correction_raw_from_um,
    latency_raw_from_us,
    uncertainty_raw_from_um,
)

__all__ = ["encode_corrected_axes", "encode_correction_status", "encode_correction_uncertainty"]

_AXIS_PACK = AXIS_LAYOUT.pack
_STATUS_PACK = CORRECTION_STATUS_LAYOUT.pack
_U_PACK = CORRECTION_UNCERTAINTY_LAYOUT.pack


def encode_corrected_axes(
    seq: int, status: int, position_nm: tuple[int, int, int]
) -> tuple[bytes, bytes, bytes]:
    """Payloads of CORRECTED_X/Y/Z for one answer, byte-equal to :meth:`CorrectedAxis.encode`
    of each axis (the daemon's reply path: no frame objects, no validation beyond the
    packing's own: OverflowError/struct.error on an out-of-range position or seq).

    :param seq: reading sequence counter, uint16.
    :param status: :class:`Status` code (0..63).
    :param position_nm: corrected X, Y, Z, nm (int40 each).
    """
    x, y, z = position_nm
    flags = status << 2  # axis code in bits 0-1
    return (
        _AXIS_PACK(x.to_bytes(5, "little", signed=True), seq, flags),
        _AXIS_PACK(y.to_bytes(5, "little", signed=True), seq, flags | 1),
        _AXIS_PACK(z.to_bytes(5, "little", signed=True), seq, flags | 2),
    )


def encode_correction_status(
    seq: int, status: int, applied: int, latency_us: float, correction_um: float
) -> bytes:
    """Payload of CORRECTION_STATUS from physical values, byte-equal to
    :meth:`CorrectionStatus.encode` of the quantised frame (the daemon's reply path).

    :param seq: reading sequence counter, uint16.
    :param status: :class:`Status` code.
    :param applied: :class:`Applied` bit mask.
    :param latency_us: reply latency, µs (rounded, saturated at 65535).
    :param correction_um: length of the applied correction, µm (0.01 µm raw, saturated).
    """
    return _STATUS_PACK(
        seq,
        status,
        applied,
        latency_raw_from_us(latency_us),
        correction_raw_from_um(correction_um),
    )


def encode_correction_uncertainty(seq: int, u_um: tuple[float, float, float] | None) -> bytes:
    """Payload of CORRECTION_UNCERTAINTY from (Ux, Uy, Uz) µm (None or NaN: unknown), byte-equal
    to :meth:`CorrectionUncertainty.encode` of :meth:`CorrectionUncertainty.from_um` (the
    daemon's reply path). Each U is rounded up to 0.01 µm (:func:`codes.uncertainty_raw_from_um`).

    :param seq: reading sequence counter, uint16.
    :param u_um: expanded uncertainties (k = 2) of X, Y, Z, µm, or None when unknown.
    """
    if u_um is None:
        return _U_PACK(seq, UNCERTAINTY_UNKNOWN, UNCERTAINTY_UNKNOWN, UNCERTAINTY_UNKNOWN)
    raw = uncertainty_raw_from_um
    return _U_PACK(seq, raw(u_um[0]), raw(u_um[1]), raw(u_um[2]))
