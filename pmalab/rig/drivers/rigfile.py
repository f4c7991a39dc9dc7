"""Rig files for real devices (``[rig] kind = "modbus"``): parse, connect, check, build a Rig.

Schema (see ``data/rigs/labjack-t7.toml`` for a commented example).  Everything sits under
``[rig]`` because :func:`pmalab.rig.loader.load_rig` passes the ``[rig]`` table to the kind's
factory and handles ``[limits]`` itself::

    [rig]        kind = "modbus", name, sample_rate_Hz = 500, allow_reduced_rate = false,
                 probe_samples = 300 (0 skips the rate probe)
    [rig.transport]  type = "tcp" (host, port) | "rtu" (port, baudrate, parity, stopbits,
                 bytesize); device_id, timeout_s, retries
    [rig.inputs]     function = "holding" | "input"; defaults data_type, word_order, scale, offset
    [rig.inputs.<channel>]   for position, force, muscle_pressure, cylinder_pressure:
                 address, (data_type, word_order, scale, offset), raw_range = [lo, hi],
                 points = [[raw, value], [raw, value]] | polynomial = [c0, c1, ...], tare;
                 or source = "indicator" (force from the serial load-cell indicator)
    [rig.outputs.cylinder_regulator]  type = "analog" (address, data_type, points raw→MPa,
                 raw_range, max_pressure_MPa) | "itv-serial" (port, baudrate, max_pressure_MPa)
    [rig.outputs.muscle_regulator]    same; absent = a manual regulator (the operator sets it)
    [rig.indicator]  port, baudrate, stale_after_s (when a channel has source = "indicator")
    [rig.emulator]   read only by ``pmalab emulate`` (truth file, seed, ...)
    [limits]     fields of pmalab.rig.base.Limits (applied by the loader)

Calibrations always map raw → engineering unit (volts → MPa, mm, N); outputs are inverted.

Before anything moves, :func:`build_modbus_rig` connects every device, reads the input block
once (a rejected address is reported as a wrong register map), commands the regulators to
vent, and probes the block-read rate (timing honesty).  Each failure is one line.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pmalab.config import check_keys, load_toml
from pmalab.errors import ConfigError, RigError
from pmalab.rig.base import (
    Clock,
    Limits,
    PressureRegulator,
    RealClock,
    RegulatedMuscleSupply,
    Rig,
)
from pmalab.rig.drivers.adapters import Adapter, DeviceExceptionReply, SerialAdapter, SocketAdapter
from pmalab.rig.drivers.calibration import (
    Calibration,
    RegisterCodec,
    parse_calibration,
    parse_codec,
)
from pmalab.rig.drivers.itv_serial import ItvSerialRegulator
from pmalab.rig.drivers.loadcell_serial import LoadCellIndicator
from pmalab.rig.drivers.modbus_daq import (
    SAMPLED,
    AnalogChannel,
    ManualMuscleSupply,
    ModbusAnalogOutput,
    ModbusSampler,
)
from pmalab.rig.drivers.modbus_link import FC_READ_HOLDING, FC_READ_INPUT, ModbusLink


@dataclass
class TransportSpec:
    type: str  # tcp | rtu
    host: str = "127.0.0.1"
    port: int | str = 502
    baudrate: int = 115200
    parity: str = "N"
    stopbits: float = 1
    bytesize: int = 8
    device_id: int = 1
    timeout_s: float = 0.05
    retries: int = 3

    @property
    def endpoint(self) -> str:
        return (
            f"tcp://{self.host}:{self.port}"
            if self.type == "tcp"
            else f"rtu://{self.port}@{self.baudrate}"
        )

    def adapter(self) -> Adapter:
        if self.type == "tcp":
            return SocketAdapter(
                self.host, int(self.port), connect_timeout=max(1.0, self.timeout_s)
            )
        return SerialAdapter(
            str(self.port), self.baudrate, self.bytesize, self.parity, self.stopbits
        )


@dataclass
class OutputSpec:
    name: str
    type: str  # analog | itv-serial
    max_pressure_MPa: float = 0.9
    address: int = 0
    codec: RegisterCodec = field(default_factory=RegisterCodec)
    calibration: Calibration | None = None
    raw_range: tuple[float, float] = (0.0, 10.0)
    port: str = ""
    baudrate: int = 9600
    timeout_s: float = 0.2
    retries: int = 2


@dataclass
class IndicatorSpec:
    port: str
    baudrate: int = 9600
    stale_after_s: float = 0.5


@dataclass
class ModbusRigSpec:
    """Everything a ``kind = "modbus"`` rig file says, validated."""

    path: Path | None
    text: str
    name: str
    sample_rate_Hz: float
    allow_reduced_rate: bool
    probe_samples: int
    transport: TransportSpec
    function: int
    channels: list[AnalogChannel]
    indicator_channels: list[str]
    outputs: dict[str, OutputSpec]
    indicator: IndicatorSpec | None
    limits: Limits
    emulator: dict[str, Any]

    def channel(self, name: str) -> AnalogChannel | None:
        return next((c for c in self.channels if c.name == name), None)


# --------------------------------------------------------------------------- parsing
SECTION_KEYS = {
    "name", "sample_rate_Hz", "allow_reduced_rate", "probe_samples",
    "transport", "inputs", "outputs", "indicator", "emulator",
}  # fmt: skip


def read_modbus_rig_file(path: str | Path) -> ModbusRigSpec:
    """Read and validate a ``kind = "modbus"`` rig file (the emulator's entry point)."""
    path = Path(path)
    doc, text = load_toml(path, "rig file")
    section = doc.get("rig", {})
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: rig: must be a [rig] table")
    section = dict(section)
    kind = section.pop("kind", None)
    if kind not in ("modbus", "labjack-t7-stream"):
        raise ConfigError(
            f"{path}: rig.kind: {kind!r} is not 'modbus' or "
            "'labjack-t7-stream' (nothing to emulate)"
        )
    for key in ("buffer_size_bytes", "ain_calibration"):  # stream-only keys
        section.pop(key, None)
    rs = parse_modbus_rig(section, path)
    rs.text = text
    rs.limits = Limits().updated(doc.get("limits", {}), str(path))
    return rs


def parse_modbus_rig(section: Mapping[str, Any], rig_file: Path | None = None) -> ModbusRigSpec:
    """Validate the ``[rig]`` table of a ``kind = "modbus"`` file; ConfigError names file and field."""
    path = rig_file
    text = ""
    where = str(path) if path else "rig"
    data = {
        "rig": section,
        **{k: section[k] for k in ("transport", "inputs", "outputs", "indicator") if k in section},
    }
    check_keys(
        section,
        SECTION_KEYS,
        "{where}: rig.{key}: unknown key for kind 'modbus' (known: {known})",
        where=where,
    )
    rig = section
    tr = _table(data, "transport", where)
    ttype = str(tr.get("type", "tcp")).lower()
    if ttype not in ("tcp", "rtu"):
        raise ConfigError(f"{where}: [rig.transport] type {ttype!r} is not 'tcp' or 'rtu'")
    if ttype == "rtu" and not isinstance(tr.get("port"), str):
        raise ConfigError(
            f"{where}: [rig.transport] port must be a serial device path for type = 'rtu'"
        )
    transport = TransportSpec(
        type=ttype,
        host=str(tr.get("host", "127.0.0.1")),
        port=tr.get("port", 502),
        baudrate=int(tr.get("baudrate", 115200)),
        parity=str(tr.get("parity", "N")),
        stopbits=tr.get("stopbits", 1),
        bytesize=int(tr.get("bytesize", 8)),
        device_id=_int(tr.get("device_id", 1), f"{where}: [rig.transport] device_id", 0, 255),
        timeout_s=_num(tr.get("timeout_s", 0.05), f"{where}: [rig.transport] timeout_s", 1e-4),
        retries=_int(tr.get("retries", 3), f"{where}: [rig.transport] retries", 0, 20),
    )
    if ttype == "tcp":
        _int(transport.port, f"{where}: [rig.transport] port", 1, 65535)

    inputs = _table(data, "inputs", where)
    fn_name = str(inputs.get("function", "holding")).lower()
    if fn_name not in ("holding", "input"):
        raise ConfigError(f"{where}: [rig.inputs] function {fn_name!r} is not 'holding' or 'input'")
    channels: list[AnalogChannel] = []
    indicator_channels: list[str] = []
    for name in SAMPLED:
        w = f"{where}: [rig.inputs.{name}]"
        ch = inputs.get(name)
        if not isinstance(ch, Mapping):
            raise ConfigError(f"{w} missing (every rig needs {', '.join(SAMPLED)})")
        if ch.get("source") == "indicator":
            indicator_channels.append(name)
            continue
        if "source" in ch:
            raise ConfigError(f"{w} source {ch['source']!r} is not 'indicator'")
        address = _int(ch.get("address"), f"{w} address", 0, 65535)
        codec = parse_codec(ch, inputs, w)
        cal = parse_calibration(ch, w)
        rr = ch.get("raw_range")
        raw_range = _pair(rr, f"{w} raw_range") if rr is not None else None
        channels.append(AnalogChannel(name, address, codec, cal, raw_range))
    _check_overlap(channels, where)
    if not channels:
        raise ConfigError(f"{where}: [rig.inputs] at least one channel must come over Modbus")

    indicator = None
    if indicator_channels:
        ind = _table(data, "indicator", where)
        if not isinstance(ind.get("port"), str):
            raise ConfigError(f"{where}: [rig.indicator] port must be a serial device path")
        indicator = IndicatorSpec(
            port=ind["port"],
            baudrate=int(ind.get("baudrate", 9600)),
            stale_after_s=_num(
                ind.get("stale_after_s", 0.5), f"{where}: [rig.indicator] stale_after_s", 0.01
            ),
        )

    outs = data.get("outputs", {})
    outputs: dict[str, OutputSpec] = {}
    for oname in ("cylinder_regulator", "muscle_regulator"):
        o = outs.get(oname)
        if o is None:
            if oname == "cylinder_regulator":
                raise ConfigError(f"{where}: [rig.outputs.cylinder_regulator] missing")
            continue
        outputs[oname] = _parse_output(oname, o, where)

    rate = _num(
        rig.get("sample_rate_Hz", 500.0), f"{where}: [rig] sample_rate_Hz", 1.0, MAX_RATE_HZ
    )
    return ModbusRigSpec(
        path=path,
        text=text,
        name=str(rig.get("name", "modbus rig")),
        sample_rate_Hz=rate,
        allow_reduced_rate=bool(rig.get("allow_reduced_rate", False)),
        probe_samples=_int(
            rig.get("probe_samples", 300), f"{where}: [rig] probe_samples", 0, 100000
        ),
        transport=transport,
        function=FC_READ_HOLDING if fn_name == "holding" else FC_READ_INPUT,
        channels=channels,
        indicator_channels=indicator_channels,
        outputs=outputs,
        indicator=indicator,
        limits=Limits(),
        emulator=dict(section.get("emulator", {})),
    )


def _parse_output(name: str, o: Any, where: str) -> OutputSpec:
    w = f"{where}: [rig.outputs.{name}]"
    if not isinstance(o, Mapping):
        raise ConfigError(f"{w} must be a table")
    otype = str(o.get("type", "analog")).lower()
    # a proportional regulator's range: 0.9 MPa (ITV1050); 1.2 MPa is beyond any PMA rig
    maxp = _num(o.get("max_pressure_MPa", 0.9), f"{w} max_pressure_MPa", 0.01, 1.2)
    if otype == "analog":
        return OutputSpec(
            name=name,
            type=otype,
            max_pressure_MPa=maxp,
            address=_int(o.get("address"), f"{w} address", 0, 65535),
            codec=parse_codec(o, {}, w),
            calibration=parse_calibration(o, w),
            raw_range=_pair(o.get("raw_range", [0.0, 10.0]), f"{w} raw_range"),
        )
    if otype == "itv-serial":
        if not isinstance(o.get("port"), str):
            raise ConfigError(f"{w} port must be a serial device path")
        return OutputSpec(
            name=name,
            type=otype,
            max_pressure_MPa=maxp,
            port=o["port"],
            baudrate=int(o.get("baudrate", 9600)),
            timeout_s=_num(o.get("timeout_s", 0.2), f"{w} timeout_s", 1e-3),
            retries=_int(o.get("retries", 2), f"{w} retries", 0, 20),
        )
    raise ConfigError(f"{w} type {otype!r} is not 'analog' or 'itv-serial'")


def override_transport(
    section: Mapping[str, Any], where: str, *, host: str | None = None, port: int | None = None
) -> dict[str, Any]:
    """A copy of a ``[rig]`` table with ``[rig.transport]`` host/port replaced (``pmalab run
    --host/--port``); only for Modbus TCP (an RTU port is a serial device in the file)."""
    out = dict(section)
    tr = out.get("transport")
    tr = dict(tr) if isinstance(tr, Mapping) else {}
    ttype = str(tr.get("type", "tcp")).lower()
    if ttype != "tcp":
        flag = "--host" if host is not None else "--port"
        raise ConfigError(
            f"{flag}: {where} talks Modbus {ttype.upper()} on a serial port; "
            "--host/--port apply to Modbus TCP rig files"
        )
    if host is not None:
        tr["host"] = host
    if port is not None:
        tr["port"] = port
    out["transport"] = tr
    return out


# --------------------------------------------------------------------------- building
def make_modbus_rig(
    section: Mapping[str, Any],
    rig_file: Path | None = None,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
) -> Rig:
    """The ``RIG_KINDS["modbus"]`` factory: parse the ``[rig]`` table, connect, check."""
    return build_modbus_rig(parse_modbus_rig(section, rig_file), seed=seed, clock=clock)


def build_modbus_rig(
    spec: str | Path | ModbusRigSpec,
    *,
    seed: int | None = 0,
    clock: Clock | None = None,
    probe: bool = True,
) -> Rig:
    """Connect every device of a modbus rig, check it, and return the :class:`Rig`.

    ``seed`` is accepted for the loader's uniform signature (real devices are not seeded).
    """
    del seed
    rs = spec if isinstance(spec, ModbusRigSpec) else read_modbus_rig_file(spec)
    where = str(rs.path) if rs.path else "rig"
    if clock is None:
        clock = RealClock()
    elif clock.virtual:
        raise ConfigError(f"{where}: real devices need a real clock, not a virtual one")

    opened: list[Any] = []

    def fail(exc: Exception) -> None:
        for dev in reversed(opened):
            try:
                dev.close()
            except Exception:
                pass
        raise exc

    t = rs.transport
    link = ModbusLink(t.adapter(), t.type, t.device_id, t.timeout_s, t.retries)
    try:
        link.connect()
    except RigError as exc:
        fail(
            RigError(
                f"{where}: {exc} (device off or wrong address/port? for a try without hardware: pmalab emulate --rig {where})"
            )
        )
    opened.append(link)

    indicator = None
    extra: dict[str, Any] = {}
    extra_stats: dict[str, Any] = {}
    if rs.indicator is not None:
        indicator = LoadCellIndicator(
            SerialAdapter(rs.indicator.port, rs.indicator.baudrate), rs.indicator.stale_after_s
        )
        try:
            indicator.connect()
        except RigError as exc:
            fail(RigError(f"{where}: [rig.indicator] {exc}"))
        opened.append(indicator)
        for name in rs.indicator_channels:
            extra[name] = indicator.force
        extra_stats["indicator"] = indicator.stats_dict

    sampler = ModbusSampler(
        link,
        list(rs.channels),
        clock,
        function=rs.function,
        sample_rate_Hz=rs.sample_rate_Hz,
        allow_reduced_rate=rs.allow_reduced_rate,
        extra=extra,
        extra_stats=extra_stats,
    )
    sampler.closers.extend(dev.close for dev in opened if dev is not link)
    # one block read: a rejected address means the register map is wrong
    try:
        sampler.read_values()
    except RigError as exc:
        if isinstance(link.last_error, DeviceExceptionReply) and link.last_error.code in (1, 2):
            lo, hi = sampler.start_address, sampler.start_address + sampler.count - 1
            fail(
                ConfigError(
                    f"{where}: [rig.inputs] registers {lo}–{hi} rejected by {t.endpoint} "
                    f"({link.last_error}); wrong register map?"
                )
            )
        fail(RigError(f"{where}: {exc}"))

    regulators: dict[str, PressureRegulator] = {}
    for oname, o in rs.outputs.items():
        try:
            regulators[oname] = _make_output(o, link)
        except RigError as exc:
            fail(RigError(f"{where}: [rig.outputs.{oname}] {exc}"))
        reg = regulators[oname]
        if isinstance(reg, ItvSerialRegulator):
            opened.append(reg)
            sampler.closers.append(reg.close)
            sampler.extra_stats[oname] = reg.stats_dict
        # command zero (vented) before anything else: checks the output register too
        try:
            if isinstance(reg, ModbusAnalogOutput):
                reg.link.write_registers(reg.address, reg.codec.encode(reg.raw_for(0.0)))
            else:
                reg.set_counts(0)  # type: ignore[attr-defined]
        except RigError as exc:
            if isinstance(link.last_error, DeviceExceptionReply) and link.last_error.code in (1, 2):
                fail(
                    ConfigError(
                        f"{where}: [rig.outputs.{oname}] address {o.address} rejected ({link.last_error}); wrong register map?"
                    )
                )
            fail(RigError(f"{where}: [rig.outputs.{oname}] {exc}"))

    cyl = regulators["cylinder_regulator"]
    if isinstance(cyl, ModbusAnalogOutput) and cyl.link is link:
        zero = cyl.codec.encode(cyl.raw_for(0.0))
        sampler.probe_companion = lambda: link.write_registers(cyl.address, zero)
    timing: dict[str, Any] = {
        "requested_rate_Hz": rs.sample_rate_Hz,
        "probe": "block read + cylinder regulator write"
        if sampler.probe_companion
        else "block read",
    }
    if probe and rs.probe_samples > 0:
        try:
            res = sampler.check_rate(rs.sample_rate_Hz, rs.probe_samples)
        except RigError as exc:
            fail(exc)
        timing.update(res.as_dict())
        timing["host_busy"] = res.host_busy
    timing["sample_rate_Hz"] = sampler.sample_rate_Hz
    timing["reduced"] = sampler.sample_rate_Hz < rs.sample_rate_Hz

    supply = (
        RegulatedMuscleSupply(regulators["muscle_regulator"])
        if "muscle_regulator" in regulators
        else ManualMuscleSupply()
    )
    info: dict[str, Any] = {
        "kind": "modbus",
        "name": rs.name,
        "rig_file": str(rs.path) if rs.path else None,
        "transport": t.endpoint,
        "device_id": t.device_id,
        "input_block": {
            "address": sampler.start_address,
            "count": sampler.count,
            "function": rs.function,
        },
        "channels": {
            c.name: {
                "address": c.address,
                "data_type": c.codec.data_type,
                "word_order": c.codec.word_order,
                "calibration": c.calibration.as_dict(),
                "raw_range": list(c.raw_range) if c.raw_range else None,
            }
            for c in rs.channels
        },
        "indicator_channels": rs.indicator_channels,
        "timing": timing,
        "sample_rate_Hz": sampler.sample_rate_Hz,
        "allow_reduced_rate": rs.allow_reduced_rate,
    }
    if rs.text:
        info["rig_file_text"] = rs.text
    return Rig(clock, sampler, regulators["cylinder_regulator"], supply, rs.limits, info)


def _make_output(o: OutputSpec, link: ModbusLink) -> PressureRegulator:
    if o.type == "analog":
        assert o.calibration is not None
        return ModbusAnalogOutput(
            link, o.address, o.codec, o.calibration, o.raw_range, o.max_pressure_MPa, o.name
        )
    reg = ItvSerialRegulator(
        SerialAdapter(o.port, o.baudrate), o.max_pressure_MPa, o.timeout_s, o.retries, o.name
    )
    reg.connect()
    return reg


# --------------------------------------------------------------------------- helpers
def _table(data: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    t = data.get(key)
    if not isinstance(t, Mapping):
        raise ConfigError(f"{where}: missing [rig.{key}] table")
    return t


#: the fastest a polled rig can be asked to sample: a Modbus request/response takes ≥ 0.2 ms
#: on a LAN (a hardware-timed card has its own limit in its driver)
MAX_RATE_HZ = 5000.0


def _num(x: Any, where: str, lo: float | None = None, hi: float | None = None) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise ConfigError(f"{where}: expected a number, got {x!r}")
    if lo is not None and x < lo:
        raise ConfigError(f"{where}: {x} is below {lo}")
    if hi is not None and x > hi:
        raise ConfigError(f"{where}: {x:g} is above {hi:g}")
    return float(x)


def _int(x: Any, where: str, lo: int, hi: int) -> int:
    if isinstance(x, bool) or not isinstance(x, int):
        raise ConfigError(f"{where}: expected an integer, got {x!r}")
    if not lo <= x <= hi:
        raise ConfigError(f"{where}: {x} outside {lo}–{hi}")
    return int(x)


def _pair(x: Any, where: str) -> tuple[float, float]:
    if not isinstance(x, (list, tuple)) or len(x) != 2:
        raise ConfigError(f"{where}: expected [low, high]")
    lo, hi = _num(x[0], where), _num(x[1], where)
    if lo >= hi:
        raise ConfigError(f"{where}: low {lo} must be below high {hi}")
    return lo, hi


def _check_overlap(channels: list[AnalogChannel], where: str) -> None:
    used: dict[int, str] = {}
    for c in channels:
        for a in range(c.address, c.address + c.codec.width):
            if a in used:
                raise ConfigError(
                    f"{where}: [rig.inputs.{c.name}] register {a} already used by {used[a]}"
                )
            used[a] = c.name
