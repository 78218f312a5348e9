""":class:`LiveSink`: the daemon's session-log topics, live, over the Foxglove WebSocket protocol.

The sink is one more consumer of what the daemon already hands its session log (compact record
tuples and dicts, ``log`` / ``log_many``, see ``sessionlog``). In the daemon those calls go to
:class:`.process.LiveProcessSink`, which copies them into shared memory; the view's process
(:mod:`.child`) hands what it read to :meth:`LiveSink.tick`. Used on its own (tests, a
program of its own), :meth:`LiveSink.log_many` keeps the batches for the next update.

Each update (:meth:`LiveSink.tick`, at most ``update_rate_hz`` times a second) takes the
batches offered since the last one (a topic nobody is subscribed to is counted
``not_encoded`` and never encoded; the newest ``/cmm/status`` and ``/cmm/grid`` are kept to
greet a new subscriber), decimates the high-rate topics (:mod:`.decimate`: at most ``max_per_update`` messages of ``/cmm/raw`` and of
``/cmm/corrected`` per update, counted ``decimated``), encodes each message as the session log
does (``sessionlog.encoding``: the topic's Struct, ``stamp = {sec, nsec}``; a non-finite
number as ``null``, counted) and hands it to the SDK's server (``foxglove-sdk``: a Rust
WebSocket server on its own threads) with the log time as the message time; it also builds
``/cmm/scene`` (:mod:`.scene`) at most ``scene_rate_hz`` times a second.

Errors never stop the daemon: a message that cannot be encoded is counted and passed to
``on_error``, an unexpected error in an update is reported and the next one goes on. A server
that cannot listen raises :class:`LiveStartError` (one line) from :meth:`LiveSink.start`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Self

from ..sessionlog.encoding import message_struct, struct_json
from ..sessionlog.logger import ReportingConsumer
from .decimate import kept
from .server import LiveServer, LiveStartError, open_live_server
from .settings import LiveSection, host_problem

_log = logging.getLogger(__name__)

STREAMED_TOPICS: tuple[str, ...] = (
    "/cmm/raw",
    "/cmm/corrected",
    "/cmm/temperature",
    "/cmm/status",
    "/cmm/counters",
    "/cmm/grid",
)
"""Session-log topics the live view streams, with the MCAP log's schema names and payloads
(the CAN/Modbus frame topics and ``/cmm/log_error`` are for the file only)."""
TOPIC_BITS: dict[str, int] = {topic: 1 << i for i, topic in enumerate(STREAMED_TOPICS)}
"""The bit of each streamed topic in the ``wanted`` mask the view's process shares."""
LATCHED_TOPICS: frozenset[str] = frozenset({"/cmm/status", "/cmm/grid"})
"""Rare topics whose newest message is sent again to each new subscriber."""
SCENE_TOPIC = "/cmm/scene"
"""The derived ``foxglove.SceneUpdate`` channel (protobuf) of the correction vectors."""
CORRECTED = "/cmm/corrected"
Batch = tuple[str, Sequence[Any], int]
"""``(topic, payloads, log_time_ns)``: what one ``log_many`` call offers."""
_TIME_NS_MAX = 2**64 - 1
_PENDING_MAX = 4096
"""Scene points kept between two scene updates (older ones are decimated away)."""


@dataclass(frozen=True)
class LiveStats:
    """Counters since start. For the streamed topics every message offered ends in exactly one
    of ``not_encoded`` (nobody subscribed to its topic when it was offered or sent: never
    encoded), ``decimated`` (left out of an update, :mod:`.decimate`), ``dropped`` (a queue
    was full), ``sent`` (encoded and handed to the server) or ``encode_errors`` (could not be
    built or encoded), or still waits (``queue_len``); so ``offered = not_encoded + decimated +
    dropped + sent + encode_errors + queue_len`` (``dropped`` and ``queue_len``: the daemon's
    shared-memory ring, :class:`.process.LiveProcessSink`). ``up``: the view runs (its process is alive
    and has looped within :data:`.process.STALL_S`).
    ``nulled``: non-finite numbers sent as ``null``. ``replayed``: latched messages sent again
    to new subscribers. Scene: ``scene_updates`` sent, ``scene_points`` drawn, ``scene_decimated``
    left out by the per-update limit, ``scene_skipped`` not drawable (a missing or non-finite
    position or correction)."""

    offered: int
    not_encoded: int
    dropped: int
    sent: int
    encode_errors: int
    queue_len: int
    nulled: int
    replayed: int
    scene_updates: int
    scene_points: int
    scene_decimated: int
    scene_skipped: int
    clients: int
    subscriptions: int
    dropped_by_topic: Mapping[str, int] = field(default_factory=dict)
    decimated: int = 0
    up: bool = True

    def counters(self) -> dict[str, int]:
        """The counters the daemon publishes (``/cmm/counters``, Prometheus ``cmm_comp_…``)."""
        return {
            "live_sent": self.sent,
            "live_dropped": self.dropped,
            "live_decimated": self.decimated,
            "live_up": int(self.up),
            "live_not_encoded": self.not_encoded,
            "live_encode_errors": self.encode_errors,
            "live_nulled": self.nulled,
            "live_scene_updates": self.scene_updates,
            "live_clients": self.clients,
            "live_subscriptions": self.subscriptions,
        }


