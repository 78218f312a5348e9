"""A Modbus TCP server (asyncio): MBAP framing, unit-id policy, idle and bad-frame handling.

    server = MbapServer(MapDevice(...).handle_pdu, unit_ids={1, 0, 0xFF}, idle_timeout_s=60.0)
    await server.start("127.0.0.1", 5020)     # ...; await server.close()

Per the Modbus Messaging on TCP/IP Implementation Guide V1.0b; requests on one connection are
answered in order, each response carrying its request's transaction and unit id.

* **Bad frame** (protocol id ≠ 0, length field outside 2..254, or a frame begun but not
  completed within ``frame_timeout_s``): the byte stream cannot be resynchronised, so the
  connection is closed and :meth:`MbapListener.on_bad_frame` says why.
* **Idle**: a connection that sends nothing for ``idle_timeout_s`` (0 = never) is closed
  (:meth:`MbapListener.on_idle_close`).
* **Unit id**: a server connected directly to TCP/IP is addressed by its IP address; the guide
  recommends the non-significant unit ids 0xFF (and accepts 0) for it, and reserves the
  exception codes 0x0A/0x0B for gateways. So requests for ``unit_ids`` are served and any other
  unit id gets no response (the connection stays open): this server is not a gateway and must
  not answer for a device it is not (:meth:`MbapListener.on_wrong_unit`).
* A handler that raises is answered with exception 04 (:meth:`MbapListener.on_error`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Collection

from .modbus_map import ExceptionCode
from .modbus_pdu import MBAP_SIZE, FrameError, adu, exception_pdu, parse_header

PduHandler = Callable[[bytes], bytes]
"""Request PDU → response PDU (both without MBAP header)."""

DIRECT_UNIT_IDS = frozenset({0x00, 0xFF})
"""Unit ids that address a server connected directly to TCP/IP (Implementation Guide V1.0b)."""


class MbapListener:
    """Receives what the server sees besides well-formed requests (default: ignore). Methods run
    in the server's event loop: keep them short."""

    def on_connect(self, peer: str) -> None:
        """A client connected from ``peer`` (``host:port``)."""

    def on_bad_frame(self, peer: str, reason: str) -> None:
        """A connection was closed for a bad frame; ``reason`` names the field."""

    def on_idle_close(self, peer: str) -> None:
        """A connection was closed after ``idle_timeout_s`` without data."""

    def on_wrong_unit(self, peer: str, unit_id: int) -> None:
        """A request for a unit id this server does not serve was discarded."""

    def on_error(self, exc: BaseException) -> None:
        """The PDU handler raised (the request was answered with exception 04)."""


