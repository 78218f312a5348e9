"""Send a batch of CAN frames on one bus: what the endpoint uses to answer several readings.

python-can has no batch send; :func:`send_batch` sends the frames in order with one
``bus.send`` each, except on python-can's in-process ``virtual`` interface (pinned 4.6.1),
whose ``send`` deep-copies the message once per receiver (~8 µs a frame, most of the cost of
an answer on that bus). There the frames are handed to every other receiver's queue as fresh
``can.Message`` objects with exactly the fields ``VirtualBus.send`` sets (timestamp, channel,
``is_rx``), which ``tests/test_daemon_can_send.py`` checks against ``VirtualBus.send`` itself.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import can
from can.interfaces.virtual import VirtualBus

__all__ = ["send_batch"]


def send_batch(bus: can.BusABC, msgs: Sequence[can.Message], timeout_s: float | None) -> None:
    """Send ``msgs`` in order on ``bus``; each ``bus.send`` may block up to ``timeout_s`` (s).

    Raises what the bus raises (``can.CanError``) on the first frame that could not be sent;
    the frames before it were sent.
    """
    if type(bus) is VirtualBus and _virtual_layout_known(bus):
        _send_virtual(bus, msgs, timeout_s)
        return
    send = bus.send
    for msg in msgs:
        send(msg, timeout=timeout_s)


def _virtual_layout_known(bus: VirtualBus) -> bool:
    """True if ``bus`` has the attributes of python-can 4.6's VirtualBus this module uses."""
    return (
        isinstance(getattr(bus, "channel", None), list)
        and hasattr(bus, "queue")
        and hasattr(bus, "receive_own_messages")
        and hasattr(bus, "preserve_timestamps")
        and hasattr(bus, "channel_id")
    )


def _send_virtual(bus: VirtualBus, msgs: Sequence[can.Message], timeout_s: float | None) -> None:
    """``VirtualBus.send`` for each message, without the per-receiver ``deepcopy``."""
    bus._check_if_open()
    own = bus.queue
    receivers = [q for q in bus.channel if q is not own or bus.receive_own_messages]
    channel_id = bus.channel_id
    preserve = bus.preserve_timestamps
    Message = can.Message
    for msg in msgs:
        timestamp = msg.timestamp if preserve else time.time()
        data = bytes(msg.data) if msg.data is not None else None
        all_sent = True
        for q in receivers:
            copy = Message(
                timestamp=timestamp,
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
                channel=channel_id,
                dlc=msg.dlc,
                data=data,
                is_fd=msg.is_fd,
                is_rx=q is not own,
                bitrate_switch=msg.bitrate_switch,
                error_state_indicator=msg.error_state_indicator,
                check=False,
            )
            try:
                q.put(copy, block=True, timeout=timeout_s)
            except Exception:  # queue.Full, as VirtualBus.send reports it
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")
