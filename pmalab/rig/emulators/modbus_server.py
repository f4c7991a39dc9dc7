"""A Modbus analog I/O module emulated with pymodbus 3.16's ``SimDevice`` API.

The register map comes from the rig file: every input channel's and analog output's
registers exist (shared block: FC3 and FC4 read the same registers, as on a LabJack T7);
every other address answers ILLEGAL DATA ADDRESS, so a wrong register map in a rig file is
caught as on a real device.  The emulator answers malformed requests as a device does:

* FC3/FC4 with 0 or more than 125 registers → exception 03 (ILLEGAL DATA VALUE) with the
  request's function code | 0x80 (``StrictReadHolding``/``StrictReadInput``; pymodbus itself
  would answer function 0x80, exception 01);
* FC6/FC16 to an input (read-only) register, to part of a multi-register output (half a
  FLOAT32) or starting inside one (misaligned) → exception 02;
* an output value that is not finite or outside the output's electrical range (e.g. a
  0–5 V DAC) → exception 03, and nothing is written;
* FC1/FC2/FC5/FC15: the module has no bit-addressed data → exception 02;
* Modbus RTU answers only the rig file's ``device_id`` (other units' frames are ignored, as
  on a shared RS-485 line); Modbus TCP answers any unit id, as a T7 does.

A fault inside the callback becomes exception 04 with one log line, never a traceback.

The ``SimDevice`` action callback (an ``async`` function pymodbus calls on every register
access, before it answers) does the physics:

* a read that touches the input registers advances the simulated rig to *now*, takes one
  sample, converts each channel to its raw electrical value with the inverse of the rig
  file's calibration and writes the encoded registers in place — pymodbus then answers
  with them;
* a write to an analog output decodes the new register words, inverts the output
  calibration (volts → MPa) and commands the simulated regulator.

Faults (:class:`~.faults.FaultPlan`): ``exception`` and ``out_of_range`` in the action
callback; ``drop``, ``garble``, ``delay`` and ``disconnect`` on the outgoing bytes through
the server's ``trace_packet`` hook.

The server runs on its own thread with its own asyncio loop (:class:`ModbusEmulator`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.register_message import ReadHoldingRegistersRequest
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.simulator.simcore import SimCore

from pmalab.rig.drivers.rigfile import ModbusRigSpec, OutputSpec
from pmalab.rig.emulators.faults import FaultPlan
from pmalab.rig.emulators.plant import EmulatedPlant

#: how far outside its range an ``out_of_range`` fault drives a channel (raw units)
OUT_OF_RANGE_RAW = 1e4
#: function codes of bit-addressed data (coils, discrete inputs), which the module lacks
BIT_FUNCTIONS = (1, 2, 5, 15)
#: slack on an output's electrical range (raw units): an integer register's scaled value
#: at the range's end must not be refused for round-off
RANGE_SLACK = 1e-9

log = logging.getLogger("pmalab.emulator")


class StrictReadHolding(ReadHoldingRegistersRequest):
    """FC3 whose register count is checked when answering, as a device does.

    pymodbus checks the count (1…125) while *decoding* and answers a bad one with function
    0x80 and exception 01; a device answers 0x83 with exception 03 (ILLEGAL DATA VALUE).
    """

    def decode(self, data: bytes) -> None:
        self.address, self.count = struct.unpack(">HH", data[:4])

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        if not 1 <= self.count <= self.MAX_COUNT:
            return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_VALUE)
        return await super().datastore_update(context, device_id)


class StrictReadInput(StrictReadHolding):
    """FC4, checked like :class:`StrictReadHolding`."""

    function_code = 4


STRICT_PDUS: list[type[ModbusPDU]] = [StrictReadHolding, StrictReadInput]


class SingleUnitCore(SimCore):
    """pymodbus's ``SimCore`` answering only its own unit ids.

    ``SimCore`` falls back to device 0 for an unknown id (and fails with a ``KeyError``
    when there is none); an RTU device on a shared line stays silent instead.  Raising
    ``NoSuchIdException`` lets a server with ``ignore_missing_devices`` send nothing.
    """

    def _known(self, device_id: int) -> None:
        if device_id not in self.devices:
            raise NoSuchIdException(f"no unit {device_id} on this line")

    async def async_getValues(self, device_id: int, *args: Any, **kwargs: Any) -> Any:
        self._known(device_id)
        return await super().async_getValues(device_id, *args, **kwargs)

    async def async_setValues(self, device_id: int, *args: Any, **kwargs: Any) -> Any:
        self._known(device_id)
        return await super().async_setValues(device_id, *args, **kwargs)


def register_runs(addresses: set[int]) -> list[tuple[int, int]]:
    """Contiguous (start, count) runs covering ``addresses``."""
    runs: list[tuple[int, int]] = []
    for a in sorted(addresses):
        if runs and runs[-1][0] + runs[-1][1] == a:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
        else:
            runs.append((a, 1))
    return runs


class StreamEngine:
    """The T7's stream mode in command-response, as :mod:`pmalab.rig.drivers.t7_stream` uses it.

    Configuration registers are stored as written; ``STREAM_ENABLE`` = 1 starts the device's
    scan clock at the written ``STREAM_SCANRATE_HZ``.  Each read of ``STREAM_DATA_CR`` first
    takes every scan due by now (the simulated rig sampled at t0 + k/rate, each AIN's volts
    as 16-bit codes) into a buffer of ``STREAM_BUFFER_SIZE_BYTES``; a scan that finds the
    buffer full is skipped (auto-recovery, status 2940) and, once there is room, a dummy scan
    of 0xFFFF codes marks the place and the read that returns it says 2941 with the number
    skipped.  ``faults.arm("stream_overflow")`` makes the next 25 scans skip as if the host
    had stalled.
    """

    CONFIG = (4002, 4024)
    SCANLIST = (4100, 4100 + 2 * 128)
    DATA = (4500, 4500 + 125)
    ENABLE = (4990, 4992)
    INJECTED_SKIP = 25

    def __init__(self, model: ModbusDeviceModel) -> None:
        self.model = model
        self.words: dict[int, int] = {}
        self.running = False
        self.buffer: list[tuple[str, Any]] = []  # ("scan", codes) | ("dummy", skipped)
        self.samples = 0  # samples held in the buffer
        self.skipping = 0  # scans skipped in the current recovery
        self.forced_skip = 0
        self.t0 = 0.0
        self.k = 0
        self.rate = 0.0
        self.addresses: list[int] = []
        self.capacity = 0  # samples

    def blocks(self) -> list[tuple[int, int, bool]]:
        return [
            (self.CONFIG[0], self.CONFIG[1] - self.CONFIG[0], False),
            (self.SCANLIST[0], self.SCANLIST[1] - self.SCANLIST[0], False),
            (self.ENABLE[0], self.ENABLE[1] - self.ENABLE[0], False),
            (self.DATA[0], self.DATA[1] - self.DATA[0], True),
        ]

    def owns(self, address: int) -> bool:
        return any(
            lo <= address < hi for lo, hi in (self.CONFIG, self.SCANLIST, self.DATA, self.ENABLE)
        )

    def _u32(self, a: int) -> int:
        return (self.words.get(a, 0) << 16) | self.words.get(a + 1, 0)

    def _f32(self, a: int) -> float:
        return struct.unpack(
            ">f", struct.pack(">HH", self.words.get(a, 0), self.words.get(a + 1, 0))
        )[0]

    def action(
        self, fc: int, base: int, address: int, count: int, registers: list[int], set_values: Any
    ) -> ExcCodes | None:
        """``registers`` is the device's register array starting at address ``base``."""
        if fc in (6, 16) and set_values:
            if self.DATA[0] <= address < self.DATA[1]:
                return ExcCodes.ILLEGAL_ADDRESS
            for i, v in enumerate(set_values):
                self.words[address + i] = int(v)
            if address <= self.ENABLE[0] < address + len(set_values) + 1:
                self._enable(self._u32(self.ENABLE[0]) == 1)
            return None
        if fc == 3 and address == self.DATA[0]:
            self._fill(registers, address - base, count)
            return None
        if fc in (3, 4) and self.DATA[0] < address < self.DATA[1]:
            return ExcCodes.ILLEGAL_ADDRESS
        return None

    def _enable(self, on: bool) -> None:
        from pmalab.rig.drivers.t7_stream import AUTO_TARGET_CR

        if not on:
            self.running = False
            return
        n = self._u32(4004)
        rate = self._f32(4002)
        if not (0 < n <= 128 and 0 < rate * n <= 100_000) or self._u32(4016) != AUTO_TARGET_CR:
            raise ValueError(
                f"stream: bad configuration (addresses {n}, rate {rate}, "
                f"auto target {self._u32(4016)})"
            )
        self.addresses = [self._u32(self.SCANLIST[0] + 2 * i) for i in range(n)]
        by_addr = {c.address: c for c in self.model.inputs}
        missing = [a for a in self.addresses if a not in by_addr]
        if missing:
            raise ValueError(f"stream: scanlist address(es) {missing} are not inputs")
        self.rate = rate
        self.capacity = max(self._u32(4012), 256) // 2
        self.t0 = self.model.plant.now()
        self.k = 0
        self.buffer, self.samples, self.skipping, self.running = [], 0, 0, True

    def _acquire(self) -> None:
        from pmalab.rig.drivers.t7_stream import volts_to_codes

        if not self.running:
            return
        plant = self.model.plant
        now = plant.now()
        chans = [next(c for c in self.model.inputs if c.address == a) for a in self.addresses]
        n = len(chans)
        if self.model.faults.take("stream_overflow"):
            self.forced_skip = self.INJECTED_SKIP
        while self.t0 + self.k / self.rate <= now:
            t = self.t0 + self.k / self.rate
            self.k += 1
            full = self.samples + 2 * n > self.capacity  # room for the scan and a marker
            if full or self.forced_skip > 0:
                self.forced_skip = max(self.forced_skip - 1, 0)
                self.skipping += 1
                continue
            if self.skipping:
                self.buffer.append(("dummy", self.skipping))
                self.samples += n
                self.skipping = 0
            with plant.lock:
                out = plant.physics.advance_and_sample(t)
            values = {
                "position": out[1],
                "force": out[2],
                "muscle_pressure": out[3],
                "cylinder_pressure": out[4],
            }
            volts = [c.calibration.inverse(float(values[c.name]), c.raw_range) for c in chans]
            self.buffer.append(("scan", volts_to_codes(np.array(volts)).tolist()))
            self.samples += n

    def _fill(self, registers: list[int], at: int, count: int) -> None:
        self._acquire()
        n = max(len(self.addresses), 1)
        room = (count - 4) // n
        out: list[int] = []
        status, info = (2940, 0) if self.skipping else (0, 0)
        taken = 0
        while taken < len(self.buffer) and len(out) // n < room:
            kind, val = self.buffer[taken]
            taken += 1
            if kind == "dummy":
                out += [0xFFFF] * n
                status, info = 2941, min(int(val), 0xFFFF)
                break  # one recovery per read: its count is in this header
            out += val
        del self.buffer[:taken]
        self.samples -= len(out)
        header = [len(out), min(2 * self.samples, 0xFFFF), status, info]
        words = header + out
        registers[at : at + len(words)] = words
        registers[at + len(words) : at + count] = [0] * (count - len(words))


