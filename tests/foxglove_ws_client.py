"""A Foxglove WebSocket client written from the protocol's public specification
(github.com/foxglove/ws-protocol, docs/spec.md), not from the server under test.

* Handshake: the client offers its subprotocols; the server must select one. The spec's name is
  ``foxglove.websocket.v1``; foxglove-sdk servers select ``foxglove.sdk.v1`` (the same messages).
* Text frames are JSON objects with an ``op``: the server sends ``serverInfo`` first, then
  ``advertise`` (``channels``: ``id``, ``topic``, ``encoding``, ``schemaName``, ``schema``,
  ``schemaEncoding``); the client sends ``subscribe`` (``subscriptions``: ``id`` chosen by the
  client, ``channelId``) and ``unsubscribe`` (``subscriptionIds``).
* Binary frames start with a one-byte opcode; ``0x01`` Message Data is
  ``opcode u8 | subscription id u32 LE | log time u64 LE (ns) | payload``.

Protobuf payloads (``foxglove.SceneUpdate``) are decoded with the ``protobuf`` package from the
FileDescriptorSet the server advertises (base64 in ``schema``), as a Foxglove client does.
"""

from __future__ import annotations

import base64
import json
import struct
import time
from dataclasses import dataclass
from typing import Any

from websockets.sync.client import ClientConnection, connect

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
MESSAGE_HEADER = struct.Struct("<BIQ")  # opcode, subscription id, log time ns


@dataclass
class Message:
    """One Message Data frame: the channel's topic, its log time (ns) and raw payload."""

    topic: str
    log_time_ns: int
    payload: bytes

    def json(self) -> Any:
        """The payload parsed as JSON (strict: NaN/Infinity are refused)."""

        def refuse(token: str) -> Any:
            raise ValueError(f"not JSON: {token}")

        return json.loads(self.payload, parse_constant=refuse)


class FoxgloveClient:
    """Connect, read ``serverInfo`` and the advertised channels, subscribe by topic, receive."""

    def __init__(self, url: str, timeout_s: float = 5.0) -> None:
        self.timeout_s = timeout_s
        # entered as a context manager (websockets 15+ warns when a connection is used unentered)
        self.ws: ClientConnection = connect(
            url, subprotocols=SUBPROTOCOLS, open_timeout=timeout_s, max_size=None
        ).__enter__()
        self.subprotocol = self.ws.subprotocol
        self.server_info: dict[str, Any] = {}
        self.channels: dict[str, dict[str, Any]] = {}  # topic -> advertised channel
        self.statuses: list[dict[str, Any]] = []
        self._subs: dict[int, str] = {}
        self._next_sub = 1
        self.backlog: list[Message] = []
        first = self._text()
        if first.get("op") != "serverInfo":
            raise AssertionError(f"first message is not serverInfo: {first}")
        self.server_info = first

    def _text(self) -> dict[str, Any]:
        frame = self.ws.recv(timeout=self.timeout_s)
        if not isinstance(frame, str):
            raise AssertionError(f"expected a JSON text frame, got {len(frame)} binary bytes")
        return json.loads(frame)  # type: ignore[no-any-return]

    def _handle_text(self, msg: dict[str, Any]) -> None:
        op = msg.get("op")
        if op == "advertise":
            for ch in msg["channels"]:
                self.channels[ch["topic"]] = ch
        elif op == "unadvertise":
            gone = set(msg["channelIds"])
            self.channels = {t: c for t, c in self.channels.items() if c["id"] not in gone}
        elif op == "status":
            self.statuses.append(msg)

    def wait_for_channels(self, topics: list[str]) -> None:
        """Read until every topic in ``topics`` was advertised."""
        deadline = time.monotonic() + self.timeout_s
        while not all(t in self.channels for t in topics):
            if time.monotonic() > deadline:
                raise AssertionError(f"not advertised: {set(topics) - set(self.channels)}")
            self._handle_text(self._text())

    def subscribe(self, topics: list[str]) -> None:
        """Subscribe to ``topics`` (already advertised), one subscription id each."""
        subs = []
        for topic in topics:
            sid = self._next_sub
            self._next_sub += 1
            self._subs[sid] = topic
            subs.append({"id": sid, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def unsubscribe(self, topics: list[str]) -> None:
        ids = [sid for sid, t in self._subs.items() if t in topics]
        for sid in ids:
            del self._subs[sid]
        self.ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": ids}))

    def _message(self, frame: bytes) -> Message | None:
        opcode, sid, log_time = MESSAGE_HEADER.unpack_from(frame, 0)
        if opcode != MESSAGE_DATA:
            return None
        return Message(self._subs[sid], log_time, bytes(frame[MESSAGE_HEADER.size :]))

    def receive(self, count: int, timeout_s: float | None = None) -> list[Message]:
        """The next ``count`` Message Data frames (text frames in between are handled)."""
        out: list[Message] = self.backlog[:count]
        del self.backlog[:count]
        deadline = time.monotonic() + (timeout_s or self.timeout_s)
        while len(out) < count:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"received {len(out)} of {count} messages: {out[-3:]}")
            try:
                frame = self.ws.recv(timeout=left)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                self._handle_text(json.loads(frame))
            elif (msg := self._message(frame)) is not None:
                out.append(msg)
        return out

    def drain_text(self, timeout_s: float = 0.2) -> None:
        """Handle what arrives within ``timeout_s``: text frames (status messages …) at once,
        Message Data kept for :meth:`receive`."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                frame = self.ws.recv(timeout=left)
            except TimeoutError:
                return
            if isinstance(frame, str):
                self._handle_text(json.loads(frame))
            elif (msg := self._message(frame)) is not None:
                self.backlog.append(msg)

    def close(self) -> None:
        self.ws.__exit__(None, None, None)

    def __enter__(self) -> FoxgloveClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def protobuf_class(channel: dict[str, Any]) -> Any:
    """The message class of a protobuf channel, built from its advertised FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    todo = list(fds.file)
    while todo:  # add files after their dependencies, whatever order the set lists them in
        added = {f.name for f in fds.file} - {f.name for f in todo}
        ready = [f for f in todo if set(f.dependency) <= added]
        assert ready, f"unresolvable dependencies in {[f.name for f in todo]}"
        for f in ready:
            pool.Add(f)
            todo.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))
