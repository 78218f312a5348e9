"""``can.Message`` ↔ frame: :func:`decode_message` never raises, it returns a typed result."""

from __future__ import annotations

from dataclasses import dataclass

import can

from .can_frames import FRAME_CLASS, PAYLOAD_SIZE, PAYLOAD_SIZES, Frame, RawAxis
from .can_ids import CanIds, MessageKind
from .codes import Axis


@dataclass(frozen=True, slots=True)
class UnknownId:
    """The message is not one of this node's ids (or not a standard-id frame)."""

    can_id: int
    is_extended_id: bool

    @property
    def reason(self) -> str:
        """Human-readable explanation."""
        kind = "extended" if self.is_extended_id else "standard"
        return f"{kind} id {self.can_id:#x} is not in this node's message set"


@dataclass(frozen=True, slots=True)
class NotData:
    """A remote (RTR) or error frame on one of our ids: carries no payload to decode."""

    can_id: int
    kind: MessageKind | None
    reason: str


@dataclass(frozen=True, slots=True)
class BadLength:
    """Known id, wrong payload length."""

    can_id: int
    kind: MessageKind
    expected: int
    got: int

    @property
    def reason(self) -> str:
        """Human-readable explanation."""
        return f"{self.kind.name} needs {self.expected} data bytes, got {self.got}"


@dataclass(frozen=True, slots=True)
class BadValue:
    """Known id and length, but the payload holds an undefined code or mismatches its id."""

    can_id: int
    kind: MessageKind
    reason: str


Undecodable = UnknownId | NotData | BadLength | BadValue
DecodeResult = Frame | Undecodable


def decode_message(msg: can.Message, ids: CanIds) -> DecodeResult:
    """Decode a received message for node ``ids``; never raises on any message content.

    Returns the frame, or :class:`UnknownId` (not ours), :class:`NotData` (remote/error frame),
    :class:`BadLength` (not the message's data length: 8, RAW_XYZ 20, CORRECTED_XYZ 32) or :class:`BadValue` (undefined code, axis field ≠ id).
    """
    can_id = -1
    kind: MessageKind | None = None
    try:
        can_id = int(msg.arbitration_id)
        if msg.is_error_frame:  # its id field carries error classes, not a message id
            return NotData(can_id, None, "error frame")
        if msg.is_extended_id:
            return UnknownId(can_id, True)
        kind = ids.kind_of(can_id)
        if kind is None:
            return UnknownId(can_id, False)
        if msg.is_remote_frame:
            return NotData(can_id, kind, f"remote frame on {kind.name}")
        data = bytes(msg.data or b"")
        size = PAYLOAD_SIZES[kind]
        if len(data) != size:
            return BadLength(can_id, kind, size, len(data))
        frame = FRAME_CLASS[kind].decode(data)
        if kind.axis is not None and frame.axis != kind.axis:  # type: ignore[union-attr]
            axis = frame.axis.name  # type: ignore[union-attr]
            return BadValue(can_id, kind, f"axis field says {axis}, id says {kind.name}")
        return frame
    except (ValueError, TypeError, AttributeError, OverflowError) as exc:
        if kind is None:  # the message object itself is malformed
            return UnknownId(can_id, False)
        return BadValue(can_id, kind, str(exc))


class RawAxisDecoder:
    """:func:`decode_message` cut down to the daemon's hot path: ``decoder(msg)`` is the
    :class:`RawAxis` that ``decode_message(msg, ids)`` returns for a clean RAW_X/Y/Z frame of
    node ``ids``, and None for any other message (call :func:`decode_message`, which says what
    it is). Never raises."""

    __slots__ = ("_axes",)

    def __init__(self, ids: CanIds) -> None:
        self._axes: dict[int, Axis] = {}
        for kind in (MessageKind.RAW_X, MessageKind.RAW_Y, MessageKind.RAW_Z):
            assert kind.axis is not None
            self._axes[ids.id_of(kind)] = kind.axis

    def __call__(self, msg: can.Message) -> RawAxis | None:
        try:
            axis = self._axes.get(msg.arbitration_id)
            if axis is None or msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
                return None
            data = msg.data
            if data is None or len(data) != PAYLOAD_SIZE:
                return None
            frame = RawAxis.decode(bytes(data))
        except (ValueError, TypeError, AttributeError, OverflowError):
            return None
        return frame if frame.axis is axis else None


def encode_message(frame: Frame, ids: CanIds, timestamp_s: float = 0.0) -> can.Message:
    """Build the ``can.Message`` (standard id) carrying ``frame``: a classic 8-byte frame, or
    a CAN FD frame (``is_fd``) for RAW_XYZ and CORRECTED_XYZ."""
    data = frame.encode()
    return can.Message(
        timestamp=timestamp_s,
        arbitration_id=ids.id_of(frame.kind),
        is_extended_id=False,
        is_fd=len(data) > PAYLOAD_SIZE,
        data=data,
    )