class LiveSink(ReportingConsumer):
    """Stream the session-log topics and ``/cmm/scene`` to Foxglove WebSocket clients.

    ``with LiveSink(settings).start() as live: live.log_many(topic, records); live.tick()``;
    or :meth:`start`, :meth:`tick` at the update rate (with the batches, in the view's
    process), then :meth:`stop`. Thread-safe producers; never blocks them.

    :param settings: the ``[live]`` section (checked again here: a bad host is refused).
    :param on_error: called with each problem (a message that could not be encoded, a failure in
        an update), in the thread calling :meth:`tick`; its own failure is logged, never raised.
    :param name: server name shown by clients.
    """

    _report_level = logging.WARNING  # a problem of the view: the daemon corrects on

    def __init__(
        self,
        settings: LiveSection,
        on_error: Callable[[BaseException], None] | None = None,
        name: str = "cmm-comp",
    ) -> None:
        why = host_problem(settings.host, settings.allow_remote)
        if why is not None:
            raise LiveStartError(f"live.host = {why}")
        super().__init__(on_error, "live view")
        self.settings = settings
        self._name = name
        self._lock = threading.Lock()
        self._batches: list[Batch] = []
        self._wanted: frozenset[str] = frozenset()
        self._latest: dict[str, tuple[Any, int]] = {}
        self._replay: set[str] = set()
        self._subs: dict[int, set[int]] = {}  # channel id -> client ids
        self._sub_lock = threading.Lock()
        self._topic_of: dict[int, str] = {}
        # counters (under _lock; idle and dropped: the daemon's side, LiveProcessSink)
        self._offered = 0
        self._idle = 0
        self._dropped = 0
        self._dropped_by: dict[str, int] = {}
        # counters (the thread calling tick)
        self._unsent = 0
        self._decimated = 0
        self._sent = 0
        self._errors = 0
        self._nulled = 0
        self._replayed = 0
        self._scene_updates = 0
        self._scene_points = 0
        self._scene_decimated = 0
        self._scene_skipped = 0
        self._pending: list[Any] = []
        self._next_slot = 0
        self._last_scene = 0.0
        self._server: LiveServer | None = None
        self._channels: dict[str, Any] = {}
        self._topics: frozenset[str] = frozenset()  # taken by log_many once started
        self._scene_channel: Any = None
        self._scene_mod: Any = None
        self._stopped = False

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Self:
        """Create the channels and the server (the owner calls :meth:`tick` from then on).
        Raises :class:`LiveStartError` (one line) when ``foxglove-sdk`` is missing or the
        address cannot be bound; nothing is left running then."""
        self._server = open_live_server(  # the one clear error when foxglove-sdk is missing
            self.settings,
            STREAMED_TOPICS,
            SCENE_TOPIC,
            self._subscribed,
            self._name,
            self._topic_of,
        )
        from . import scene  # imports foxglove: only once it is known to be there

        self._scene_mod = scene
        self._scene_channel = self._server.scene
        self._channels = self._server.channels
        self._topics = frozenset(STREAMED_TOPICS)  # producers start taking messages now
        return self

    @property
    def port(self) -> int:
        """The port the server listens on (the chosen one when ``port = 0``)."""
        return self._server.port if self._server is not None else 0

    @property
    def url(self) -> str:
        """``ws://host:port`` for Foxglove's *Open connection → Foxglove WebSocket*."""
        host = self.settings.host
        host = f"[{host}]" if ":" in host else host
        return f"ws://{host}:{self.port}"

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Send what is queued, stop the server (connections closed). True when done.
        Idempotent. (``timeout_s``: the interface's; nothing here waits.)"""
        if self._stopped:
            return True
        self._stopped = True
        if self._server is None:
            return True
        self.tick(final=True)
        try:
            self._server.stop()
        except Exception as exc:  # reported, the daemon's stop goes on
            self._report(exc)
            return False
        return True

    # ------------------------------------------------------------------ producers
    def log_many(self, topic: str, payloads: Sequence[Any], log_time_ns: int | None = None) -> int:
        """Offer ``payloads`` of ``topic`` (record tuples or dicts, as the session log takes
        them) with one log time (integer ns since the epoch; now if None) to the next
        :meth:`tick` (a topic nobody watches: counted ``not_encoded`` at once; beyond ``queue``
        batches waiting, dropped and counted). Never blocks;
        the sequence and its payloads must not be changed afterwards. Returns ``len(payloads)``
        (0 once stopped); topics the view does not stream are ignored."""
        n = len(payloads)
        if not n or topic not in self._topics:
            return n
        t_ns = time.time_ns() if log_time_ns is None else log_time_ns
        if topic in LATCHED_TOPICS:
            self._latest[topic] = (payloads[-1], t_ns)
        if self._stopped:
            return 0
        with self._lock:
            self._offered += n
            if topic not in self._wanted:  # the common case: nobody watches this topic
                self._idle += n
            elif len(self._batches) < self.settings.queue:
                self._batches.append((topic, payloads, t_ns))
            else:  # nobody ticks: bounded, the newest dropped (as by the daemon's ring)
                self._dropped += n
                self._dropped_by[topic] = self._dropped_by.get(topic, 0) + n
        return n

    def kick(self) -> None:
        """Nothing to wake: updates run at their own rate (the :class:`SessionLogger` call)."""

    # ------------------------------------------------------------------ subscriptions
    def _subscribed(self, client_id: int, channel_id: int, on: bool) -> None:
        topic = self._topic_of.get(channel_id)
        if topic is None:
            return
        with self._sub_lock:
            clients = self._subs.setdefault(channel_id, set())
            if on:
                clients.add(client_id)
                if topic in LATCHED_TOPICS:
                    self._replay.add(topic)
            else:
                clients.discard(client_id)
            wanted = set()
            for cid, who in self._subs.items():
                if who:
                    t = self._topic_of[cid]
                    wanted.add(CORRECTED if t == SCENE_TOPIC else t)
            self._wanted = frozenset(wanted)

    @property
    def wanted_topics(self) -> frozenset[str]:
        """The session-log topics some client needs now (``/cmm/corrected`` for the scene too)."""
        return self._wanted

    def _sub_counts(self) -> tuple[int, int]:
        with self._sub_lock:
            clients = set().union(*self._subs.values()) if self._subs else set()
            return len(clients), sum(len(v) for v in self._subs.values())

    # ------------------------------------------------------------------ statistics
    def stats(self) -> LiveStats:
        """A snapshot of the counters (exact after :meth:`stop`)."""
        with self._lock:
            offered, idle, dropped = self._offered, self._idle, self._dropped
            by_topic = dict(self._dropped_by)
        clients, subs = self._sub_counts()
        return LiveStats(
            offered=offered,
            not_encoded=idle + self._unsent,
            decimated=self._decimated,
            dropped=dropped,
            sent=self._sent,
            encode_errors=self._errors,
            queue_len=0,
            nulled=self._nulled,
            replayed=self._replayed,
            scene_updates=self._scene_updates,
            scene_points=self._scene_points,
            scene_decimated=self._scene_decimated,
            scene_skipped=self._scene_skipped,
            clients=clients,
            subscriptions=subs,
            dropped_by_topic=by_topic,
        )

    def counters(self) -> dict[str, int]:
        """``stats().counters()``."""
        return self.stats().counters()

    # ------------------------------------------------------------------ updates
    def tick(self, final: bool = False, batches: Iterable[Batch] | None = None) -> None:
        """One update: send what was offered (decimated), greet new subscribers, the scene
        (forced when ``final``). Never raises (a bug is reported). What was offered: the
        batches of :meth:`log_many` since the last update, or ``batches`` when given:
        ``(topic, payloads, log_time_ns)`` (the view's process hands it what it read from
        shared memory)."""
        try:
            self._drain(self._take() if batches is None else self._offer(batches))
            self._replay_latched()
            self._scene_tick(time.monotonic(), force=final)
        except Exception as exc:  # a bug: reported, the loop goes on
            self._report(exc)

    def _take(self) -> list[Batch]:
        """The batches :meth:`log_many` kept, taken."""
        with self._lock:
            batches, self._batches = self._batches, []
        return batches

    def _offer(self, batches: Iterable[Batch]) -> list[Batch]:
        """``batches`` counted as offered, the latched topics' newest kept."""
        out = [b for b in batches if b[1] and b[0] in self._topics]
        for topic, payloads, t_ns in out:
            if topic in LATCHED_TOPICS:
                self._latest[topic] = (payloads[-1], t_ns)
        with self._lock:
            self._offered += sum(len(b[1]) for b in out)
        return out

    def _drain(self, batches: Sequence[Batch]) -> None:
        if not batches:
            return
        keep = self._decimation(batches)
        index: dict[str, int] = dict.fromkeys(keep, 0)  # running index per decimated topic
        for topic, payloads, t_ns in batches:
            channel = self._channels[topic]
            live = channel.has_sinks()
            scene = topic == CORRECTED and self._scene_channel.has_sinks()
            if not live and not scene:
                self._unsent += len(payloads)
                continue
            if type(t_ns) is not int or not 0 <= t_ns <= _TIME_NS_MAX:
                self._errors += len(payloads)
                self._report(
                    ValueError(f"live view: {topic}: log time {t_ns!r:.40} is not integer ns")
                )
                continue
            chosen = keep.get(topic)
            for payload in payloads:
                send = live
                if chosen is not None:
                    send = live and index[topic] in chosen
                    index[topic] += 1
                    if live and not send:
                        self._decimated += 1
                        if not scene:
                            continue
                self._one(topic, channel, payload, t_ns, send, scene, counted=live)

    def _decimation(self, batches: Sequence[Batch]) -> dict[str, set[int]]:
        """Per decimated topic with more messages than an update takes: the indices (over
        this update's messages of the topic, oldest first) to send."""
        per_topic: dict[str, list[Any]] = {}
        for topic, payloads, _ in batches:
            per_topic.setdefault(topic, []).extend(payloads)
        out: dict[str, set[int]] = {}
        for topic, payloads in per_topic.items():
            chosen = kept(topic, payloads, self.settings.max_per_update)
            if chosen is not None:
                out[topic] = chosen
        return out

    def _one(
        self,
        topic: str,
        channel: Any,
        payload: Any,
        t_ns: int,
        live: bool,
        scene: bool,
        counted: bool = False,
    ) -> None:
        """Send one message (``live``: its channel has a subscriber and it was not decimated)
        and/or add it to the scene. ``counted``: its fate is already counted (decimated)."""
        try:
            obj = message_struct(topic, payload, t_ns)
            if live:
                data, nulled = struct_json(topic, obj, nonfinite_as_null=True)
                channel.log(data, log_time=t_ns)
                self._nulled += nulled
                self._sent += 1
            elif not counted:
                self._unsent += 1
        except Exception as exc:  # malformed record, not JSON: counted, never fatal
            if not live:  # only the scene wanted it: nothing to draw
                self._scene_skipped += 1
                return
            self._errors += 1
            self._report(ValueError(f"live view: {topic} message not sent: {exc}"))
            return
        if scene:
            self._add_to_scene(obj, t_ns)

    def _add_to_scene(self, obj: Any, t_ns: int) -> None:
        point = self._scene_mod.point_from_corrected(obj, t_ns)
        if point is None:
            self._scene_skipped += 1
            return
        self._pending.append(point)
        if len(self._pending) > _PENDING_MAX:
            cut = len(self._pending) - _PENDING_MAX // 2
            del self._pending[:cut]
            self._scene_decimated += cut

    def _replay_latched(self) -> None:
        if not self._replay:
            return
        with self._sub_lock:
            topics, self._replay = self._replay, set()
        for topic in topics:
            latest = self._latest.get(topic)
            if latest is None:
                continue
            payload, t_ns = latest
            try:
                obj = message_struct(topic, payload, t_ns)
                data, _ = struct_json(topic, obj, nonfinite_as_null=True)
                self._channels[topic].log(data, log_time=t_ns)
                self._replayed += 1
            except Exception as exc:
                self._report(ValueError(f"live view: {topic} latched message not sent: {exc}"))

    def _scene_tick(self, now: float, force: bool = False) -> None:
        if not self._pending:
            return
        if not force and now - self._last_scene < 1.0 / self.settings.scene_rate_hz:
            return
        self._last_scene = now
        pending, self._pending = self._pending, []
        if not self._scene_channel.has_sinks():
            return
        s = self.settings
        picked = [
            pending[i] for i in self._scene_mod.pick_evenly(len(pending), s.scene_max_new_arrows)
        ]
        self._scene_decimated += len(pending) - len(picked)
        update = self._scene_mod.scene_update(
            picked, self._next_slot, s.scene_keep_arrows, s.arrow_mm_per_um
        )
        self._next_slot = (self._next_slot + len(picked)) % s.scene_keep_arrows
        self._scene_channel.log(update, log_time=picked[-1].t_ns)
        self._scene_updates += 1
        self._scene_points += len(picked)
