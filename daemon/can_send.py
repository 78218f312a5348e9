"""Send and take batches of CAN frames on one bus: what the endpoint does under load.

python-can has no batch send or receive: :func:`send_batch` sends the frames in order with one
``bus.send`` each, :func:`recv_pending` takes what is waiting with ``bus.recv(0)`` calls. Only
the public ``BusABC`` interface: the same code for every interface (socketcan, pcan, …, and
the ``virtual`` and ``udp_multicast`` buses of the tests).
"""

from __future__ import annotations

from collections.abc import Sequence

import can

__all__ = ["recv_pending", "send_batch"]


def send_batch(bus: can.BusABC, msgs: Sequence[can.Message], timeout_s: float | None) -> None:
    """Send ``msgs`` in order on ``bus``; each ``bus.send`` may block up to ``timeout_s`` (s).

    Raises what the bus raises (``can.CanError``) on the first frame that could not be sent;
    the frames before it were sent.
    """
    send = bus.send
    for msg in msgs:
        send(msg, timeout=timeout_s)


def recv_pending(bus: can.BusABC, max_n: int) -> list[can.Message]:
    """Up to ``max_n`` frames already waiting on ``bus``, in order, without blocking (what
    ``bus.recv(0)`` repeated until it returns None gives). Raises what the bus raises."""
    out: list[can.Message] = []
    recv = bus.recv
    for _ in range(max_n):
        msg = recv(0.0)
        if msg is None:
            break
        out.append(msg)
    return out
