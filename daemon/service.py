"""The compensation daemon: grid, temperatures, CAN and/or Modbus endpoints, logs, metrics.

    with DaemonService(config) as daemon:     # starts everything
        daemon.reload_grid()                  # what SIGHUP does
    # leaving the block stops endpoints, then flushes and closes the MCAP file

:meth:`DaemonService.run_forever` is the process main loop: SIGTERM/SIGINT stop cleanly
(MCAP finished), SIGHUP reloads the grid atomically (a bad or untrusted new grid is refused and
the old one stays active); the reload is prepared in its own thread (:class:`GridReloader`) and
ends with one reference swap, so answers keep flowing with the old grid meanwhile. Configuration and grids change only through files on the host; nothing on the
bus can change them. A missing or bad grid at start is not fatal: the daemon runs and every
answer says ``no_grid`` until a good grid is loaded.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from mcap.writer import CompressionType

from cmm_comp.protocol import DaemonBlock, Heartbeat
from cmm_comp.protocol.codes import DaemonState, grid_id_from_sha256

from .can_endpoint import BusFactory, CanEndpoint, open_bus
from .config import DaemonConfig
from .engine import CorrectionEngine
from .events import EventLog
from .grid_slot import (
    KERNEL_CACHE_OFF,
    GridLoadError,
    GridReloader,
    GridSlot,
    LoadedGrid,
    load_grid,
    stylus_note,
)
from .grid_trust import GridTrust
from .grid_worker import ProcessGridLoader
from .live import LiveDownError, LiveFanOut, LiveProcessSink, LiveStartError
from .memory import DAEMON_MMAP_THRESHOLD_BYTES, fix_mmap_threshold
from .metrics import Metrics, MetricsServer
from .modbus_server import ModbusEndpoint
from .osthread import name_os_thread
from .sessionlog import McapProcessLogger, SessionLogger
from .state import StateBoard
from .temperatures import TemperatureTable

_TICK_S = 0.1


SIGTERM_STOP_S = 12.0
"""Time a SIGTERM/SIGINT stop may take, s, most of it the session log finishing its file: a
loaded machine serves the log's writer last, and what it has not written when the time is up
is lost (counted). Below the shipped systemd unit's ``TimeoutStopSec=15``."""


