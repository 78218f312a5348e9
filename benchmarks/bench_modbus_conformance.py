"""Why the Modbus server is our own: the documented cases sent to pymodbus's server and to ours.

Both servers run on 127.0.0.1 with the same register map (docs/modbus.md: 0..2 and 300..326
read-only, 100..119 and 200..263 read-write, nothing else defined); a raw socket sends each case
of tests/modbus_spec_cases.py (packed by hand with ``struct`` from the specs) and records what
comes back: a response PDU, nothing (the connection open), or the connection closed.

pymodbus 3.16.1 is set up as well as its server API allows: ``SimDevice`` for unit ids 1 and
255 (its id 0 means "every other unit id", so 0 cannot be served alone),
``ignore_missing_devices=True`` (its documented way of not answering other unit ids), read-only
``SimData`` where the map is read-only, and an ``action`` hook returning 03 for the map's value
rules (direction code > 2, reserved flag bits). Its server has no idle timeout and no frame
timeout setting; ours runs with ``idle_timeout_s=2``, ``frame_timeout_s=1``.

    python benchmarks/bench_modbus_conformance.py

prints the table (docs/modbus.md quotes it) and writes benchmarks/results/modbus_conformance.json.
"""

from __future__ import annotations

import asyncio
import json
import logging
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from modbus_spec_cases import (  # noqa: E402
    BAD_FRAMES,
    EXCEPTION_CASES,
    REG_DIR_X,
    REG_READING_FLAGS,
    ExceptionCase,
    frame,
    read_pdu,
)

IDLE_S = 2.0
"""Our server's idle timeout here; a connection still open after IDLE_S + GRACE_S was not
closed for being idle."""
FRAME_S = 1.0
GRACE_S = 2.0
SILENT_S = 1.0
"""No response within this long (on loopback, an idle server answers in well under 1 ms) counts
as no response."""
READ_ONLY = ((0, [2, 0x434D, 16]), (300, [0, 13] + [0] * 25))
READ_WRITE = ((100, 20), (200, 64))
READ_0 = b"\x03\x02\x00\x02"
"""FC3 response to reading register 0 (MAP_VERSION 2)."""


@dataclass(frozen=True)
class Outcome:
    kind: str
    """``response`` (with ``pdu``), ``silent`` (nothing within SILENT_S, connection open) or
    ``closed`` (the server closed the connection)."""
    pdu: bytes = b""

    def __str__(self) -> str:
        return f"{self.pdu.hex(' ', 1)}" if self.kind == "response" else self.kind


def _recv_exact(sock: socket.socket, n: int) -> bytes | None:
    out = b""
    while len(out) < n:
        chunk = sock.recv(n - len(out))
        if not chunk:
            return None
        out += chunk
    return out


def _outcome(sock: socket.socket, wait_s: float = SILENT_S) -> Outcome:
    """What the server does next: a response (its PDU), nothing within ``wait_s``, or EOF."""
    sock.settimeout(wait_s)
    try:
        head = _recv_exact(sock, 7)
    except TimeoutError:
        return Outcome("silent")
    except ConnectionResetError:
        return Outcome("closed")
    if head is None:
        return Outcome("closed")
    _tid, _pid, length, _unit = struct.unpack(">HHHB", head)
    sock.settimeout(5.0)
    body = _recv_exact(sock, length - 1)
    return Outcome("closed") if body is None else Outcome("response", body)


@contextmanager
def _connect(port: int) -> Iterator[socket.socket]:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    try:
        yield sock
    finally:
        sock.close()


def _request(port: int, pdu: bytes, unit: int = 1) -> Outcome:
    with _connect(port) as sock:
        sock.sendall(frame(pdu, tid=0x1234, unit=unit))
        return _outcome(sock)


@dataclass(frozen=True)
class Check:
    name: str
    expected: str
    run: Callable[[int], str]
    rule: str
    """``spec``, ``guide`` (the TCP Implementation Guide), ``map`` or ``ours`` (see _rule)."""


OUR_CHOICES = frozenset({1, 2, 5, 8, 15})
"""Function codes the map does not implement (no coils, no diagnostics): answering 01 is our
choice, a server with coils or diagnostics implements them."""