class ModbusDeviceModel:
    """Register map + physics coupling of one emulated analog I/O module."""

    def __init__(
        self, spec: ModbusRigSpec, plant: EmulatedPlant, faults: FaultPlan | None = None
    ) -> None:
        self.spec = spec
        self.plant = plant
        self.faults = faults or FaultPlan()
        self.inputs = list(spec.channels)
        self.outputs: list[tuple[OutputSpec, Callable[[float], None]]] = []
        for name, o in spec.outputs.items():
            if o.type != "analog":
                continue
            cmd = plant.command_cylinder if name == "cylinder_regulator" else plant.command_muscle
            self.outputs.append((o, cmd))
        inputs: set[int] = set()
        for c in self.inputs:
            inputs.update(range(c.address, c.address + c.codec.width))
        outputs: set[int] = set()
        for o, _ in self.outputs:
            outputs.update(range(o.address, o.address + o.codec.width))
        #: (start, count, read-only) register runs: inputs are read-only, outputs writable
        self.blocks = [(a, n, True) for a, n in register_runs(inputs)] + [
            (a, n, False) for a, n in register_runs(outputs)
        ]
        self.runs = register_runs(inputs | outputs)
        #: the unit id answered: 0 = any (Modbus TCP, as a T7), else the rig file's (RTU)
        self.device_id = spec.transport.device_id if spec.transport.type == "rtu" else 0
        self.in_lo = min(c.address for c in self.inputs)
        self.in_hi = max(c.address + c.codec.width for c in self.inputs)
        self.reads = 0
        self.writes = 0
        self.last_request = time.perf_counter()
        self.outputs_live = False
        self.watchdog_trips = 0
        self.stream = StreamEngine(self)
        self.blocks += self.stream.blocks()

    def sim_device(self) -> SimDevice:
        """The pymodbus ``SimDevice``: inputs read-only, outputs writable; unit
        :attr:`device_id` (0 answers any unit id, as a T7 does)."""
        data = [
            SimData(address=a, count=n, values=0, datatype=DataType.REGISTERS, readonly=ro)
            for a, n, ro in sorted(self.blocks)
        ]
        return SimDevice(id=self.device_id, simdata=data, action=self.action)

    # ------------------------------------------------------------------ callback
    async def action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        self.last_request = time.perf_counter()
        if self.faults.take("exception"):
            return ExcCodes(self.faults.exception_code)
        try:
            if function_code in BIT_FUNCTIONS:
                return ExcCodes.ILLEGAL_ADDRESS
            if self.stream.owns(address):
                return self.stream.action(
                    function_code, start_address, address, count, registers, set_values
                )
            if function_code in (3, 4) and address < self.in_hi and address + count > self.in_lo:
                self.reads += 1
                self._fill_inputs(start_address, registers)
            elif function_code in (6, 16) and set_values:
                return self._apply_outputs(address, [int(v) for v in set_values])
        except Exception as exc:  # a device reports a fault, it does not print a traceback
            log.warning(
                "emulated module: function %d at %d: %s: %s",
                function_code,
                address,
                type(exc).__name__,
                exc,
            )
            return ExcCodes.DEVICE_FAILURE
        return None

    def _fill_inputs(self, start_address: int, registers: list[int]) -> None:
        s = self.plant.sample()
        bad = self.faults.take("out_of_range")
        for i, c in enumerate(self.inputs):
            # the sensor's electrical output for the simulated reading (inverse calibration);
            # integer registers saturate in encode() like a real ADC
            raw = c.calibration.inverse(s[c.name], c.raw_range)
            if bad and i == len(self.inputs) - 1:
                raw = OUT_OF_RANGE_RAW
            words = c.codec.encode(raw)
            k = c.address - start_address
            registers[k : k + len(words)] = words

    def _apply_outputs(self, address: int, values: list[int]) -> ExcCodes | None:
        """Check a write against the outputs it touches, then command them (all or none).

        Returns exception 02 for a write covering part of an output (half a FLOAT32) or
        starting inside one, 03 for a value that is not finite or outside the output's
        electrical range; None when every touched output took its new value.
        """
        end = address + len(values)
        commands: list[tuple[Callable[[float], None], float]] = []
        for o, command in self.outputs:
            lo, hi = o.address, o.address + o.codec.width
            if end <= lo or address >= hi:
                continue
            if address > lo or end < hi:  # misaligned or partial
                return ExcCodes.ILLEGAL_ADDRESS
            raw = o.codec.decode(values[lo - address : hi - address])
            if not (
                math.isfinite(raw)
                and o.raw_range[0] - RANGE_SLACK <= raw <= o.raw_range[1] + RANGE_SLACK
            ):
                return ExcCodes.ILLEGAL_VALUE
            assert o.calibration is not None
            mpa = o.calibration(raw)
            if not math.isfinite(mpa):
                return ExcCodes.ILLEGAL_VALUE
            commands.append((command, mpa))
        self.writes += 1
        for command, mpa in commands:
            command(mpa)
            self.outputs_live = True
        return None

    def watchdog(self, timeout_s: float, registers_zero: Callable[[], None]) -> bool:
        """Vent every output after ``timeout_s`` without a request (the T7's comm watchdog).

        A host that dies or loses the link mid-run cannot vent the regulator itself; the
        device's watchdog does.  Returns True when it tripped now.
        """
        if not self.outputs_live or time.perf_counter() - self.last_request < timeout_s:
            return False
        for _, command in self.outputs:
            command(0.0)
        registers_zero()
        self.outputs_live = False
        self.watchdog_trips += 1
        return True

    # ------------------------------------------------------------------ wire faults
    def make_trace_packet(
        self, framing: str, on_disconnect: Callable[[], None]
    ) -> Callable[[bool, bytes], bytes]:
        """pymodbus ``trace_packet`` hook: alter outgoing frames per the fault plan."""

        def trace(sending: bool, data: bytes) -> bytes:
            if not sending or not data:
                return data
            f = self.faults
            if f.take("delay"):
                time.sleep(f.delay_s)  # blocks the server loop: a device stuck in a long job
            if f.take("drop"):
                return b""
            if f.take("disconnect"):
                on_disconnect()
                return b""
            if f.take("garble"):
                b = bytearray(data)
                if framing == "rtu":
                    b[-1] ^= 0x5A  # CRC no longer matches
                else:
                    b[2] ^= 0x7F  # MBAP protocol id must be 0
                return bytes(b)
            return data

        return trace


