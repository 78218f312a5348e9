"""CAN identifiers of the message set: one block of 16 standard (11-bit) ids per machine.

``id = base_id + 0x10 · node_id + offset`` with the offsets of :class:`MessageKind`. The
defaults (``base_id=0x200``) give node 0 the ids 0x200..0x20F, node 1 0x210..0x21F, …; node ids
0..95 fit below 0x7FF (a lower id wins arbitration, so node 0 has the highest priority). The DBC file ``cmm_comp.dbc`` describes node 0;
:func:`dbc_text` shifts it to any other node.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass
from importlib import resources

from .codes import Axis

STANDARD_ID_MAX = 0x7FF
NODE_STRIDE = 0x10
DBC_BASE_ID = 0x200
"""Base id the shipped DBC uses (node 0, default base)."""


class MessageKind(enum.IntEnum):
    """Message type; the value is the id offset inside a node's block."""

    RAW_X = 0x0
    RAW_Y = 0x1
    RAW_Z = 0x2
    PROBE_DIRECTION = 0x3
    TEMPERATURE = 0x4
    RAW_XYZ = 0x5
    """CAN FD: a whole reading in one 20-byte frame (:mod:`.can_fd_frames`)."""
    CORRECTED_X = 0x8
    CORRECTED_Y = 0x9
    CORRECTED_Z = 0xA
    CORRECTION_STATUS = 0xB
    CORRECTION_UNCERTAINTY = 0xC
    CORRECTED_XYZ = 0xD
    """CAN FD: the whole answer to a RAW_XYZ reading in one 32-byte frame."""
    HEARTBEAT = 0xF

    @property
    def axis(self) -> Axis | None:
        """Axis of a per-axis message, None for the others."""
        return _AXIS_OF.get(self)


_AXIS_OF = {
    MessageKind.RAW_X: Axis.X,
    MessageKind.RAW_Y: Axis.Y,
    MessageKind.RAW_Z: Axis.Z,
    MessageKind.CORRECTED_X: Axis.X,
    MessageKind.CORRECTED_Y: Axis.Y,
    MessageKind.CORRECTED_Z: Axis.Z,
}
RAW_KIND = {Axis.X: MessageKind.RAW_X, Axis.Y: MessageKind.RAW_Y, Axis.Z: MessageKind.RAW_Z}
CORRECTED_KIND = {
    Axis.X: MessageKind.CORRECTED_X,
    Axis.Y: MessageKind.CORRECTED_Y,
    Axis.Z: MessageKind.CORRECTED_Z,
}
_BY_OFFSET = {int(k): k for k in MessageKind}
CONTROLLER_KINDS = frozenset(
    {*RAW_KIND.values(), MessageKind.RAW_XYZ, MessageKind.PROBE_DIRECTION, MessageKind.TEMPERATURE}
)
"""Messages the controller transmits (DBC transmitter ``Controller``)."""
DAEMON_KINDS = frozenset(
    {
        *CORRECTED_KIND.values(),
        MessageKind.CORRECTION_UNCERTAINTY,
        MessageKind.CORRECTION_STATUS,
        MessageKind.CORRECTED_XYZ,
        MessageKind.HEARTBEAT,
    }
)
"""Messages the daemon transmits (DBC transmitter ``Daemon``)."""


def sent_by_daemon(can_id: int, is_extended: bool = False) -> bool:
    """True if a frame with this id is one a daemon transmits, per the DBC, whatever its node
    and base id (blocks start at multiples of 16, so the id's offset in its block is
    ``can_id % 16``). Extended (29-bit) ids are never the daemon's. How replay recognises the
    daemon's own frames in a log written before frames carried their direction."""
    if is_extended or not 0 <= can_id <= STANDARD_ID_MAX:
        return False
    return _BY_OFFSET.get(can_id % NODE_STRIDE) in DAEMON_KINDS


@dataclass(frozen=True)
class CanIds:
    """The CAN ids of one machine (node) on a shared bus.

    ``node_id`` selects the machine's block of 16 ids; ``base_id`` moves all blocks.
    """

    node_id: int = 0
    base_id: int = DBC_BASE_ID

    def __post_init__(self) -> None:
        if self.base_id < 0 or self.base_id % NODE_STRIDE:
            raise ValueError(
                f"base_id {self.base_id:#x} must be a non-negative multiple of {NODE_STRIDE:#x}"
            )
        top = self.base_id + NODE_STRIDE * self.node_id + NODE_STRIDE - 1
        if self.node_id < 0 or top > STANDARD_ID_MAX:
            max_node = (STANDARD_ID_MAX + 1 - self.base_id) // NODE_STRIDE - 1
            raise ValueError(
                f"node_id {self.node_id} out of range 0..{max_node} for base_id "
                f"{self.base_id:#x} (ids must stay standard 11-bit, <= {STANDARD_ID_MAX:#x})"
            )

    @property
    def block_start(self) -> int:
        """First id of this node's block."""
        return self.base_id + NODE_STRIDE * self.node_id

    def id_of(self, kind: MessageKind) -> int:
        """CAN id of message ``kind`` for this node."""
        return self.block_start + int(kind)

    def kind_of(self, can_id: int) -> MessageKind | None:
        """Message kind of ``can_id`` if it belongs to this node, else None."""
        offset = can_id - self.block_start
        if not 0 <= offset < NODE_STRIDE:
            return None
        return _BY_OFFSET.get(offset)

    def raw_id(self, axis: Axis) -> int:
        """Id of the raw axis frame for ``axis``."""
        return self.id_of(RAW_KIND[axis])

    def corrected_id(self, axis: Axis) -> int:
        """Id of the corrected axis frame for ``axis``."""
        return self.id_of(CORRECTED_KIND[axis])

    def controller_tx_ids(self) -> frozenset[int]:
        """Ids the controller sends (raw axes, probing direction, temperature)."""
        return frozenset(self.id_of(k) for k in CONTROLLER_KINDS)

    def daemon_tx_ids(self) -> frozenset[int]:
        """Ids the daemon sends (corrected axes, uncertainty, correction status, heartbeat)."""
        return frozenset(self.id_of(k) for k in DAEMON_KINDS)

    def can_filters(self) -> list[dict[str, int | bool]]:
        """python-can ``can_filters`` accepting exactly this node's block of 16 standard ids."""
        return [{"can_id": self.block_start, "can_mask": 0x7F0, "extended": False}]


_ID_REF = re.compile(r"\b(BO_|SG_|VAL_) (\d+) ")
"""A message id in a DBC line: ``BO_ 512 …``, ``CM_ SG_ 512 …``, ``VAL_ 512 …``."""


def dbc_text(ids: CanIds | None = None) -> str:
    """Text of the shipped DBC, with its message ids shifted to ``ids`` (default: node 0)."""
    text = resources.files("cmm_comp.protocol").joinpath("cmm_comp.dbc").read_text(encoding="utf-8")
    if ids is None:
        return text
    shift = ids.block_start - DBC_BASE_ID
    return _ID_REF.sub(lambda m: f"{m.group(1)} {int(m.group(2)) + shift} ", text)