def _rule(case: ExceptionCase) -> str:
    """Who says what the answer must be: ``spec`` (the Application Protocol Specification's
    exception codes), ``map`` (a rule of our register map, given to pymodbus through its
    ``action`` hook), ``ours`` (our documented choice where the spec leaves room)."""
    if case.application:
        return "map"
    if case.pdu[0] in OUR_CHOICES or "one byte long" in case.what:
        return "ours"
    return "spec"


def _exception_checks() -> list[Check]:
    checks = []
    for case in EXCEPTION_CASES:

        def run(port: int, pdu: bytes = case.pdu) -> str:
            return str(_request(port, pdu))

        checks.append(Check(case.what, case.expected.hex(" ", 1), run, _rule(case)))
    return checks


def _unit_checks() -> list[Check]:
    def unit(n: int) -> Callable[[int], str]:
        return lambda port: str(_request(port, read_pdu(3, 0, 1), n))

    def unknown_then_known(port: int) -> str:
        with _connect(port) as sock:
            sock.sendall(frame(read_pdu(3, 0, 1), tid=1, unit=7))
            first = _outcome(sock)
            if first.kind == "closed":
                return "closed"
            sock.sendall(frame(read_pdu(3, 0, 1), tid=2, unit=1))
            return f"{first}; unit 1 then: {_outcome(sock)}"

    ok = Outcome("response", READ_0).__str__()
    return [
        Check("unit id 1 (the device)", ok, unit(1), "guide"),
        Check("unit id 255 (direct, recommended)", ok, unit(255), "guide"),
        Check("unit id 0 (direct, accepted)", ok, unit(0), "guide"),
        Check("unit id 7, then 1", f"silent; unit 1 then: {ok}", unknown_then_known, "guide"),
    ]


def _frame_checks() -> list[Check]:
    checks = []
    for garbage, reason in BAD_FRAMES:

        def run(port: int, garbage: bytes = garbage) -> str:
            with _connect(port) as sock:
                sock.sendall(garbage)
                first = _outcome(sock, FRAME_S + GRACE_S)
                if first.kind != "silent":
                    return str(first)
                sock.sendall(frame(read_pdu(3, 0, 1)))  # a valid request after it
                return f"open; a valid request then: {_outcome(sock)}"

        name = f"bad header: {reason} ({garbage[:7].hex()})"
        checks.append(Check(name, "closed", run, "ours"))

    def truncated(port: int) -> str:
        with _connect(port) as sock:
            sock.sendall(b"\x00\x01\x00")
            return str(_outcome(sock, FRAME_S + GRACE_S))

    def idle(port: int) -> str:
        with _connect(port) as sock:
            sock.sendall(frame(read_pdu(3, 0, 1)))
            if _outcome(sock).kind != "response":
                return "no answer to the first request"
            return str(_outcome(sock, IDLE_S + GRACE_S))

    def pipelined_one(port: int) -> str:
        return pipelined(port, split=False)

    def pipelined(port: int, split: bool = True) -> str:
        with _connect(port) as sock:
            burst = b"".join(frame(read_pdu(3, 0, 1), tid=t) for t in (0xBEEF, 7, 0xFFFF))
            if split:
                sock.sendall(burst[:5])
                time.sleep(0.05)
                sock.sendall(burst[5:])
            else:
                sock.sendall(burst)
            tids = []
            for _ in range(3):
                sock.settimeout(SILENT_S)
                try:
                    head = _recv_exact(sock, 7)
                except TimeoutError:
                    break
                if head is None:
                    break
                tid, _, length, _ = struct.unpack(">HHHB", head)
                _recv_exact(sock, length - 1)
                tids.append(tid)
            return "in order" if tids == [0xBEEF, 7, 0xFFFF] else f"tids {tids}"

    return [
        *checks,
        Check(f"3 header bytes, then silence ({FRAME_S:g} s)", "closed", truncated, "ours"),
        Check(f"idle connection ({IDLE_S:g} s)", "closed", idle, "ours"),
        Check("3 pipelined requests, header split", "in order", pipelined, "guide"),
        Check("3 pipelined requests, one segment", "in order", pipelined_one, "guide"),
    ]


CHECKS = [*_exception_checks(), *_unit_checks(), *_frame_checks()]


