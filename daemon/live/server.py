"""The ``foxglove-sdk`` side of the live view: one ``foxglove.Context`` of its own (nothing on
the SDK's global context), a JSON channel per streamed session-log topic (the MCAP log's JSON
Schema and schema name), the ``/cmm/scene`` ``foxglove.SceneUpdate`` channel, and the WebSocket
server (the SDK's Rust server, on threads of its own).

The SDK's server speaks the Foxglove WebSocket protocol under the subprotocol name
``foxglove.sdk.v1`` (the same messages as the ``foxglove.websocket.v1`` of the published spec;
the SDK refuses a client that offers only the old name with HTTP 400). Current Foxglove apps
offer both.
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.protocol.session_topics import TOPIC_SCHEMAS

from .settings import LiveSection

SUBPROTOCOL = "foxglove.sdk.v1"
"""WebSocket subprotocol the SDK's server selects (docs/live.md)."""


class LiveStartError(CmmCompError, RuntimeError):
    """The live view could not start (package missing, address in use …); one line."""


SubscriptionHook = Callable[[int, int, bool], None]
"""``(client_id, channel_id, subscribed)``, called on the server's threads."""


@dataclass
class LiveServer:
    """The open server and its channels. ``channels``: topic → ``foxglove.Channel``;
    ``scene``: the ``SceneUpdateChannel``; ``topic_of``: channel id → topic; ``context``: the
    ``foxglove.Context`` (kept referenced: once the Python object is freed, the server no longer
    advertises the channels to new clients)."""

    server: Any
    channels: dict[str, Any]
    scene: Any
    topic_of: dict[int, str]
    context: Any
    host: str = ""

    @property
    def port(self) -> int:
        """The bound port."""
        return int(self.server.port)

    def close_channels(self) -> None:
        """Close every channel (clients see them unadvertised); never raises."""
        for ch in [*self.channels.values(), self.scene]:
            with contextlib.suppress(Exception):  # a channel of a stopped server
                ch.close()

    def stop(self, release_wait_s: float = 2.0) -> None:
        """Stop the server (connections closed, port released), then close the channels.

        The SDK's ``stop()`` may return before its runtime has closed the listening socket;
        this waits (at most ``release_wait_s``, s) until the port can be bound again, so a
        restart on the same port right after finds it free."""
        port = self.port
        try:
            self.server.stop()
        finally:
            self.close_channels()
        _wait_released(self.host, port, release_wait_s)


def _wait_released(host: str, port: int, timeout_s: float) -> bool:
    """Whether ``host:port`` (TCP) can be bound, polled every 10 ms for up to ``timeout_s``
    (s). SO_REUSEADDR: only a listener, not a closed connection's TIME_WAIT, blocks the bind."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    deadline = time.monotonic() + timeout_s
    while True:
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind((host or "127.0.0.1", port))
                return True
            except OSError:
                pass
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)


def open_live_server(
    settings: LiveSection,
    topics: Iterable[str],
    scene_topic: str,
    on_subscription: SubscriptionHook,
    name: str = "cmm-comp",
    topic_of: dict[int, str] | None = None,
) -> LiveServer:
    """Create the channels on a new context and start the server on ``settings.host`` /
    ``settings.port``. ``topic_of`` (channel id → topic) is filled before the server starts,
    so the hook can resolve a subscription at once. Raises :class:`LiveStartError` with one line when ``foxglove-sdk`` is
    not installed or the address cannot be bound (nothing is left open then)."""
    try:
        import foxglove
        import foxglove.messages  # the scene's (.scene, imported once this passed)
        from foxglove.channels import SceneUpdateChannel
        from foxglove.websocket import ServerListener
    except ImportError as exc:
        raise LiveStartError(
            f"live view: the foxglove-sdk package is not installed ({exc}); install it with "
            "pip install 'cmm-comp[live]' or set live.enabled = false"
        ) from None

    class Listener(ServerListener):
        """Subscriptions to the hook; runs on the server's threads, so it does nothing else."""

        def on_subscribe(self, client: Any, channel: Any) -> None:
            on_subscription(int(client.id), int(channel.id), True)

        def on_unsubscribe(self, client: Any, channel: Any) -> None:
            on_subscription(int(client.id), int(channel.id), False)

    context = foxglove.Context()
    channels: dict[str, Any] = {}
    topic_of = {} if topic_of is None else topic_of
    for topic in topics:
        ch = foxglove.Channel(topic, schema=dict(TOPIC_SCHEMAS[topic].schema), context=context)
        channels[topic] = ch
        topic_of[ch.id()] = topic
    scene = SceneUpdateChannel(scene_topic, context=context)
    topic_of[scene.id()] = scene_topic
    try:
        server = foxglove.start_server(
            name=name,
            host=settings.host,
            port=settings.port,
            server_listener=Listener(),
            context=context,
        )
    except Exception as exc:  # the SDK raises RuntimeError("FoxgloveError: …")
        LiveServer(None, channels, scene, topic_of, context).close_channels()
        raise LiveStartError(
            f"live view: cannot listen on {settings.host}:{settings.port} ({exc}); choose "
            "another live.port (0 = any free port) or set live.enabled = false"
        ) from None
    return LiveServer(server, channels, scene, topic_of, context, settings.host)
