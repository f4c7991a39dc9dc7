"""A Modbus client link (TCP or RTU framing) with bounded retry, reconnect and fault counters.

Frames are built and PDUs decoded by pymodbus 3.16 (``FramerSocket``/``FramerRTU``,
``DecodePDU``, its CRC); the bytes travel through an :class:`~.adapters.Adapter`, so this
module controls every timeout and can count every fault, and the tests can check the exact
bytes on the wire.  One request is in flight at a time (Modbus is request/reply).

Fault handling, per request: a timeout, a closed connection, a corrupt frame (CRC, length,
header) or an exception reply is counted in :class:`LinkStats` and the request is retried up
to ``retries`` more times; a closed link or a corrupt TCP stream is re-opened first (after a
timeout or bad frame the byte stream may be out of step, so TCP reconnects and RTU flushes).
Past the bound a :class:`pmalab.errors.RigError` names the endpoint and the last fault.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

from pymodbus.framer import FramerRTU, FramerSocket
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadInputRegistersRequest,
    WriteMultipleRegistersRequest,
)

from pmalab.errors import RigError
from pmalab.rig.drivers.adapters import (
    Adapter,
    DeviceExceptionReply,
    FrameError,
    TransportClosed,
    TransportError,
    TransportTimeout,
    ValueOutOfRange,
)

#: Modbus exception codes (spec section 7) for readable messages
EXCEPTION_NAMES = {
    1: "ILLEGAL FUNCTION",
    2: "ILLEGAL DATA ADDRESS",
    3: "ILLEGAL DATA VALUE",
    4: "SERVER DEVICE FAILURE",
    5: "ACKNOWLEDGE",
    6: "SERVER DEVICE BUSY",
    10: "GATEWAY PATH UNAVAILABLE",
    11: "GATEWAY TARGET FAILED TO RESPOND",
}

FC_READ_HOLDING = 3
FC_READ_INPUT = 4
FC_WRITE_MULTIPLE = 16


@dataclass
class LinkStats:
    """Counters of one link's traffic and faults (recorded in the run's metadata)."""

    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    disconnects: int = 0
    reconnects: int = 0
    bad_frames: int = 0
    exception_replies: int = 0
    out_of_range: int = 0
    stale_replies: int = 0
    failures: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def summary(self) -> str:
        """The non-zero fault counters, e.g. ``"12 retries, 9 timeouts, 3 reconnects"``."""
        d = self.as_dict()
        parts = [f"{v} {k.replace('_', ' ')}" for k, v in d.items() if v and k != "requests"]
        return f"{d['requests']} requests" + (", " + ", ".join(parts) if parts else "")

    def count(self, exc: TransportError) -> None:
        """Count one fault by its kind."""
        if isinstance(exc, TransportTimeout):
            self.timeouts += 1
        elif isinstance(exc, TransportClosed):
            self.disconnects += 1
        elif isinstance(exc, FrameError):
            self.bad_frames += 1
        elif isinstance(exc, DeviceExceptionReply):
            self.exception_replies += 1
        elif isinstance(exc, ValueOutOfRange):
            self.out_of_range += 1


class RetriesExhausted(Exception):
    """Every attempt of :func:`exchange_with_retries` failed; ``last`` is the last fault."""

    def __init__(self, last: TransportError | None) -> None:
        super().__init__(one_line(last))
        self.last = last


def exchange_with_retries(
    adapter: Adapter,
    stats: LinkStats,
    retries: int,
    exchange: Callable[[], Any],
    *,
    recover: Callable[[TransportError], None],
    reconnect_delay: float = 0.0,
    record: Callable[[TransportError], None] | None = None,
) -> Any:
    """Run one request/reply ``exchange()`` with bounded retry and reconnect; its result.

    Every request counts in ``stats``; each failed attempt too (by kind).  A closed link
    (or an ``OSError`` while re-opening it) is closed and re-opened on the next attempt,
    after ``reconnect_delay`` s; any other transport fault is passed to ``recover`` (flush
    the input, or drop a TCP stream that may be out of step).  ``record`` sees every fault.
    After ``retries + 1`` failed attempts: :class:`RetriesExhausted`.
    """
    stats.requests += 1
    last: TransportError | None = None
    for attempt in range(retries + 1):
        if attempt:
            stats.retries += 1
        try:
            if not adapter.is_open:
                if attempt and reconnect_delay:
                    time.sleep(reconnect_delay)
                adapter.open()
                stats.reconnects += 1
            return exchange()
        except OSError as exc:  # refused/unreachable while reconnecting, or a broken port
            last = TransportClosed(f"{adapter.name}: {one_line(exc)}")
            stats.disconnects += 1
            adapter.close()
        except TransportError as exc:
            last = exc
            stats.count(exc)
            if isinstance(exc, TransportClosed):
                adapter.close()
            else:
                recover(exc)
        if record is not None:
            record(last)
    stats.failures += 1
    raise RetriesExhausted(last)


class ModbusLink:
    """Modbus client over an adapter: ``framing`` is ``"tcp"`` (MBAP) or ``"rtu"`` (CRC)."""

    def __init__(
        self,
        adapter: Adapter,
        framing: str = "tcp",
        device_id: int = 1,
        timeout: float = 0.1,
        retries: int = 3,
        reconnect_delay: float = 0.0,
    ) -> None:
        if framing not in ("tcp", "rtu"):
            raise ValueError(f"framing must be 'tcp' or 'rtu', not {framing!r}")
        self.adapter = adapter
        self.framing = framing
        self.device_id = int(device_id)
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.reconnect_delay = float(reconnect_delay)
        self.stats = LinkStats()
        decoder = DecodePDU(is_server=False)
        self._decoder = decoder
        self._framer = FramerSocket(decoder) if framing == "tcp" else FramerRTU(decoder)
        self._tid = 0
        #: the last fault met (any request), for diagnostics such as "wrong register map"
        self.last_error: TransportError | None = None

    @property
    def name(self) -> str:
        return f"{self.adapter.name} (Modbus {self.framing.upper()}, device {self.device_id})"

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Open the link; raise :class:`RigError` with one clear line when it cannot."""
        try:
            self.adapter.open()
        except (OSError, TransportError) as exc:
            raise RigError(f"{self.adapter.name}: cannot connect ({one_line(exc)})") from exc

    def close(self) -> None:
        self.adapter.close()

    # ------------------------------------------------------------------ public requests
    def read_registers(
        self,
        address: int,
        count: int,
        function: int = FC_READ_HOLDING,
        convert: Callable[[list[int]], Any] | None = None,
    ) -> Any:
        """Read ``count`` 16-bit registers from ``address`` with FC3 (holding) or FC4 (input).

        ``convert(registers)`` (optional) turns them into values and may raise
        :class:`ValueOutOfRange`, which is counted and retried like any other fault.
        """
        cls = (
            ReadHoldingRegistersRequest
            if function == FC_READ_HOLDING
            else ReadInputRegistersRequest
        )
        pdu = cls(address=address, count=count, dev_id=self.device_id)

        def check(data: bytes) -> Any:
            regs = self._check_read(data, function, count)
            return convert(regs) if convert is not None else regs

        return self._transact(pdu, check)

    def write_registers(self, address: int, values: list[int]) -> None:
        """Write registers with FC16 (write multiple registers)."""
        pdu = WriteMultipleRegistersRequest(
            address=address, count=len(values), registers=list(values), dev_id=self.device_id
        )
        self._transact(pdu, lambda data: self._check_write(data, address, len(values)))

    # ------------------------------------------------------------------ machinery
    def _transact(self, pdu: ModbusPDU, check: Callable[[bytes], Any]) -> Any:
        try:
            return exchange_with_retries(
                self.adapter,
                self.stats,
                self.retries,
                lambda: check(self._exchange(pdu)),
                recover=self._recover,
                reconnect_delay=self.reconnect_delay,
                record=self._record,
            )
        except RetriesExhausted as exc:
            raise RigError(
                f"{self.name}: request failed after {self.retries + 1} attempts "
                f"(last: {one_line(exc.last)}; link so far: {self.stats.summary()})"
            ) from None

    def _record(self, exc: TransportError) -> None:
        self.last_error = exc

    def _recover(self, exc: TransportError) -> None:
        if isinstance(exc, (TransportTimeout, FrameError)):
            if self.framing == "tcp":
                # the stream may be out of step: a late reply would be read as
                # the answer to the next request, so start a fresh connection
                self.adapter.close()
            else:
                self.adapter.discard_input()

    def _next_tid(self) -> int:
        self._tid = self._tid % 65535 + 1
        return self._tid

    def _exchange(self, pdu: ModbusPDU) -> bytes:
        """Send ``pdu`` and return the reply PDU bytes (function code first)."""
        pdu.transaction_id = self._next_tid() if self.framing == "tcp" else 0
        frame = self._framer.buildFrame(pdu)
        self.adapter.write(frame)
        if self.framing == "tcp":
            return self._receive_tcp(pdu.transaction_id)
        return self._receive_rtu(pdu.function_code)

    def _receive_tcp(self, tid: int) -> bytes:
        deadline = time.perf_counter() + self.timeout
        while True:
            header = self.adapter.read_exact(7, max(deadline - time.perf_counter(), 0.0))
            rtid, proto, length, unit = struct.unpack(">HHHB", header)
            if proto != 0 or not 2 <= length <= 254:
                raise FrameError(f"{self.adapter.name}: bad MBAP header {header.hex(' ')}")
            body = self.adapter.read_exact(length - 1, max(deadline - time.perf_counter(), 0.0))
            if rtid != tid:
                # a late answer to an earlier (timed-out) request: skip it
                self.stats.stale_replies += 1
                continue
            if unit != self.device_id:
                raise FrameError(
                    f"{self.adapter.name}: reply from unit {unit}, expected {self.device_id}"
                )
            return body

    def _receive_rtu(self, function: int) -> bytes:
        deadline = time.perf_counter() + self.timeout

        def left() -> float:
            return max(deadline - time.perf_counter(), 0.0)

        head = self.adapter.read_exact(2, left())
        if head[1] & 0x80:
            rest = self.adapter.read_exact(3, left())
        elif head[1] in (FC_READ_HOLDING, FC_READ_INPUT):
            n = self.adapter.read_exact(1, left())
            rest = n + self.adapter.read_exact(n[0] + 2, left())
        elif head[1] == FC_WRITE_MULTIPLE:
            rest = self.adapter.read_exact(6, left())
        else:
            raise FrameError(f"{self.adapter.name}: unexpected function code {head[1]:#04x}")
        frame = head + rest
        crc = int.from_bytes(frame[-2:], "big")
        if not FramerRTU.check_CRC(frame[:-2], crc):
            raise FrameError(f"{self.adapter.name}: CRC error in reply {frame.hex(' ')}")
        if head[0] != self.device_id:
            raise FrameError(
                f"{self.adapter.name}: reply from device {head[0]}, expected {self.device_id}"
            )
        return frame[1:-2]

    def _decode(self, data: bytes, function: int) -> ModbusPDU:
        if not data:
            raise FrameError(f"{self.adapter.name}: empty reply")
        if data[0] == function | 0x80:
            code = data[1] if len(data) > 1 else 0
            raise DeviceExceptionReply(
                f"{self.adapter.name}: exception reply {code} ({EXCEPTION_NAMES.get(code, '?')}) "
                f"to function {function}",
                code,
            )
        if data[0] != function:
            raise FrameError(f"{self.adapter.name}: reply function {data[0]}, expected {function}")
        try:
            reply = self._decoder.decode(data)
        except Exception as exc:  # pymodbus raises assorted errors on junk
            raise FrameError(f"{self.adapter.name}: undecodable reply {data.hex(' ')}") from exc
        if reply is None or isinstance(reply, ExceptionResponse):
            raise FrameError(f"{self.adapter.name}: undecodable reply {data.hex(' ')}")
        return reply

    def _check_read(self, data: bytes, function: int, count: int) -> list[int]:
        if (
            len(data) >= 2
            and data[0] == function
            and (data[1] != 2 * count or len(data) != 2 + 2 * count)
        ):
            raise FrameError(
                f"{self.adapter.name}: reply carries {len(data) - 2} bytes, expected {2 * count}"
            )
        return list(self._decode(data, function).registers)

    def _check_write(self, data: bytes, address: int, count: int) -> None:
        reply = self._decode(data, FC_WRITE_MULTIPLE)
        if reply.address != address or reply.count != count:
            raise FrameError(
                f"{self.adapter.name}: write echo {reply.address}/{reply.count} mismatch"
            )


def one_line(exc: BaseException | None) -> str:
    """The useful part of an exception's message, as one line."""
    if exc is None:
        return "unknown"
    text = str(exc) or type(exc).__name__
    return " ".join(text.split())