class DaemonService:
    """All daemon parts wired together. Context manager; ``stop(timeout_s)``.

    :param events_stream: where the structured log lines go (stdout by default, None = off).
    :param bus_factory: opens the CAN bus (tests inject failing buses).
    :param grid_loader: reads, verifies and builds a grid (tests inject a slow one); by
        default the start-up load and ``reload_grid`` run :func:`.grid_slot.load_grid` in the
        calling thread and SIGHUP reloads run it in a worker process (:mod:`.grid_worker`).
    """

    def __init__(
        self,
        config: DaemonConfig,
        events_stream: TextIO | None = sys.stdout,
        bus_factory: BusFactory = open_bus,
        grid_loader: Callable[[str | Path, GridTrust | None], LoadedGrid] | None = None,
    ) -> None:
        self.config = config
        self.events = EventLog(
            events_stream, config.log.format, config.log.level, config.log.max_per_s
        )
        self.metrics = Metrics()
        self.logger: SessionLogger | None = None
        self.live: LiveProcessSink | None = None
        self.grids = GridSlot()
        self.grid_trust = GridTrust.from_section(config.grid)
        self._grid_loader = grid_loader or load_grid
        self._process_loader = ProcessGridLoader() if grid_loader is None else None
        self._reload_loader = grid_loader or self._process_loader or load_grid
        self.reloader = GridReloader(self._background_reload)
        self.temperatures = TemperatureTable(config.temperatures, config.sensor_roles())
        self.state = StateBoard(self._on_state_change, config.log.state_repeat_s)
        self.engine: CorrectionEngine | None = None
        self.can: CanEndpoint | None = None
        self.modbus: ModbusEndpoint | None = None
        self.metrics_server: MetricsServer | None = None
        self._bus_factory = bus_factory
        self.grid_problem: str | None = None
        """Why no grid is active (the last refusal, or no grid configured); None once one is."""
        self._stop = threading.Event()
        self._reload_requested = threading.Event()
        self._housekeeper: threading.Thread | None = None
        self._stopped = False

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> DaemonService:
        """Start all parts; on a failure to start, stops what was started and re-raises."""
        cfg = self.config
        try:
            if cfg.mcap.path:
                directory = not cfg.mcap.path.endswith(".mcap")
                self.logger = McapProcessLogger(
                    cfg.mcap.path,
                    roll_bytes=int(cfg.mcap.roll_mb * 1e6)
                    if directory and cfg.mcap.roll_mb
                    else None,
                    roll_s=cfg.mcap.roll_s if directory and cfg.mcap.roll_s else None,
                    flush_period_s=cfg.mcap.flush_s,
                    metadata={"config": cfg.source},
                    on_error=self._on_mcap_error,
                    compression=CompressionType[cfg.mcap.compression.upper()],
                )
                if cfg.mcap.path.endswith(".mcap"):
                    first = self.logger.files[0] if self.logger.files else None
                    if first is not None and first.name != Path(cfg.mcap.path).name:
                        # an existing file is never overwritten: the log went to a new name
                        self.events.emit(
                            "mcap_rotated", "warning", requested=cfg.mcap.path, path=str(first)
                        )
            live_error = self._start_live() if cfg.live.enabled else None
            self.engine = CorrectionEngine(
                cfg, self.grids, self.temperatures, self.metrics, self.events, self.logger
            )
            self.events.emit("starting", config=cfg.source)
            for note in cfg.notes:  # a removed key left in the file (config.REMOVED_KEYS)
                self.events.emit("config_note", "warning", detail=note)
            self._status_log(DaemonState.STARTING, "starting")
            self._report_kernel_cache()
            if live_error is not None:
                self._status_log(DaemonState.STARTING, f"live view off: {live_error}")
            if cfg.grid.path:
                self._load_grid(cfg.grid.path)
            else:
                self.grid_problem = "grid.path is empty"
            self.state.set_grid(self.grids.current is not None)
            if cfg.metrics.enabled:
                self.metrics_server = MetricsServer(
                    self._prometheus, cfg.metrics.host, cfg.metrics.port
                )
                self.events.emit("metrics_listening", url=self.metrics_server.url)
            if cfg.modbus.enabled:
                self.modbus = ModbusEndpoint(
                    cfg.modbus,
                    self.engine,
                    self.daemon_block,
                    self.metrics,
                    self.events,
                    self.logger,
                ).start()
            if cfg.can.enabled:
                self.can = CanEndpoint(
                    cfg.can,
                    self.engine,
                    self.state,
                    self.heartbeat,
                    self.metrics,
                    self.events,
                    self.logger,
                    self._bus_factory,
                ).start()
            self._housekeeper = threading.Thread(
                target=self._housekeeping, name="daemon-housekeep", daemon=True
            )
            self._housekeeper.start()
            self.reloader.start()
            self.state.set_phase(DaemonState.READY)
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Stop endpoints, the metrics server and housekeeping, then finish the MCAP file.

        Returns True when every part stopped within ``timeout_s`` (s) in total. Idempotent.
        """
        if self._stopped:
            return True
        self._stopped = True
        deadline = time.monotonic() + timeout_s
        self.state.set_phase(DaemonState.STOPPING)
        ok = True
        if self.can is not None:
            ok &= self.can.stop(max(0.1, deadline - time.monotonic()))
        if self.modbus is not None:
            ok &= self.modbus.stop(max(0.1, deadline - time.monotonic()))
        if self.metrics_server is not None:
            ok &= self.metrics_server.stop(max(0.1, deadline - time.monotonic()))
        self._stop.set()
        ok &= self.reloader.stop(max(0.1, deadline - time.monotonic()))
        if self._process_loader is not None:
            ok &= self._process_loader.stop(max(0.1, deadline - time.monotonic()))
        if self._housekeeper is not None:
            self._housekeeper.join(max(0.1, deadline - time.monotonic()))
            ok &= not self._housekeeper.is_alive()
        self._publish_counters()
        self.events.emit("stopped", answered=self.metrics.answered, not_ok=self.metrics.not_ok)
        if self.logger is not None:
            ok &= self.logger.stop(max(0.5, deadline - time.monotonic()))
        return ok

    def __enter__(self) -> DaemonService:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def prewarm_reload_worker(self, wait_s: float) -> bool:
        """Start the grid-reload worker and wait (at most ``wait_s``, s) until its imports are
        done: called before :meth:`start`, so they never run beside the first answers. True
        when it is ready (always True with an in-process loader)."""
        if self._process_loader is None:
            return True
        return self._process_loader.prewarm(wait_s)

    def run_forever(self) -> int:
        """Process main loop (main thread): signals drive stop and reload. Returns exit code.

        Being the process's loop, it also fixes glibc's mmap threshold
        (:func:`.memory.fix_mmap_threshold`): a reloaded grid's buffers are then given back
        to the OS with the grid instead of staying in the heap."""
        fix_mmap_threshold(DAEMON_MMAP_THRESHOLD_BYTES)

        def on_term(signum: int, frame: Any) -> None:
            self._stop.set()

        def on_hup(signum: int, frame: Any) -> None:
            self._reload_requested.set()

        signal.signal(signal.SIGTERM, on_term)
        signal.signal(signal.SIGINT, on_term)
        signal.signal(signal.SIGHUP, on_hup)
        if self._process_loader is not None:
            self._process_loader.prewarm()  # the first SIGHUP then finds it ready
        while not self._stop.wait(0.05):
            if self._reload_requested.is_set():
                self._reload_requested.clear()
                self.request_reload()
        self.stop(SIGTERM_STOP_S)
        return 0

    def _start_live(self) -> str | None:
        """Start the live view (docs/live.md) and put it beside the MCAP log; returns why it
        could not start (the daemon runs on without it), or None."""
        try:
            live = LiveProcessSink(self.config.live, on_error=self._on_live_error).start()
        except LiveStartError as exc:
            self.metrics.count("live_errors")
            self.events.emit("live_error", "error", error=str(exc))
            return str(exc)
        self.live = live
        self.logger = LiveFanOut(self.logger, live)
        self.events.emit("live_listening", url=live.url)
        return None

    def _on_live_error(self, exc: BaseException) -> None:
        self.metrics.count("live_errors")
        self.events.emit("live_error", "warning", error=str(exc))
        if isinstance(exc, LiveDownError):  # died, stalled, runs again: the daemon state stays
            self._status_log(self.state.state, str(exc))

    # ------------------------------------------------------------------ grid
    def _load_grid(
        self,
        path: str,
        loader: Callable[[str | Path, GridTrust | None], LoadedGrid] | None = None,
    ) -> bool:
        try:
            loaded = self.grids.reload(path, self.grid_trust, loader or self._grid_loader)
        except GridLoadError as exc:
            if self.grids.current is None:
                self.grid_problem = str(exc)
            self.metrics.fault("grid_refused")
            old = self.grids.current
            self.events.emit(
                "grid_refused",
                "error",
                error=str(exc),
                active=old.sha256 if old is not None else "",
            )
            self._status_log(self.state.state, f"grid refused: {exc}")
            return False
        self.grid_problem = None
        self.metrics.count("grid_loads")
        stylus = self.engine.stylus_mm(loaded) if self.engine is not None else None
        self.events.emit(
            "grid_loaded",
            path=loaded.path,
            sha256=loaded.sha256,
            machine=loaded.machine,
            signed_by=loaded.signed_by or "unsigned (allowed)",
            signals=list(loaded.temperature_roles + loaded.input_signals),
            stylus_mm=list(stylus) if stylus is not None else None,
        )
        note = stylus_note(self.config.grid.stylus_mm, loaded.probe_offset_mm, loaded.path)
        if note is not None:
            self.events.emit("stylus_differs", "warning", detail=note)
        if self.logger is not None:
            self.logger.log("/cmm/grid", loaded.identity())
        self._status_log(self.state.state, f"grid loaded: {loaded.path}")
        return True

    def _report_kernel_cache(self) -> None:
        """Say where the compiled grid kernels are cached, or loudly that they are not (each
        start then compiles them: :data:`.grid_slot.KERNEL_CACHE_OFF`)."""
        from cmm_comp.compensation.grid.kernels import kernels_cache_dir

        folder = kernels_cache_dir()
        if folder is None:
            self.events.emit("kernel_cache", "warning", cache=None, detail=KERNEL_CACHE_OFF)
        else:
            self.events.emit("kernel_cache", cache=folder)

    def request_reload(self) -> None:
        """Reload the configured grid in the reload thread (what SIGHUP does): returns at once;
        answers use the old grid until the new one is verified and built, then one swap."""
        self.reloader.request()

    def _background_reload(self) -> None:
        """One SIGHUP reload, in the reload thread, with the work in the loader process."""
        self._load_grid(self.config.grid.path, self._reload_loader)
        self.state.set_grid(self.grids.current is not None)

    def reload_grid(self, path: str | None = None) -> bool:
        """Reload the grid from ``path`` (default: the configured file) in the calling thread.
        On failure the old grid stays active and False is returned."""
        ok = self._load_grid(path or self.config.grid.path)
        self.state.set_grid(self.grids.current is not None)
        return ok

    # ------------------------------------------------------------------ status
    def _grid_sha(self) -> str:
        g = self.grids.current
        return g.sha256 if g is not None else ""

    def heartbeat(self) -> Heartbeat:
        """Current CAN heartbeat frame."""
        sha = self._grid_sha()
        return Heartbeat(
            self.state.state,
            self.metrics.answered & 0xFFFF,
            self.metrics.not_ok & 0xFFFF,
            grid_id_from_sha256(sha) if sha else 0,
        )

    def daemon_block(self) -> DaemonBlock:
        """Current Modbus DAEMON block (heartbeat and input-error fields filled by the server)."""
        hb = self.heartbeat()
        return DaemonBlock(hb.state, hb.answered, hb.not_ok, hb.grid_id)

    def _status_log(self, state: DaemonState, detail: str) -> None:
        if self.logger is not None:
            self.logger.log(
                "/cmm/status",
                {"state": state.label, "detail": detail, "grid_sha256": self._grid_sha()},
            )

    def _on_state_change(self, state: DaemonState, detail: str, repeats: int = 0) -> None:
        level = (
            "info"
            if state in (DaemonState.READY, DaemonState.STARTING, DaemonState.STOPPING)
            else "warning"
        )
        extra = {"repeats": repeats} if repeats else {}
        self.events.emit(
            "state", level, state=state.label, detail=detail, grid=self._grid_sha(), **extra
        )
        self._status_log(state, detail)

    def _on_mcap_error(self, exc: BaseException) -> None:
        self.metrics.fault("mcap_error")
        self.events.emit("mcap_error", "error", error=repr(exc))

    def _prometheus(self) -> str:
        extra = {
            f'cmm_comp_state{{state="{s.label}"}}': float(self.state.state == s)
            for s in DaemonState
        }
        if self.logger is not None:
            # exact per-topic drops and encode errors of the session log (docs/mcap.md)
            for k, v in self.logger.stats().counters().items():
                extra[f"cmm_comp_{k}"] = float(v)
        if self.live is not None:  # live_sent, live_dropped (exact), live_clients …
            for k, v in self.live.counters().items():
                extra[f"cmm_comp_{k}"] = float(v)
        return self.metrics.prometheus(extra)

    def _publish_counters(self) -> None:
        if self.logger is None:
            return
        snap = self.metrics.snapshot(reset_period=True)
        snap["period_s"] = self.config.metrics.period_s
        snap["counters"]["mcap_dropped"] = self.logger.stats().dropped
        if self.live is not None:
            snap["counters"].update(self.live.counters())
        self.logger.log("/cmm/counters", snap)

    def _housekeeping(self) -> None:
        name_os_thread()
        next_publish = time.monotonic() + self.config.metrics.period_s
        while not self._stop.wait(_TICK_S):
            try:
                self._check_conditions()
                if time.monotonic() >= next_publish:
                    next_publish += self.config.metrics.period_s
                    self._publish_counters()
            except Exception as exc:  # reported, and the loop goes on
                self.metrics.fault("housekeeping_error")
                self.events.emit("housekeeping_error", "error", error=repr(exc))

    def _check_conditions(self) -> None:
        loaded = self.grids.current
        if loaded is not None and self.engine is not None:
            required = self.engine.required_roles(loaded)
            verdict = self.temperatures.inputs(required, time.monotonic())
            self.state.set_condition(
                "temperatures", None if verdict.status is None else verdict.detail
            )
        if self.logger is not None and self.logger.error is not None:
            self.state.set_condition("mcap", f"session log failed: {self.logger.error!r}")
        if self.modbus is not None and self.modbus.error is not None:
            self.state.set_condition("fault:modbus", repr(self.modbus.error))