class ModbusEmulator:
    """A pymodbus server (TCP or RTU) for one rig file, on a background thread."""

    def __init__(
        self,
        spec: ModbusRigSpec,
        plant: EmulatedPlant,
        faults: FaultPlan | None = None,
        *,
        host: str = "127.0.0.1",
        port: int | None = None,
        serial_port: str | None = None,
        baudrate: int | None = None,
        watchdog_s: float | None = None,
    ) -> None:
        self.model = ModbusDeviceModel(spec, plant, faults)
        #: s without a request after which the outputs vent (None: no watchdog)
        self.watchdog_s = watchdog_s
        self.framing = spec.transport.type
        self.host = host
        self.port = (
            int(port if port is not None else spec.transport.port) if self.framing == "tcp" else 0
        )
        self.serial_port = serial_port
        self.baudrate = baudrate or spec.transport.baudrate
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    @property
    def faults(self) -> FaultPlan:
        return self.model.faults

    @property
    def endpoint(self) -> str:
        if self.framing == "tcp":
            return f"tcp://{self.host}:{self.port}"
        return f"rtu://{self.serial_port}@{self.baudrate}"

    def _drop_connections(self) -> None:
        server = self._server
        if server is None or self._loop is None:
            return

        def close_all() -> None:
            for conn in list(server.active_connections.values()):
                if conn.transport is not None:
                    conn.transport.close()

        self._loop.call_soon(close_all)

    async def _main(self) -> None:
        trace = self.model.make_trace_packet(self.framing, self._drop_connections)
        device = self.model.sim_device()
        if self.framing == "tcp":
            self._server = ModbusTcpServer(
                device, address=(self.host, self.port), trace_packet=trace, custom_pdu=STRICT_PDUS
            )
        else:  # an RS-485 device ignores frames for other units
            if self.serial_port is None:  # reported by start()
                raise ValueError("an RTU emulator needs serial_port (the serial bridge's path)")
            self._server = ModbusSerialServer(
                device,
                port=self.serial_port,
                baudrate=self.baudrate,
                trace_packet=trace,
                custom_pdu=STRICT_PDUS,
                ignore_missing_devices=True,
            )
            self._server.context = SingleUnitCore(device)
        await self._server.serve_forever(background=True)
        self._ready.set()
        watch = asyncio.ensure_future(self._watch(self.watchdog_s)) if self.watchdog_s else None
        await self._server.serving
        if watch is not None:
            watch.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watch

    async def _watch(self, timeout_s: float) -> None:
        core = self._server.context  # SimCore: its runtime holds the register block

        def zero_output_registers() -> None:
            for runtime in core.devices.values():
                start, _, registers, _ = next(iter(runtime.block.values()))
                for o, _ in self.model.outputs:
                    assert o.calibration is not None
                    raw0 = min(
                        max(o.calibration.inverse(0.0, o.raw_range), o.raw_range[0]), o.raw_range[1]
                    )
                    words = o.codec.encode(raw0)
                    k = o.address - start
                    registers[k : k + len(words)] = words

        while not self._server.serving.done():
            await asyncio.sleep(min(0.05, timeout_s / 4))
            self.model.watchdog(timeout_s, zero_output_registers)

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._main())
        except BaseException as exc:  # reported by start()
            self._error = exc
            self._ready.set()
        finally:
            loop.close()

    def start(self, timeout: float = 5.0) -> ModbusEmulator:
        self._thread = threading.Thread(target=self._run, name="modbus-emulator", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError(f"Modbus emulator on {self.endpoint} did not start")
        if self._error is not None:
            raise RuntimeError(
                f"Modbus emulator on {self.endpoint}: {self._error}"
            ) from self._error
        return self

    def stop(self) -> None:
        if self._loop is not None and self._server is not None and self._loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            try:
                fut.result(timeout=2.0)
            except Exception:
                pass
        if self._thread is not None:
            self._thread.join(timeout=3.0)
            self._thread = None
