"""The daemon's Modbus TCP side: protocol's register map served by protocol's MBAP server.

The controller writes a reading into READING (100..119; the write that includes SEQ commits
it) and temperatures into TEMPERATURE slots (200..263); the commit is corrected inside the
request, so the ANSWER block (300..316) and its uncertainty (324..326) already hold the answer
when the controller's next read arrives. Framing, exception codes, unit-id policy, idle and bad-frame handling come from
:class:`protocol.MbapServer` and :class:`protocol.MapDevice` (docs/modbus.md); this module
wires them to the engine, fills the DAEMON block and the device identification, counts what
goes wrong (metrics) and logs it (one line per kind per 10 s at most, with the number of
events folded into it). MCAP logging is scheduled after the response. The server runs its own
asyncio loop in one thread, bound to 127.0.0.1 unless configured otherwise; it is a context
manager with ``stop(timeout_s)``.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.metadata
import threading
import time
from collections.abc import Callable
from typing import Any

from cmm_comp.protocol import (
    DIRECT_UNIT_IDS,
    AnswerBlock,
    DaemonBlock,
    DeviceIdentity,
    Handled,
    MapDevice,
    MbapListener,
    MbapServer,
    ReadingBlock,
    TemperatureSlot,
)
from cmm_comp.protocol import modbus_map as mm
from cmm_comp.protocol.modbus_devid import OBJ_GRID_SHA256, object_value

from .config import ModbusSection
from .engine import CorrectionEngine, Reading
from .events import EventLog, Throttle
from .metrics import Metrics
from .osthread import name_os_thread
from .sessionlog.logger import SessionLogger

LOG_INTERVAL_S = 10.0
"""At most one log line per kind of Modbus trouble this often, s (the rest are counted)."""


def package_identity() -> DeviceIdentity:
    """Device identification objects of this package (version and URL from its metadata)."""
    try:
        meta = importlib.metadata.metadata("cmm-comp")
        version = meta["Version"] or "unknown"
        urls = [u.split(",", 1)[-1].strip() for u in meta.get_all("Project-URL") or []]
        url = ((meta.get_all("Home-page") or [""])[0] or (urls[0] if urls else "")).strip()
    except importlib.metadata.PackageNotFoundError:
        version, url = "unknown", ""
    return DeviceIdentity(
        vendor_name="cmm-comp project",
        product_code="cmm-comp",
        revision=version,
        vendor_url=url,
        product_name="cmm-comp volumetric compensation daemon",
        model_name=f"Modbus register map v{mm.MAP_VERSION}",
    )


class LogThrottle:
    """One event line per kind per ``interval_s``; lines carry how many were folded in."""

    def __init__(self, events: EventLog, interval_s: float = LOG_INTERVAL_S) -> None:
        self.events = events
        self._throttle = Throttle(interval_s)

    def emit(self, kind: str, level: str, **fields: Any) -> None:
        """Log ``kind`` now, or count it for the next line of that kind."""
        folded = self._throttle.passes(kind)
        if folded is not None:
            self.events.emit(kind, level, **fields, not_logged=folded)


class _Listener(MbapListener):
    """Counts and logs what the MBAP server saw besides well-formed requests."""

    def __init__(self, metrics: Metrics, throttle: LogThrottle, served: list[int]) -> None:
        self.metrics = metrics
        self.throttle = throttle
        self.served = served

    def on_connect(self, peer: str) -> None:
        self.metrics.count("modbus_connections")

    def on_bad_frame(self, peer: str, reason: str) -> None:
        self.metrics.fault("modbus_bad_frame")
        self.throttle.emit("modbus_bad_frame", "warning", peer=peer, reason=reason)

    def on_idle_close(self, peer: str) -> None:
        self.metrics.count("modbus_idle_closed")
        self.throttle.emit("modbus_idle_closed", "info", peer=peer)

    def on_wrong_unit(self, peer: str, unit_id: int) -> None:
        self.metrics.fault("modbus_wrong_unit")
        self.throttle.emit(
            "modbus_wrong_unit",
            "warning",
            peer=peer,
            unit_id=unit_id,
            served=self.served,
            action="no response",
        )

    def on_error(self, exc: BaseException) -> None:
        self.metrics.fault("modbus_handler_error")
        self.throttle.emit("modbus_handler_error", "error", error=repr(exc))


class ModbusEndpoint:
    """Serve the register map on ``host:port`` (port 0 = any free port, see ``.port``).

    :param daemon_block: builds the current DAEMON block (state, counters, grid id).
    """

    def __init__(
        self,
        config: ModbusSection,
        engine: CorrectionEngine,
        daemon_block: Callable[[], DaemonBlock],
        metrics: Metrics,
        events: EventLog,
        logger: SessionLogger | None = None,
    ) -> None:
        self.config = config
        self.engine = engine
        self._daemon_block = daemon_block
        self.metrics = metrics
        self.events = events
        self.logger = logger
        self.port: int = config.port
        self.host: str = config.host
        self._input_errors = 0
        self._throttle = LogThrottle(events)
        self._identity = package_identity().objects()
        self._ready = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self.error: BaseException | None = None
        self.device = MapDevice(
            on_commit=self._on_commit,
            daemon_block=self._block,
            on_temperature=self._on_temperature,
            identity=self._identity_objects,
        )
        self.served_unit_ids = sorted({config.device_id, *DIRECT_UNIT_IDS})
        self._thread = threading.Thread(target=self._run, name="modbus-server", daemon=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self, timeout_s: float = 5.0) -> ModbusEndpoint:
        """Start serving; raises RuntimeError if the server could not listen."""
        self._thread.start()
        if not self._ready.wait(timeout_s) or self.error is not None:
            self.stop()
            raise RuntimeError(
                f"Modbus server on {self.host}:{self.config.port} did not start: {self.error!r}"
            )
        return self

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Close the listener and connections; True if the thread ended within ``timeout_s``."""
        loop, ev = self._loop, self._stop_event
        if loop is not None and ev is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # loop already closed
                loop.call_soon_threadsafe(ev.set)
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def __enter__(self) -> ModbusEndpoint:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        name_os_thread()
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported, never silent
            self.error = exc
            self.metrics.fault("modbus_server_error")
            self.events.emit("modbus_server_error", "error", error=repr(exc))
        finally:
            self._ready.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop_event = asyncio.Event()
        server = MbapServer(
            self._handle,
            self.served_unit_ids,
            idle_timeout_s=self.config.idle_timeout_s,
            frame_timeout_s=self.config.frame_timeout_s,
            listener=_Listener(self.metrics, self._throttle, self.served_unit_ids),
        )
        await server.start(self.config.host, self.config.port)
        try:
            self.host, self.port = server.host, server.port
            self.events.emit(
                "modbus_listening", host=self.host, port=self.port, unit_ids=self.served_unit_ids
            )
            self._ready.set()
            await self._stop_event.wait()
        finally:
            await server.close()

    # ------------------------------------------------------------------ requests
    def _handle(self, pdu: bytes) -> bytes:
        handled = self.device.handle(pdu)
        if handled.code is not None:
            self._rejected(handled)
        if self.logger is not None and handled.request is not None:
            loop = self._loop
            if loop is not None:  # log after the response has gone out
                loop.call_soon(self._log, handled)
        return handled.response

    def _rejected(self, handled: Handled) -> None:
        """Count every exception response the server sends (bad function, address, value)."""
        assert handled.code is not None
        self._input_errors += 1
        fc = handled.response[0] & 0x7F
        self.metrics.fault("modbus_rejected_request")
        if handled.error is not None:
            self.metrics.fault("modbus_handler_error")
            self._throttle.emit("modbus_handler_error", "error", error=repr(handled.error))
        self._throttle.emit(
            "modbus_rejected_request",
            "warning",
            function_code=fc,
            code=int(handled.code),
            meaning=mm.describe_exception(handled.code),
        )

    def _log(self, handled: Handled) -> None:
        request = handled.request
        if self.logger is None or request is None or request.function_code == mm.FC_READ_DEVICE_ID:
            return
        values = request.values
        self.logger.log(
            "/cmm/modbus",
            {
                "op": "read" if values is None else "write",
                "function_code": request.function_code,
                "device_id": self.config.device_id,
                "address": request.address,
                "count": request.count,
                "values": [] if values is None else list(values),
                "ok": handled.code is None,
                "error": "" if handled.code is None else mm.describe_exception(handled.code),
            },
        )

    def _identity_objects(self) -> dict[int, bytes]:
        loaded = self.engine.grids.current
        sha = loaded.sha256 if loaded is not None else ""
        return {**self._identity, OBJ_GRID_SHA256: object_value(sha)}

    def _block(self) -> DaemonBlock:
        block = self._daemon_block()
        return DaemonBlock(
            block.state,
            block.answered,
            block.not_ok,
            block.grid_id,
            int(time.monotonic() * 10) & 0xFFFF,  # 10 Hz heartbeat: frozen = dead daemon
            self._input_errors & 0xFFFF,
        )

    def _on_commit(self, block: ReadingBlock) -> AnswerBlock:
        t0 = time.perf_counter()
        reading = Reading(
            seq=block.seq,
            position_nm=block.position_nm,
            directions=(
                block.directions[0].sign,
                block.directions[1].sign,
                block.directions[2].sign,
            ),
            valid=block.valid,
            probe=block.probe,
            received_s=t0,
            source="modbus",
        )
        self.metrics.count("frames_rx")
        answer = self.engine.correct(reading)
        latency_us = (time.perf_counter() - t0) * 1e6
        out = AnswerBlock.from_physical(
            answer.seq,
            answer.status,
            answer.position_nm,
            answer.applied,
            latency_us,
            answer.correction_norm_um,
            answer.uncertainty_um,  # registers 324..326: unknown unless known
        )
        loop = self._loop
        if loop is not None:  # log after the response has gone out
            loop.call_soon(self.engine.record, reading, answer, latency_us)
        return out

    def _on_temperature(self, slot: TemperatureSlot) -> None:
        self.engine.temperature(slot.sensor, slot.temp_C, slot.counter, slot.valid, "modbus")
