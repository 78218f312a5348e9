"""Simulated CMM controller over Modbus TCP (the daemon is the server).

Per reading: one FC16 write of the READING block (100..119, SEQ last: commits it), then reads
of ANSWER+DAEMON (300..323) until the answer carries that seq, via the reference client
:class:`protocol.ControllerClient`. Temperatures are written into their slots (one request per
sensor, counter incremented each time). Latency = write start to matching answer read, µs.
Synchronous facade over asyncio: :meth:`ModbusController.run` runs a whole program.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence

from cmm_comp.protocol import AnswerTimeoutError, ControllerClient, ReadingBlock, TemperatureSlot
from cmm_comp.protocol.codes import Status

from .controller import AnswerRecord, RawReading


class ModbusController:
    """Exchange readings with a daemon's Modbus server at ``host:port``.

    :param temperatures: called before each reading with the reading index; returns the
        samples to write now (sensor id → °C), or an empty dict.
    """

    def __init__(
        self,
        host: str,
        port: int,
        device_id: int = 1,
        timeout_s: float = 1.0,
    ) -> None:
        self.host, self.port, self.device_id, self.timeout_s = host, port, device_id, timeout_s
        self._counters: dict[int, int] = {}

    async def _write_temps(self, client: ControllerClient, temps: dict[int, float]) -> None:
        for sensor, temp_C in temps.items():
            counter = (self._counters.get(sensor, 0) + 1) & 0xFFFF
            self._counters[sensor] = counter
            slot = TemperatureSlot(sensor, round(temp_C * 1000), True, counter)
            await client.write_temperature(slot)

    async def run_async(
        self,
        readings: Sequence[RawReading],
        temperatures: Callable[[int], dict[int, float]] | None = None,
    ) -> list[AnswerRecord]:
        """Exchange every reading in turn; return the answers in order."""
        out: list[AnswerRecord] = []
        async with ControllerClient(
            self.host, self.port, self.device_id, timeout_s=self.timeout_s
        ) as client:
            await client.check_server()
            for i, r in enumerate(readings):
                if temperatures is not None and (temps := temperatures(i)):
                    await self._write_temps(client, temps)
                block = ReadingBlock.from_mm(
                    r.seq, r.indicated_mm, r.travel_dir, r.probe_dir, r.valid
                )
                t0 = time.perf_counter()
                try:
                    ans = await client.exchange(block, self.timeout_s)
                except AnswerTimeoutError:
                    out.append(AnswerRecord(r.seq, "timeout", None, float("nan")))
                    continue
                lat = (time.perf_counter() - t0) * 1e6
                out.append(
                    AnswerRecord(
                        r.seq,
                        Status(ans.status).label,
                        ans.position_mm,
                        lat,
                        ans.latency_us,
                        ans.correction_10nm / 100,
                        int(ans.applied),
                    )
                )
        return out

    def run(
        self,
        readings: Sequence[RawReading],
        temperatures: Callable[[int], dict[int, float]] | None = None,
    ) -> list[AnswerRecord]:
        """Synchronous :meth:`run_async` (own event loop)."""
        return asyncio.run(self.run_async(readings, temperatures))
