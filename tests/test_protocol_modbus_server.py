"""Our MBAP server with the map on 127.0.0.1 (random free port), driven by pymodbus clients.

Everything runs in one asyncio.run per test; the server and clients are closed before it
returns, so no thread or socket outlives the test (conftest checks threads; filterwarnings=error
turns an unclosed-socket ResourceWarning into a failure).
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTcpClient

from cmm_comp.protocol import (
    AnswerBlock,
    AnswerTimeoutError,
    Applied,
    ControllerClient,
    DaemonBlock,
    DaemonState,
    MapDevice,
    MbapServer,
    ModbusExceptionError,
    ReadingBlock,
    Status,
    TemperatureSlot,
)
from cmm_comp.protocol import modbus_map as mm
from cmm_comp.protocol.modbus_codec import int_to_registers


class FakeDaemon:
    """Answers each commit with position + 1 µm per axis; records what it saw."""

    def __init__(self) -> None:
        self.commits: list[ReadingBlock] = []
        self.heartbeat = 0

    def on_commit(self, reading: ReadingBlock) -> AnswerBlock:
        self.commits.append(reading)
        x, y, z = reading.position_nm
        return AnswerBlock(
            reading.seq, Status.OK, (x + 1000, y + 1000, z + 1000), Applied.GEOMETRY, 42, 173
        )

    def daemon_block(self) -> DaemonBlock:
        self.heartbeat += 1
        return DaemonBlock(DaemonState.READY, len(self.commits), 0, 0xA1B2C3, self.heartbeat, 0)


Scenario = Callable[[int, FakeDaemon], Awaitable[None]]


def run_with_server(scenario: Scenario, device_id: int = 1) -> FakeDaemon:
    daemon = FakeDaemon()

    async def main() -> None:
        device = MapDevice(daemon.on_commit, daemon.daemon_block)
        server = MbapServer(device.handle_pdu, unit_ids={device_id})
        await server.start("127.0.0.1", 0)
        try:
            await asyncio.wait_for(scenario(server.port, daemon), timeout=10)
        finally:
            await server.close()

    asyncio.run(main())
    return daemon


def test_exchange_reading_and_answer() -> None:
    async def scenario(port: int, daemon: FakeDaemon) -> None:
        async with ControllerClient("127.0.0.1", port) as client:
            await client.check_server()
            await client.write_temperature(TemperatureSlot(3, 20_125, True, 1))
            reading = ReadingBlock.from_mm(7, (100.0, 200.0, -50.0), (1, -1, 0), (0, 0, -1.0))
            answer = await client.exchange(reading)
            assert answer == AnswerBlock(
                7, Status.OK, (100_001_000, 200_001_000, -49_999_000), Applied.GEOMETRY, 42, 173
            )
            assert answer.position_mm == pytest.approx((100.001, 200.001, -49.999))
            _, state = await client.read_output()
            assert (state.state, state.answered, state.grid_id) == (DaemonState.READY, 1, 0xA1B2C3)
            temps = await client.read_registers(mm.temperature_address(3), 4)
            assert TemperatureSlot.from_registers(3, temps) == TemperatureSlot(3, 20_125, True, 1)
        assert daemon.commits == [reading]

    run_with_server(scenario)


def test_commit_happens_only_when_seq_is_written() -> None:
    async def scenario(port: int, daemon: FakeDaemon) -> None:
        async with ControllerClient("127.0.0.1", port) as client:
            regs = ReadingBlock.from_mm(11, (1.0, 2.0, 3.0)).to_registers()
            await client.write_registers(mm.READING_START, regs[:-1])  # values, no SEQ
            assert daemon.commits == []
            await client.write_registers(mm.REG_SEQ, [11])  # now commit
            assert [c.seq for c in daemon.commits] == [11]
            assert daemon.commits[0].position_nm == (1_000_000, 2_000_000, 3_000_000)
            assert (await client.wait_answer(11)).seq == 11
            with pytest.raises(AnswerTimeoutError, match="no answer for seq 12"):
                await client.wait_answer(12, timeout_s=0.02)

    run_with_server(scenario)


def test_exception_responses_seen_by_an_independent_client() -> None:
    """Raw pymodbus client (not our wrapper) sees the standard exception codes."""

    async def scenario(port: int, daemon: FakeDaemon) -> None:
        raw = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=1, retries=0)
        try:
            assert await raw.connect()
            cases: list[tuple[str, Any, int]] = [
                ("gap", raw.read_holding_registers(50, count=1, device_id=1), 2),
                ("past UNCERTAINTY", raw.read_holding_registers(300, count=28, device_id=1), 2),
                ("write UNCERTAINTY", raw.write_registers(324, [1], device_id=1), 2),
                ("write ANSWER", raw.write_registers(300, [1], device_id=1), 2),
                ("write INFO", raw.write_register(0, 5, device_id=1), 2),
                ("direction 3", raw.write_register(mm.REG_DIR_X, 3, device_id=1), 3),
                ("reserved flag", raw.write_register(mm.REG_READING_FLAGS, 8, device_id=1), 3),
                ("coils", raw.read_coils(0, count=1, device_id=1), 1),
            ]
            for name, request, code in cases:
                rr = await request
                assert rr.isError(), name
                assert rr.exception_code == code, name
            ok = await raw.read_input_registers(mm.INFO_START, count=3, device_id=1)
            assert list(ok.registers) == [mm.MAP_VERSION, mm.MAGIC, mm.TEMPERATURE_SLOTS]
        finally:
            raw.close()
        assert daemon.commits == []  # the rejected writes committed nothing

    run_with_server(scenario)


def test_our_client_raises_with_the_code() -> None:
    async def scenario(port: int, daemon: FakeDaemon) -> None:
        async with ControllerClient("127.0.0.1", port) as client:
            with pytest.raises(ModbusExceptionError, match=r"ILLEGAL_DATA_ADDRESS \(2\)") as exc:
                await client.write_registers(mm.REG_STATUS, [0])
            assert exc.value.code == 2
            bad = [*int_to_registers(0, 4) * 3, 3, 0, 0, 0, 0, 0, 0, 1]  # direction X = 3
            with pytest.raises(ModbusExceptionError, match=r"ILLEGAL_DATA_VALUE \(3\)"):
                await client.write_registers(mm.READING_START, bad)
        assert daemon.commits == []

    run_with_server(scenario)


def test_connect_failure_is_a_connection_error() -> None:
    async def scenario() -> None:
        client = ControllerClient("127.0.0.1", 1, timeout_s=0.2)  # nothing listens on port 1
        try:
            with pytest.raises(ConnectionError, match="cannot connect to Modbus server"):
                await client.connect()
        finally:
            client.close()

    asyncio.run(scenario())


def test_answer_published_later_through_the_pull_hook() -> None:
    """A daemon that computes outside on_commit publishes through answer_block()."""
    queued: list[ReadingBlock] = []
    published: list[AnswerBlock] = []

    async def main() -> None:
        device = MapDevice(
            on_commit=lambda r: queued.append(r),  # returns None: answer comes later
            answer_block=lambda: published[-1] if published else None,
        )
        server = MbapServer(device.handle_pdu, unit_ids={1})
        await server.start("127.0.0.1", 0)
        port = server.port
        try:
            async with ControllerClient("127.0.0.1", port) as client:
                await client.write_reading(ReadingBlock.from_mm(3, (1.0, 1.0, 1.0)))
                first, _ = await client.read_output()
                assert (first.seq, first.status) == (0, Status.NOT_READY)  # not answered yet
                assert [r.seq for r in queued] == [3]
                published.append(AnswerBlock(3, Status.OUTSIDE_VOLUME, queued[0].position_nm))
                answer = await client.wait_answer(3)
                assert answer.status is Status.OUTSIDE_VOLUME
        finally:
            await server.close()

    asyncio.run(main())
