"""The daemon's Modbus TCP side: a pymodbus 3.16 server implementing protocol's register map.

The controller writes a reading into READING (100..119; the write that includes SEQ commits
it) and temperatures into TEMPERATURE slots (200..263); the commit is corrected inside the
request, so the ANSWER block (300..316) already holds the answer when the controller's next
read arrives. Request validation, exception codes and the register layout come from
:func:`protocol.build_sim_device`; this module adds temperature handling, the DAEMON block and
logging (scheduled after the response). The server runs its own asyncio loop in one thread,
bound to 127.0.0.1 unless configured otherwise; it is a context manager with ``stop(timeout_s)``.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Callable
from typing import Any

from pymodbus.pdu import ModbusPDU
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import SimDevice

from cmm_comp.protocol import (
    AnswerBlock,
    DaemonBlock,
    ReadingBlock,
    TemperatureSlot,
    build_sim_device,
)
from cmm_comp.protocol import modbus_map as mm

from .config import ModbusSection
from .engine import CorrectionEngine, Reading
from .events import EventLog
from .metrics import Metrics
from .osthread import name_os_thread
from .sessionlog.logger import SessionLogger


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
        self._ready = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self.error: BaseException | None = None
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
        server = ModbusTcpServer(
            self._device(),
            address=(self.config.host, self.config.port),
            trace_pdu=self._trace_pdu,
        )
        await server.serve_forever(background=True)
        try:
            sockets = getattr(server.transport, "sockets", None) or []
            if sockets:
                self.host, self.port = sockets[0].getsockname()[:2]
            self.events.emit("modbus_listening", host=self.host, port=self.port)
            self._ready.set()
            await self._stop_event.wait()
        finally:
            await server.shutdown()
            for conn in list(getattr(server, "active_connections", {}).values()):
                conn.close()
            await asyncio.sleep(0)

    # ------------------------------------------------------------------ device
    def _device(self) -> SimDevice:
        base = build_sim_device(
            self.config.device_id,
            on_commit=self._on_commit,
            daemon_block=self._block,
            on_invalid_commit=self._on_invalid_commit,
        )
        inner = base.action
        assert inner is not None

        async def action(
            function_code: int,
            start_address: int,
            address: int,
            count: int,
            registers: list[int],
            set_values: list[int] | list[bool] | None,
        ) -> Any:
            result = await inner(
                function_code, start_address, address, count, registers, set_values
            )
            if result is None and set_values is not None:
                self._temperatures(start_address, address, registers, [int(v) for v in set_values])
            if self.logger is not None:
                self.logger.log(
                    "/cmm/modbus",
                    {
                        "op": "read" if set_values is None else "write",
                        "function_code": function_code,
                        "device_id": self.config.device_id,
                        "address": address,
                        "count": count,
                        "values": [] if set_values is None else [int(v) for v in set_values],
                        "ok": result is None,
                        "error": "" if result is None else str(result),
                    },
                )
            return result

        return SimDevice(base.id, simdata=base.simdata, action=action)

    def _trace_pdu(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU:
        """Count every exception response the server sends (bad address, value, function)."""
        if sending and pdu.isError():
            self._input_errors += 1
            self.metrics.fault("modbus_rejected_request")
            self.events.emit(
                "modbus_rejected_request",
                "warning",
                function_code=pdu.function_code & 0x7F,
                code=int(getattr(pdu, "exception_code", 0)),
            )
        return pdu

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
        )
        loop = self._loop
        if loop is not None:  # log after the response has gone out
            loop.call_soon(self.engine.record, reading, answer, latency_us)
        return out

    def _on_invalid_commit(self, regs: list[int], error: ValueError) -> None:
        self._input_errors += 1
        self.metrics.fault("modbus_invalid_commit")
        self.events.emit("modbus_invalid_commit", "warning", error=str(error))

    def _temperatures(
        self, start: int, address: int, registers: list[int], values: list[int]
    ) -> None:
        lo, hi = mm.TEMPERATURE_START, mm.TEMPERATURE_START + mm.TEMPERATURE_SIZE
        end = address + len(values)
        if end <= lo or address >= hi:
            return
        first = (max(address, lo) - lo) // mm.TEMPERATURE_SLOT_SIZE
        last = (min(end, hi) - 1 - lo) // mm.TEMPERATURE_SLOT_SIZE
        for sensor in range(first, last + 1):
            slot_addr = mm.temperature_address(sensor)
            regs = registers[slot_addr - start : slot_addr - start + mm.TEMPERATURE_SLOT_SIZE]
            for i in range(mm.TEMPERATURE_SLOT_SIZE):
                if address <= slot_addr + i < end:
                    regs[i] = values[slot_addr + i - address]
            slot = TemperatureSlot.from_registers(sensor, regs)
            self.engine.temperature(sensor, slot.temp_C, slot.counter, slot.valid, "modbus")
