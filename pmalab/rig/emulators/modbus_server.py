"""A Modbus analog I/O module emulated with pymodbus 3.16's ``SimDevice`` API.

The register map comes from the rig file: every input channel's and analog output's
registers exist (shared block: FC3 and FC4 read the same registers, as on a LabJack T7);
every other address answers ILLEGAL DATA ADDRESS, so a wrong register map in a rig file is
caught as on a real device.

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
import threading
import time
from collections.abc import Callable
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from pmalab.rig.drivers.rigfile import ModbusRigSpec, OutputSpec
from pmalab.rig.emulators.faults import FaultPlan
from pmalab.rig.emulators.plant import EmulatedPlant

#: how far outside its range an ``out_of_range`` fault drives a channel (raw units)
OUT_OF_RANGE_RAW = 1e4


def register_runs(addresses: set[int]) -> list[tuple[int, int]]:
    """Contiguous (start, count) runs covering ``addresses``."""
    runs: list[tuple[int, int]] = []
    for a in sorted(addresses):
        if runs and runs[-1][0] + runs[-1][1] == a:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
        else:
            runs.append((a, 1))
    return runs


class ModbusDeviceModel:
    """Register map + physics coupling of one emulated analog I/O module."""

    def __init__(self, spec: ModbusRigSpec, plant: EmulatedPlant, faults: FaultPlan | None = None) -> None:
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
        addrs: set[int] = set()
        for c in self.inputs:
            addrs.update(range(c.address, c.address + c.codec.width))
        for o, _ in self.outputs:
            addrs.update(range(o.address, o.address + o.codec.width))
        self.runs = register_runs(addrs)
        self.in_lo = min(c.address for c in self.inputs)
        self.in_hi = max(c.address + c.codec.width for c in self.inputs)
        self.reads = 0
        self.writes = 0
        self.last_request = time.perf_counter()
        self.outputs_live = False
        self.watchdog_trips = 0

    def sim_device(self) -> SimDevice:
        """The pymodbus ``SimDevice`` (id 0 = answers any unit id, as a T7 does)."""
        data = [SimData(address=a, count=n, values=0, datatype=DataType.REGISTERS) for a, n in self.runs]
        return SimDevice(id=0, simdata=data, action=self.action)

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
        if function_code in (3, 4) and address < self.in_hi and address + count > self.in_lo:
            self.reads += 1
            self._fill_inputs(start_address, registers)
        elif function_code in (6, 16) and set_values:
            self.writes += 1
            self._apply_outputs(start_address, address, [int(v) for v in set_values], registers)
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

    def _apply_outputs(self, start_address: int, address: int, values: list[int], registers: list[int]) -> None:
        for o, command in self.outputs:
            width = o.codec.width
            if address + len(values) <= o.address or address >= o.address + width:
                continue
            words = []
            for a in range(o.address, o.address + width):
                j = a - address
                words.append(values[j] if 0 <= j < len(values) else registers[a - start_address])
            raw = o.codec.decode(words)
            raw = min(max(raw, o.raw_range[0]), o.raw_range[1])
            assert o.calibration is not None
            command(o.calibration(raw))
            self.outputs_live = True

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
    def make_trace_packet(self, framing: str, on_disconnect: Callable[[], None]) -> Callable[[bool, bytes], bytes]:
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
        self.port = int(port if port is not None else spec.transport.port) if self.framing == "tcp" else 0
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
            self._server = ModbusTcpServer(device, address=(self.host, self.port), trace_packet=trace)
        else:
            self._server = ModbusSerialServer(
                device, port=self.serial_port, baudrate=self.baudrate, trace_packet=trace
            )
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
                    raw0 = min(max(o.calibration.inverse(0.0, o.raw_range), o.raw_range[0]), o.raw_range[1])
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
            raise RuntimeError(f"Modbus emulator on {self.endpoint}: {self._error}") from self._error
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
