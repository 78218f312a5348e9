"""The register map as a Modbus server device: request PDU in, response PDU out (no I/O).

:class:`MapDevice` holds the registers of :mod:`protocol.modbus_map` (INFO preset, READING/
TEMPERATURE writable, ANSWER/DAEMON read-only, everything else undefined) and answers each
request PDU exactly per the Modbus Application Protocol V1.1b3: the function-level checks of
:func:`protocol.modbus_pdu.parse_request` (01, 03), then the map's address and value checks
(02, 03), then the operation; a hook that raises gives 04 SERVER_DEVICE_FAILURE. FC43/MEI 14
answers the device identification (:mod:`protocol.modbus_devid`).

Hooks (all optional) run inside the request, so keep them short:

* ``on_commit(reading) -> AnswerBlock | None``: a validated write including SEQ; a returned
  answer is stored at once, so the controller's next read sees it.
* ``answer_block() -> AnswerBlock | None``: pulled on every read touching ANSWER or
  UNCERTAINTY (None keeps the stored answer): lets a daemon that computes elsewhere publish its
  answers. An answer is stored in ANSWER and UNCERTAINTY together, in one step.
* ``daemon_block() -> DaemonBlock``: pulled on every read touching DAEMON.
* ``on_temperature(slot)``: each temperature slot a validated write touched, as it is after it.
* ``identity() -> {object id: bytes}``: device identification objects, per request (None:
  FC43 is not implemented, exception 01).

:class:`protocol.MbapServer` serves a device over TCP.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import NamedTuple

from . import modbus_map as mm
from .codes import Status
from .modbus_codec import (
    AnswerBlock,
    DaemonBlock,
    ReadingBlock,
    TemperatureSlot,
    info_registers,
)
from .modbus_devid import device_id_response
from .modbus_pdu import (
    Request,
    exception_pdu,
    parse_request,
    read_response,
    write_multiple_response,
    write_single_response,
)

INITIAL_ANSWER = AnswerBlock(0, Status.NOT_READY, (0, 0, 0))
"""ANSWER block before the first answer: an all-zero block would read as "seq 0, ok" (U reads
unknown)."""

CommitHook = Callable[[ReadingBlock], AnswerBlock | None]
DaemonHook = Callable[[], DaemonBlock]
AnswerHook = Callable[[], AnswerBlock | None]
TemperatureHook = Callable[[TemperatureSlot], None]
IdentityHook = Callable[[], Mapping[int, bytes]]

_SIZE = mm.UNCERTAINTY_START + mm.UNCERTAINTY_SIZE
_TEMP_END = mm.TEMPERATURE_START + mm.TEMPERATURE_SIZE


class Handled(NamedTuple):
    """What :meth:`MapDevice.handle` did: the response PDU, the request (None if it did not
    parse), the exception code answered (None = success) and the hook error behind a 04."""

    response: bytes
    request: Request | None
    code: mm.ExceptionCode | None
    error: BaseException | None = None


def _overlaps(address: int, count: int, start: int, size: int) -> bool:
    return address < start + size and address + count > start


class MapDevice:
    """The cmm-comp register map answering Modbus request PDUs (see the module docstring)."""

    def __init__(
        self,
        on_commit: CommitHook | None = None,
        daemon_block: DaemonHook | None = None,
        answer_block: AnswerHook | None = None,
        on_temperature: TemperatureHook | None = None,
        identity: IdentityHook | None = None,
    ) -> None:
        self.on_commit = on_commit
        self.daemon_block = daemon_block
        self.answer_block = answer_block
        self.on_temperature = on_temperature
        self.identity = identity
        self.registers = [0] * _SIZE
        """Register contents, index = address (undefined addresses are never served)."""
        self.registers[mm.INFO_START : mm.INFO_START + mm.INFO_SIZE] = info_registers()
        self._store_answer(INITIAL_ANSWER)
        if daemon_block is not None:
            self._store(mm.DAEMON_START, daemon_block().to_registers())

    def _store(self, address: int, values: list[int]) -> None:
        self.registers[address : address + len(values)] = values

    def _store_answer(self, answer: AnswerBlock) -> None:
        """ANSWER and UNCERTAINTY of ``answer`` (one step: requests are handled one at a time)."""
        self._store(mm.ANSWER_START, answer.to_registers())
        self._store(mm.UNCERTAINTY_START, answer.uncertainty_registers())

    def handle_pdu(self, pdu: bytes) -> bytes:
        """Response PDU to ``pdu`` (the :class:`protocol.MbapServer` handler)."""
        return self.handle(pdu).response

    def handle(self, pdu: bytes) -> Handled:
        """Answer one request PDU (function code + data, 1..253 bytes)."""
        request = parse_request(pdu)
        if isinstance(request, mm.ExceptionCode):
            return Handled(exception_pdu(pdu[0], request), None, request)
        fc = request.function_code
        try:
            if fc == mm.FC_READ_DEVICE_ID:
                result = self._identify(request)
            elif request.values is None:
                result = self._read(request)
            else:
                result = self._write(request)
        except Exception as exc:  # a hook failed: the spec's SERVER DEVICE FAILURE
            code = mm.ExceptionCode.SERVER_DEVICE_FAILURE
            return Handled(exception_pdu(fc, code), request, code, exc)
        if isinstance(result, mm.ExceptionCode):
            return Handled(exception_pdu(fc, result), request, result)
        return Handled(result, request, None)

    def _read(self, request: Request) -> bytes | mm.ExceptionCode:
        address, count = request.address, request.count
        if code := mm.check_request(request.function_code, address, count):
            return code
        if self.answer_block is not None and (
            _overlaps(address, count, mm.ANSWER_START, mm.ANSWER_SIZE)
            or _overlaps(address, count, mm.UNCERTAINTY_START, mm.UNCERTAINTY_SIZE)
        ):
            answer = self.answer_block()
            if answer is not None:
                self._store_answer(answer)
        if self.daemon_block is not None and _overlaps(
            address, count, mm.DAEMON_START, mm.DAEMON_SIZE
        ):
            self._store(mm.DAEMON_START, self.daemon_block().to_registers())
        return read_response(request.function_code, self.registers[address : address + count])

    def _write(self, request: Request) -> bytes | mm.ExceptionCode:
        fc, address, values = request.function_code, request.address, list(request.values or ())
        if code := mm.check_write(fc, address, values):
            return code
        self._store(address, values)
        end = address + len(values)
        if self.on_temperature is not None and address < _TEMP_END and end > mm.TEMPERATURE_START:
            self._temperatures(address, end)
        if mm.commits_reading(fc, address, len(values)):
            self._commit()
        if fc == mm.FC_WRITE_SINGLE:
            return write_single_response(address, values[0])
        return write_multiple_response(address, len(values))

    def _commit(self) -> None:
        block = self.registers[mm.READING_START : mm.READING_START + mm.READING_SIZE]
        reading = ReadingBlock.from_registers(block)  # check_write made it decodable
        if self.on_commit is not None and (answer := self.on_commit(reading)) is not None:
            self._store_answer(answer)

    def _temperatures(self, address: int, end: int) -> None:
        assert self.on_temperature is not None
        size = mm.TEMPERATURE_SLOT_SIZE
        first = (max(address, mm.TEMPERATURE_START) - mm.TEMPERATURE_START) // size
        last = (min(end, _TEMP_END) - 1 - mm.TEMPERATURE_START) // size
        for sensor in range(first, last + 1):
            slot_address = mm.temperature_address(sensor)
            regs = self.registers[slot_address : slot_address + size]
            self.on_temperature(TemperatureSlot.from_registers(sensor, regs))

    def _identify(self, request: Request) -> bytes | mm.ExceptionCode:
        if self.identity is None:
            return mm.ExceptionCode.ILLEGAL_FUNCTION
        return device_id_response(self.identity(), request.address, request.count)
