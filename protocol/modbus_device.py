"""The register map as a pymodbus 3.16 ``SimDevice``: a reference server-side binding.

:func:`build_sim_device` lays out the map (INFO preset, READING/TEMPERATURE writable, ANSWER/
DAEMON read-only, everything else undefined) and validates every request with
:func:`protocol.modbus_map.check_request` / :func:`check_write`, answering the standard
exception codes. On a commit (a write including SEQ) it calls ``on_commit(reading)``; a returned
:class:`AnswerBlock` is stored at once, so the controller's next read sees it. Answers computed
elsewhere are pulled from ``answer_block()`` and the DAEMON block from ``daemon_block()`` on
every read that touches them. The daemon engineer may
use this directly with ``pymodbus.server.ModbusTcpServer(build_sim_device(...), address=…)``.

Hooks run inside the server's event loop: keep them short (or hand off and return None).
"""

from __future__ import annotations

from collections.abc import Callable

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from . import modbus_map as mm
from .codes import Status
from .modbus_codec import AnswerBlock, DaemonBlock, ReadingBlock, info_registers

INITIAL_ANSWER = AnswerBlock(0, Status.NOT_READY, (0, 0, 0))
"""ANSWER block before the first answer: an all-zero block would read as "seq 0, ok"."""

CommitHook = Callable[[ReadingBlock], AnswerBlock | None]
DaemonHook = Callable[[], DaemonBlock]
AnswerHook = Callable[[], AnswerBlock | None]
InvalidCommitHook = Callable[[list[int], ValueError], None]


def _overlaps(address: int, count: int, start: int, size: int) -> bool:
    return address < start + size and address + count > start


def _simdata(block: mm.RegisterBlock, values: list[int] | None = None) -> SimData:
    return SimData(
        block.start,
        values=values if values is not None else [0] * block.size,
        datatype=DataType.REGISTERS,
        readonly=not block.writable,
    )


def build_sim_device(
    device_id: int = 1,
    on_commit: CommitHook | None = None,
    daemon_block: DaemonHook | None = None,
    on_invalid_commit: InvalidCommitHook | None = None,
    answer_block: AnswerHook | None = None,
) -> SimDevice:
    """A ``SimDevice`` implementing the cmm-comp register map for Modbus unit ``device_id``.

    ``on_commit(reading)``: called after a committing write has been validated, with the
    READING block as it will be after the write. ``daemon_block()``: current DAEMON block.
    ``on_invalid_commit(regs, error)``: a commit whose READING block does not decode.
    ``answer_block()``: latest answer (or None to keep the stored one), pulled on every read
    touching ANSWER; lets a daemon that computes outside the hook publish its answers.
    """
    blocks = {b.name: b for b in mm.BLOCKS}
    simdata = [
        _simdata(blocks["INFO"], info_registers()),
        _simdata(blocks["READING"]),
        _simdata(blocks["TEMPERATURE"]),
        _simdata(blocks["ANSWER"], INITIAL_ANSWER.to_registers()),
        _simdata(blocks["DAEMON"]),
    ]

    async def action(
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        if set_values is None:
            code = mm.check_request(function_code, address, count)
        else:
            code = mm.check_write(function_code, address, [int(v) for v in set_values])
        if code is not None:
            return ExcCodes(int(code))
        if set_values is not None and mm.commits_reading(function_code, address, count):
            _commit(start_address, address, registers, [int(v) for v in set_values])
        if set_values is None:
            _refresh(start_address, address, count, registers)
        return None

    def _refresh(start: int, address: int, count: int, registers: list[int]) -> None:
        """Pull ANSWER / DAEMON from the hooks when a read touches them."""
        if answer_block is not None and _overlaps(address, count, mm.ANSWER_START, mm.ANSWER_SIZE):
            answer = answer_block()
            if answer is not None:
                a = mm.ANSWER_START - start
                registers[a : a + mm.ANSWER_SIZE] = answer.to_registers()
        if daemon_block is not None and _overlaps(address, count, mm.DAEMON_START, mm.DAEMON_SIZE):
            d = mm.DAEMON_START - start
            registers[d : d + mm.DAEMON_SIZE] = daemon_block().to_registers()

    def _commit(start: int, address: int, registers: list[int], values: list[int]) -> None:
        base = mm.READING_START - start
        after = registers[base : base + mm.READING_SIZE]
        for i, value in enumerate(values):
            offset = address + i - mm.READING_START
            if 0 <= offset < mm.READING_SIZE:
                after[offset] = value
        try:
            reading = ReadingBlock.from_registers(after)
        except ValueError as exc:  # check_write makes this unreachable; kept as a guard
            if on_invalid_commit is not None:
                on_invalid_commit(after, exc)
            return
        if on_commit is not None and (answer := on_commit(reading)) is not None:
            a = mm.ANSWER_START - start
            registers[a : a + mm.ANSWER_SIZE] = answer.to_registers()

    return SimDevice(device_id, simdata=simdata, action=action)
