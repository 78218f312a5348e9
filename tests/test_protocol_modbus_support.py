"""Helpers for the Modbus tests: a raw-socket client packing MBAP by hand, a threaded server.

The raw client is the oracle: frames are built with ``struct`` straight from the spec (Modbus
Messaging on TCP/IP Implementation Guide V1.0b: transaction id, protocol id 0, length = unit id
+ PDU bytes, unit id; then the PDU), not with the project's codec.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from modbus_spec_cases import frame

from cmm_comp.protocol import MapDevice, MbapListener, MbapServer

__all__ = ["WAIT_S", "RawClient", "Served", "frame", "threaded_server", "wait_for"]

WAIT_S = 10.0
"""Generous upper bound for anything the tests wait on (loaded 2-core machine)."""


class RawClient:
    """A blocking TCP client speaking bytes (closed on exit)."""

    def __init__(self, port: int, timeout_s: float = WAIT_S) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout_s)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._tid = 0

    def __enter__(self) -> RawClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.sock.close()

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def recv_exact(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            if not chunk:
                raise ConnectionError(f"connection closed after {len(out)} of {n} bytes")
            out += chunk
        return out

    def response(self) -> tuple[int, int, int, bytes]:
        """(transaction id, protocol id, unit id, PDU) of the next response; checks the length."""
        tid, pid, length, unit = struct.unpack(">HHHB", self.recv_exact(7))
        return tid, pid, unit, self.recv_exact(length - 1)

    def request(self, pdu: bytes, unit: int = 1) -> bytes:
        """Send ``pdu`` with a fresh transaction id; the response PDU (tid and unit checked)."""
        self._tid = (self._tid + 1) & 0xFFFF
        self.send(frame(pdu, self._tid, unit))
        tid, pid, runit, rpdu = self.response()
        assert (tid, pid, runit) == (self._tid, 0, unit)
        return rpdu

    def wait_eof(self, timeout_s: float = WAIT_S) -> float:
        """Block until the server closes the connection; seconds waited (TimeoutError if not)."""
        t0 = time.monotonic()
        self.sock.settimeout(timeout_s)
        while True:
            if not self.sock.recv(4096):
                return time.monotonic() - t0


@dataclass
class Recorder(MbapListener):
    """Records the server's listener calls (thread-safe enough: appends only)."""

    bad_frames: list[str] = field(default_factory=list)
    idle_closed: list[str] = field(default_factory=list)
    wrong_units: list[int] = field(default_factory=list)
    errors: list[BaseException] = field(default_factory=list)
    changed: threading.Event = field(default_factory=threading.Event)

    def on_bad_frame(self, peer: str, reason: str) -> None:
        self.bad_frames.append(reason)
        self.changed.set()

    def on_idle_close(self, peer: str) -> None:
        self.idle_closed.append(peer)
        self.changed.set()

    def on_wrong_unit(self, peer: str, unit_id: int) -> None:
        self.wrong_units.append(unit_id)
        self.changed.set()

    def on_error(self, exc: BaseException) -> None:
        self.errors.append(exc)
        self.changed.set()


@dataclass
class Served:
    port: int
    device: MapDevice
    recorder: Recorder


@contextmanager
def threaded_server(
    device: MapDevice,
    unit_ids: tuple[int, ...] = (1, 0, 0xFF),
    idle_timeout_s: float = 60.0,
    frame_timeout_s: float = 1.0,
) -> Iterator[Served]:
    """``MbapServer`` serving ``device`` from its own thread and loop on 127.0.0.1."""
    recorder = Recorder()
    server = MbapServer(device.handle_pdu, unit_ids, idle_timeout_s, frame_timeout_s, recorder)
    loop = asyncio.new_event_loop()
    ready = threading.Event()
    stop: list[asyncio.Event] = []

    async def main() -> None:
        stop.append(asyncio.Event())
        await server.start("127.0.0.1", 0)
        ready.set()
        try:
            await stop[0].wait()
        finally:
            await server.close()

    thread = threading.Thread(target=loop.run_until_complete, args=(main(),), name="test-mbap")
    thread.start()
    try:
        assert ready.wait(WAIT_S), "server did not start"
        yield Served(server.port, device, recorder)
    finally:
        if stop:
            loop.call_soon_threadsafe(stop[0].set)
        thread.join(WAIT_S)
        loop.close()


def wait_for(predicate: object, timeout_s: float = WAIT_S) -> bool:
    """Poll ``predicate()`` until true or ``timeout_s`` passes (no tight timing)."""
    assert callable(predicate)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return bool(predicate())
