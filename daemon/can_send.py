"""Send and take batches of CAN frames on one bus: what the endpoint uses under load.

python-can has no batch send or receive; :func:`send_batch` sends the frames in order with one
``bus.send`` each and :func:`recv_pending` takes what is waiting with ``bus.recv(0)`` calls,
except on python-can's in-process ``virtual`` interface (pinned 4.6.1). Its ``send``
deep-copies the message once per receiver (~8 µs a frame, most of the cost of an answer on
that bus) and puts it with one locked ``Queue.put`` each; its ``recv`` is one locked
``Queue.get`` per frame. There :func:`send_batch` hands the frames to every other receiver's
queue as fresh ``can.Message`` objects with exactly the fields ``VirtualBus.send`` sets
(timestamp, channel, ``is_rx``), all of one batch under one lock when the queue is unbounded
(a bounded queue keeps one blocking ``put`` per frame), and :func:`recv_pending` takes every
waiting frame under one lock, then applies the bus's filters as ``BusABC.recv`` does.
``tests/test_daemon_can_send.py`` checks both against ``VirtualBus.send`` / ``recv``.
"""

from __future__ import annotations

import queue
import time
from collections import deque
from collections.abc import Sequence

import can
from can.interfaces.virtual import VirtualBus

__all__ = ["recv_pending", "send_batch"]


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
    unbounded = [q for q in receivers if q.maxsize <= 0]
    if len(unbounded) == len(receivers):
        _put_batches(receivers, own, channel_id, preserve, msgs)
        return
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


def _put_batches(
    receivers: list[queue.Queue[can.Message]],
    own: queue.Queue[can.Message],
    channel_id: can.typechecking.Channel,
    preserve: bool,
    msgs: Sequence[can.Message],
) -> None:
    """Unbounded receiver queues: each receiver's copies of all ``msgs`` go in with one lock
    and one notify (``Queue.put`` per frame, batched: same items, same order)."""
    Message = can.Message
    now = time.time()
    for q in receivers:
        is_rx = q is not own
        copies = [
            Message(
                timestamp=msg.timestamp if preserve else now,
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
                channel=channel_id,
                dlc=msg.dlc,
                data=bytes(msg.data) if msg.data is not None else None,
                is_fd=msg.is_fd,
                is_rx=is_rx,
                bitrate_switch=msg.bitrate_switch,
                error_state_indicator=msg.error_state_indicator,
                check=False,
            )
            for msg in msgs
        ]
        if not copies:
            continue
        with q.not_empty:
            q.queue.extend(copies)
            q.unfinished_tasks += len(copies)
            q.not_empty.notify(len(copies))


def recv_pending(bus: can.BusABC, max_n: int) -> list[can.Message]:
    """Up to ``max_n`` frames already waiting on ``bus``, in order, without blocking (what
    ``bus.recv(0)`` repeated until it returns None gives). Raises what the bus raises."""
    if type(bus) is VirtualBus and _virtual_layout_known(bus):
        q = bus.queue
        if isinstance(q, queue.Queue) and isinstance(getattr(q, "queue", None), deque):
            bus._check_if_open()
            with q.mutex:
                items = q.queue
                n = min(len(items), max_n)
                got = [items.popleft() for _ in range(n)]
                if n:
                    q.not_full.notify(n)
            if bus._filters is None:
                return got
            match = bus._matches_filters
            return [m for m in got if match(m)]
    out: list[can.Message] = []
    recv = bus.recv
    for _ in range(max_n):
        msg = recv(0.0)
        if msg is None:
            break
        out.append(msg)
    return out