@contextmanager
def _in_thread(start: Callable[[], object], stop: Callable[[], object]) -> Iterator[None]:
    """Run the coroutine ``start()`` in a loop of its own thread; ``stop()`` ends it."""
    loop = asyncio.new_event_loop()
    ready = threading.Event()
    done: list[asyncio.Event] = []

    async def main() -> None:
        done.append(asyncio.Event())
        await start()  # type: ignore[misc]
        ready.set()
        try:
            await done[0].wait()
        finally:
            await stop()  # type: ignore[misc]

    thread = threading.Thread(target=loop.run_until_complete, args=(main(),), daemon=True)
    thread.start()
    try:
        if not ready.wait(10.0):
            raise RuntimeError("server did not start")
        yield
    finally:
        if done:
            loop.call_soon_threadsafe(done[0].set)
        thread.join(10.0)
        loop.close()


@contextmanager
def ours() -> Iterator[int]:
    from cmm_comp.protocol import DIRECT_UNIT_IDS, MapDevice, MbapServer

    server = MbapServer(MapDevice().handle_pdu, {1, *DIRECT_UNIT_IDS}, IDLE_S, FRAME_S)
    with _in_thread(lambda: server.start("127.0.0.1", 0), server.close):
        yield server.port


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def pymodbus_server() -> Iterator[int]:
    from pymodbus.constants import ExcCodes
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    async def map_rules(fc, start, address, count, registers, values):  # type: ignore[no-untyped-def]
        """The map's value rules (docs/modbus.md), as pymodbus's hook lets one add them."""
        for i, value in enumerate(values or []):
            reg = address + i
            if REG_DIR_X <= reg < REG_DIR_X + 3 and value > 2:
                return ExcCodes.ILLEGAL_VALUE
            if reg == REG_READING_FLAGS and value & ~0x7:
                return ExcCodes.ILLEGAL_VALUE
        return None

    def device(unit: int) -> SimDevice:
        data = [
            SimData(a, values=v, datatype=DataType.REGISTERS, readonly=True) for a, v in READ_ONLY
        ]
        data += [SimData(a, count=n, values=0, datatype=DataType.REGISTERS) for a, n in READ_WRITE]
        return SimDevice(unit, simdata=data, action=map_rules)

    port = _free_tcp_port()
    holder: list[ModbusTcpServer] = []

    async def start() -> None:
        server = ModbusTcpServer(
            [device(1), device(255)],
            address=("127.0.0.1", port),
            ignore_missing_devices=True,
        )
        holder.append(server)
        await server.serve_forever(background=True)

    async def stop() -> None:
        await holder[0].shutdown()

    with _in_thread(start, stop):
        yield port


def run() -> dict[str, object]:
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # its error lines for each case
    rows = []
    with ours() as our_port, pymodbus_server() as their_port:
        for check in CHECKS:
            rows.append(
                {
                    "rule": check.rule,
                    "case": check.name,
                    "expected": check.expected,
                    "ours": check.run(our_port),
                    "pymodbus": check.run(their_port),
                }
            )
    import pymodbus

    return {"pymodbus": pymodbus.__version__, "rows": rows}


def table(result: dict[str, object]) -> str:
    rows = result["rows"]
    assert isinstance(rows, list)
    lines = [
        f"| case | rule | expected | ours | pymodbus {result['pymodbus']} |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        mark = {k: ("" if r[k] == r["expected"] else " ✗") for k in ("ours", "pymodbus")}
        lines.append(
            f"| {r['case']} | {r['rule']} | {r['expected']} | {r['ours']}{mark['ours']} "
            f"| {r['pymodbus']}{mark['pymodbus']} |"
        )
    lines.append("")
    for rule in RULES:
        of_rule = [r for r in rows if r["rule"] == rule]
        wrong = {k: sum(r[k] != r["expected"] for r in of_rule) for k in ("ours", "pymodbus")}
        lines.append(
            f"{rule:5} {len(of_rule):2} cases: ours differs in {wrong['ours']}, "
            f"pymodbus in {wrong['pymodbus']}"
        )
    return "\n".join(lines)


RULES = ("spec", "guide", "map", "ours")


def main() -> int:
    result = run()
    print(table(result))
    out = ROOT / "benchmarks" / "results" / "modbus_conformance.json"
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out.relative_to(ROOT)}")
    rows = result["rows"]
    assert isinstance(rows, list)
    return 1 if any(r["ours"] != r["expected"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
