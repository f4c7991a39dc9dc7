"""Start every device a ``kind = "modbus"`` rig file names, emulated on one simulated rig.

:func:`start_emulators` reads the rig file and starts:

* the Modbus analog I/O module — TCP on the file's host/port, or RTU on a pty bridge
  (paced at the baud rate unless ``[rig.emulator] baud_pacing = false``), with the
  device's communication watchdog when ``[rig.emulator] watchdog_s`` is set (no request for
  that long → every analog output vents, as a LabJack T7 configured for it does);
* an SMC ITV for each ``type = "itv-serial"`` output, on a pty;
* the load-cell indicator when a channel has ``source = "indicator"``, on a pty;

all sharing one :class:`~.plant.EmulatedPlant` built from ``[rig.emulator] truth``/``seed``.
Serial devices get a symlink at the path the rig file names (``/tmp/pmalab-emulator/...``)
so ``pmalab run --rig`` finds them; tests pass ``make_links=False`` and use
:meth:`EmulatorSet.rig_spec`, which points a copy of the spec at the actual endpoints.
"""

from __future__ import annotations

import copy
import socket
from dataclasses import dataclass, field
from pathlib import Path

from pmalab.errors import ConfigError
from pmalab.rig.drivers.rigfile import ModbusRigSpec, read_modbus_rig_file
from pmalab.rig.emulators.faults import FaultPlan
from pmalab.rig.emulators.modbus_server import ModbusEmulator
from pmalab.rig.emulators.plant import EmulatedPlant
from pmalab.rig.emulators.pty_link import PtyBridge, link_path
from pmalab.rig.emulators.serial_devices import IndicatorEmulator, ItvEmulator


@dataclass
class EmulatorSet:
    """The running emulators of one rig file."""

    spec: ModbusRigSpec
    plant: EmulatedPlant
    modbus: ModbusEmulator
    bridge: PtyBridge | None = None
    itvs: dict[str, ItvEmulator] = field(default_factory=dict)
    indicator: IndicatorEmulator | None = None
    links: list[Path] = field(default_factory=list)

    @property
    def faults(self) -> FaultPlan:
        """The Modbus module's fault plan (each serial device has its own ``.faults``)."""
        return self.modbus.faults

    def endpoints(self) -> list[str]:
        """One line per device: what it is and where it listens."""
        out = [f"Modbus {self.spec.transport.type.upper()} I/O module: {self.modbus.endpoint}"]
        if self.bridge is not None:
            out[-1] += f" (pty {self.bridge.server_path} <-> {self.bridge.client_path})"
            if self.spec.transport.type == "rtu":
                out.append(
                    f"  rig file port {self.spec.transport.port} -> {self.bridge.client_path}"
                )
        for name, itv in self.itvs.items():
            out.append(
                f"SMC ITV (RS-232C) for {name}: {itv.path} (rig file port {self.spec.outputs[name].port})"
            )
        if self.indicator is not None:
            assert self.spec.indicator is not None
            out.append(
                f"load-cell indicator: {self.indicator.path} (rig file port {self.spec.indicator.port})"
            )
        return out

    def rig_spec(self) -> ModbusRigSpec:
        """A copy of the rig spec pointing at the running emulators' real endpoints."""
        rs = copy.deepcopy(self.spec)
        if rs.transport.type == "tcp":
            rs.transport.port = self.modbus.port
        elif self.bridge is not None:
            rs.transport.port = self.bridge.client_path
        for name, itv in self.itvs.items():
            rs.outputs[name].port = itv.path
        if self.indicator is not None and rs.indicator is not None:
            rs.indicator.port = self.indicator.path
        return rs

    def stop(self) -> None:
        self.modbus.stop()
        if self.bridge is not None:
            self.bridge.stop()
        for itv in self.itvs.values():
            itv.stop()
        if self.indicator is not None:
            self.indicator.stop()
        for link in self.links:
            try:
                if link.is_symlink():
                    link.unlink()
            except OSError:
                pass

    def __enter__(self) -> EmulatorSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """An unused TCP port on ``host`` (for tests)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def start_emulators(
    rig: str | Path | ModbusRigSpec,
    *,
    tcp_port: int | None = None,
    make_links: bool = True,
    truth: str | Path | None = None,
    seed: int | None = None,
    baud_pacing: bool | None = None,
    serial_pacing: bool = True,
) -> EmulatorSet:
    """Start the emulators of a rig file; ``tcp_port=0`` picks a free port."""
    spec = rig if isinstance(rig, ModbusRigSpec) else read_modbus_rig_file(rig)
    where = str(spec.path) if spec.path else "rig"
    emu = spec.emulator
    if truth is None and emu.get("truth"):
        truth = Path(emu["truth"])
        if not truth.is_absolute() and spec.path is not None:
            truth = spec.path.parent / truth
    if seed is None:
        seed = int(emu.get("seed", 0))
    if baud_pacing is None:
        baud_pacing = bool(emu.get("baud_pacing", True))
    watchdog_s = emu.get("watchdog_s")
    if watchdog_s is not None and (
        isinstance(watchdog_s, bool) or not isinstance(watchdog_s, (int, float)) or watchdog_s <= 0
    ):
        raise ConfigError(f"{where}: rig.emulator.watchdog_s: must be a number of seconds > 0")
    plant = EmulatedPlant(truth, seed=seed)

    started: list[object] = []
    links: list[Path] = []
    try:
        bridge = None
        if spec.transport.type == "tcp":
            port = (
                int(spec.transport.port)
                if tcp_port is None
                else (tcp_port or free_tcp_port(spec.transport.host))
            )
            modbus = ModbusEmulator(
                spec, plant, host=spec.transport.host, port=port, watchdog_s=watchdog_s
            )
        else:
            bridge = PtyBridge(spec.transport.baudrate if baud_pacing else None).start()
            started.append(bridge)
            modbus = ModbusEmulator(
                spec, plant, serial_port=bridge.server_path, baudrate=spec.transport.baudrate,
                watchdog_s=watchdog_s,
            )  # fmt: skip
            if make_links:
                links.append(link_path(bridge.client_path, str(spec.transport.port)))
        try:
            modbus.start()
        except RuntimeError as exc:
            raise ConfigError(f"{where}: cannot start the Modbus emulator ({exc})") from exc
        started.append(modbus)
        itvs: dict[str, ItvEmulator] = {}
        for name, o in spec.outputs.items():
            if o.type == "itv-serial":
                target = "cylinder" if name == "cylinder_regulator" else "muscle"
                itv = ItvEmulator(
                    plant,
                    o.max_pressure_MPa,
                    baudrate=o.baudrate,
                    pace=serial_pacing,
                    target=target,
                ).start()
                started.append(itv)
                itvs[name] = itv
                if make_links:
                    links.append(link_path(itv.path, o.port))
        indicator = None
        if spec.indicator is not None:
            rate = float(emu.get("indicator_rate_Hz", 50.0))
            indicator = IndicatorEmulator(
                plant, rate, baudrate=spec.indicator.baudrate, pace=serial_pacing
            ).start()
            started.append(indicator)
            if make_links:
                links.append(link_path(indicator.path, spec.indicator.port))
    except BaseException:
        for dev in reversed(started):
            dev.stop()  # type: ignore[attr-defined]
        for link in links:
            if link.is_symlink():
                link.unlink()
        raise
    return EmulatorSet(spec, plant, modbus, bridge, itvs, indicator, links)