class _Connection(asyncio.Protocol):
    def __init__(self, server: MbapServer) -> None:
        self._server = server
        self._loop = asyncio.get_running_loop()
        self._transport: asyncio.Transport | None = None
        self._buf = b""
        self._partial_since = 0.0
        self._last_rx = self._loop.time()
        self._timer: asyncio.TimerHandle | None = None
        self.peer = "?"

    # ---------------------------------------------------------------- asyncio.Protocol
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport
        peer = transport.get_extra_info("peername")
        self.peer = f"{peer[0]}:{peer[1]}" if peer else "?"
        self._server._connections.add(self)
        self._server.listener.on_connect(self.peer)
        self._arm()

    def connection_lost(self, exc: Exception | None) -> None:
        self._server._connections.discard(self)
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._transport = None

    def data_received(self, data: bytes) -> None:
        now = self._loop.time()
        self._last_rx = now
        buf = self._buf + data if self._buf else data
        pos, size = 0, len(buf)
        transport = self._transport
        server = self._server
        while size - pos >= MBAP_SIZE and transport is not None:
            try:
                header = parse_header(buf, pos)
            except FrameError as exc:
                self._bad_frame(str(exc))
                return
            end = pos + 6 + header.length
            if end > size:
                break
            pdu = buf[pos + MBAP_SIZE : end]
            pos = end
            if header.unit_id not in server.unit_ids:
                server.listener.on_wrong_unit(self.peer, header.unit_id)
                continue
            try:
                response = server.handler(pdu)
            except Exception as exc:  # answered, reported, never kills the connection
                response = exception_pdu(pdu[0], ExceptionCode.SERVER_DEVICE_FAILURE)
                server.listener.on_error(exc)
            transport.write(adu(header.transaction_id, header.unit_id, response))
            transport = self._transport
        had_partial = bool(self._buf)
        self._buf = buf[pos:] if pos < size else b""
        if self._buf and (pos or not had_partial):  # a frame began: it must complete in time
            self._partial_since = now
            self._arm()

    # ---------------------------------------------------------------- timeouts
    def _arm(self) -> None:
        """(Re)schedule the one timer at the earliest idle or frame deadline."""
        server = self._server
        deadlines = []
        if server.idle_timeout_s > 0:
            deadlines.append(self._last_rx + server.idle_timeout_s)
        if self._buf:
            deadlines.append(self._partial_since + server.frame_timeout_s)
        if not deadlines or self._transport is None:
            return
        when = min(deadlines)
        if self._timer is not None:
            if self._timer.when() <= when:
                return
            self._timer.cancel()
        self._timer = self._loop.call_at(when, self._check)

    def _check(self) -> None:
        self._timer = None
        if self._transport is None:
            return
        now = self._loop.time()
        server = self._server
        if self._buf and now - self._partial_since >= server.frame_timeout_s:
            self._bad_frame(
                f"incomplete frame ({len(self._buf)} bytes) for {server.frame_timeout_s} s"
            )
            return
        if server.idle_timeout_s > 0 and now - self._last_rx >= server.idle_timeout_s:
            self._transport.close()
            self._transport = None
            server.listener.on_idle_close(self.peer)
            return
        self._arm()

    def _bad_frame(self, reason: str) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        self._buf = b""
        self._server.listener.on_bad_frame(self.peer, reason)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None


class MbapServer:
    """Serve ``handler`` on a TCP port (see the module docstring for the rules).

    :param unit_ids: unit ids answered (others: no response, ``on_wrong_unit``).
    :param idle_timeout_s: close a connection silent this long, s; 0 = never.
    :param frame_timeout_s: a frame begun must complete within this, s (> 0).
    """

    def __init__(
        self,
        handler: PduHandler,
        unit_ids: Collection[int],
        idle_timeout_s: float = 60.0,
        frame_timeout_s: float = 1.0,
        listener: MbapListener | None = None,
    ) -> None:
        if not idle_timeout_s >= 0:
            raise ValueError(f"idle_timeout_s = {idle_timeout_s}; allowed: >= 0 (0 = never)")
        if not frame_timeout_s > 0:
            raise ValueError(f"frame_timeout_s = {frame_timeout_s}; allowed: > 0")
        self.handler = handler
        self.unit_ids = frozenset(unit_ids)
        self.idle_timeout_s = idle_timeout_s
        self.frame_timeout_s = frame_timeout_s
        self.listener = listener or MbapListener()
        self.host = ""
        self.port = 0
        self._server: asyncio.Server | None = None
        self._connections: set[_Connection] = set()

    @property
    def connections(self) -> int:
        """Open connections."""
        return len(self._connections)

    async def start(self, host: str, port: int) -> None:
        """Listen on ``host:port`` (0 = any free port; the bound one is in ``.port``)."""
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: _Connection(self), host, port)
        self.host, self.port = self._server.sockets[0].getsockname()[:2]

    async def close(self) -> None:
        """Stop listening and close every connection."""
        if self._server is not None:
            self._server.close()
        for conn in list(self._connections):
            conn.close()
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None
        await asyncio.sleep(0)  # let the transports finish closing

    async def __aenter__(self) -> MbapServer:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()
