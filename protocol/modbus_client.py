"""Reference controller-side Modbus TCP client (async, pymodbus 3.16) for the register map.

    async with ControllerClient("127.0.0.1", port) as client:
        await client.write_temperature(TemperatureSlot(sensor=0, temp_mC=20_125, counter=1))
        answer = await client.exchange(ReadingBlock.from_mm(7, (100.0, 200.0, 50.0)))

A Modbus exception response raises :class:`ModbusExceptionError` carrying the code.
"""

from __future__ import annotations

import asyncio
import time
from types import TracebackType
from typing import Self

from pymodbus.client import AsyncModbusTcpClient

from cmm_comp.compensation.errors import CmmCompError

from . import modbus_map as mm
from .modbus_codec import AnswerBlock, DaemonBlock, ReadingBlock, TemperatureSlot, decode_output


class ModbusExceptionError(CmmCompError, RuntimeError):
    """The server answered a Modbus exception response."""

    def __init__(self, operation: str, code: int) -> None:
        super().__init__(f"{operation} failed: {mm.describe_exception(code)}")
        self.operation = operation
        self.code = code


class AnswerTimeoutError(CmmCompError, TimeoutError):
    """No answer with the expected seq arrived in time."""


class ControllerClient:
    """Write readings and temperatures, read answers; one TCP connection, one Modbus unit.

    ``timeout_s``: per-request timeout, s. ``retries``: pymodbus request retries.
    """

    def __init__(
        self,
        host: str,
        port: int = 502,
        device_id: int = 1,
        timeout_s: float = 1.0,
        retries: int = 0,
    ) -> None:
        self.device_id = device_id
        self._client = AsyncModbusTcpClient(
            host, port=port, timeout=timeout_s, retries=retries, reconnect_delay=0
        )

    async def connect(self) -> None:
        """Open the connection; ConnectionError if the server does not answer."""
        if not await self._client.connect():
            params = self._client.comm_params
            raise ConnectionError(f"cannot connect to Modbus server {params.host}:{params.port}")

    def close(self) -> None:
        """Close the connection (idempotent)."""
        self._client.close()

    async def __aenter__(self) -> Self:
        await self.connect()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    async def read_registers(self, address: int, count: int) -> list[int]:
        """FC3 read; raises ModbusExceptionError on an exception response."""
        rr = await self._client.read_holding_registers(
            address, count=count, device_id=self.device_id
        )
        if rr.isError():
            raise ModbusExceptionError(f"read {address}+{count}", rr.exception_code)
        return list(rr.registers)

    async def write_registers(self, address: int, values: list[int]) -> None:
        """FC16 write; raises ModbusExceptionError on an exception response."""
        rr = await self._client.write_registers(address, values, device_id=self.device_id)
        if rr.isError():
            raise ModbusExceptionError(f"write {address}+{len(values)}", rr.exception_code)

    async def check_server(self) -> None:
        """Read INFO and check the magic and the map version (at least this client's: versions
        only add registers); ValueError otherwise."""
        version, magic, _slots = await self.read_registers(mm.INFO_START, mm.INFO_SIZE)
        if magic != mm.MAGIC or version < mm.MAP_VERSION:
            raise ValueError(
                f"not a cmm-comp map v{mm.MAP_VERSION} or later: magic {magic:#06x}, "
                f"version {version}"
            )

    async def write_reading(self, reading: ReadingBlock) -> None:
        """Write and commit a reading: one FC16 request of 100..119 (SEQ last)."""
        await self.write_registers(mm.READING_START, reading.to_registers())

    async def write_temperature(self, slot: TemperatureSlot) -> None:
        """Write one temperature slot (4 registers, one request)."""
        await self.write_registers(slot.address, slot.to_registers())

    async def read_output(self) -> tuple[AnswerBlock, DaemonBlock]:
        """Read ANSWER, DAEMON and UNCERTAINTY (300..326) in one request."""
        return decode_output(await self.read_registers(mm.OUTPUT_START, mm.OUTPUT_SIZE))

    async def wait_answer(
        self, seq: int, timeout_s: float = 1.0, poll_s: float = 0.0005
    ) -> AnswerBlock:
        """Poll until the ANSWER block answers ``seq``; AnswerTimeoutError after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            answer, _ = await self.read_output()
            if answer.seq == seq:
                return answer
            if time.monotonic() > deadline:
                raise AnswerTimeoutError(
                    f"no answer for seq {seq} within {timeout_s} s (last answer: seq {answer.seq})"
                )
            await asyncio.sleep(poll_s)

    async def exchange(self, reading: ReadingBlock, timeout_s: float = 1.0) -> AnswerBlock:
        """Write ``reading`` and wait for its answer."""
        await self.write_reading(reading)
        return await self.wait_answer(reading.seq, timeout_s)
