"""NI-DAQmx rigs (``[rig] kind = "nidaqmx"``): the seed papers' DAQ card, hardware timed.

One buffered analog-input task samples every sensor on the device's own sample clock
(continuous acquisition at the protocol's rate, 500 Hz–10 kHz); sample ``k`` of a run is at
``t = k / rate`` from the task's start — the host's clock never stamps a sample.  The
regulators (SMC ITV1050: 0–10 V command = 0–0.9 MPa) hang on analog outputs written on
demand once per block read (every ``read_block_s``, 10 ms by default); a hardware-timed AO
task is not used.

Rig file (``data/rigs/nidaqmx.toml`` is a commented example)::

    [rig]  kind = "nidaqmx", name, device = "Dev1", buffer_s = 2.0, read_block_s = 0.01,
           read_timeout_s = 1.0, vent_confirm_s = 2.0, vent_confirm_MPa = 0.03
    [rig.inputs.<channel>]   for position, force, muscle_pressure, cylinder_pressure:
           channel = "ai0", terminal = "RSE" | "NRSE" | "DIFF" | "PSEUDO_DIFF" | "DEFAULT",
           range_V = [lo, hi], raw_range = [lo, hi] (volts outside: a broken wire),
           points = [[V, value], [V, value]] | polynomial = [...], tare
    [rig.outputs.cylinder_regulator]  channel = "ao0", range_V = [0, 10],
           points = [[V, MPa], [V, MPa]], max_pressure_MPa
    [rig.outputs.muscle_regulator]    the same; absent = a manual regulator

Errors.  A DAQmx error during a run (buffer overflow −200279, samples not arriving
−200284, device removed −201003/−50405) is raised as a :class:`~pmalab.errors.RigError`
naming the code and what it means; the runner then vents and keeps every sample read
before it.  Venting writes 0 V to each regulator's output and is *confirmed* only when
that regulator's pressure sensor reads below ``vent_confirm_MPa`` within
``vent_confirm_s`` (read from the running task, or from a fresh on-demand task when the
stream has stopped); a write that fails, or a pressure that does not fall or cannot be
read, is a FAILED vent that says so.

Needs NI's driver and the ``nidaqmx`` package (``pip install pmalab[nidaq]``); imported
only when such a rig is built.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmalab.config import check_keys
from pmalab.errors import ConfigError, RigError
from pmalab.rig.base import (
    Block,
    Clock,
    Limits,
    PressureRegulator,
    RealClock,
    RegulatedMuscleSupply,
    Rig,
    Sampler,
    VentResult,
)
from pmalab.rig.drivers.calibration import Calibration, parse_calibration
from pmalab.rig.drivers.modbus_daq import ManualMuscleSupply

#: the channels a rig samples, in the order of the task's channel list
INPUTS = ("position", "force", "muscle_pressure", "cylinder_pressure")
#: which sensor confirms which regulator's vent
VENT_SENSOR = {"cylinder_regulator": "cylinder_pressure", "muscle_regulator": "muscle_pressure"}
TERMINALS = ("DEFAULT", "RSE", "NRSE", "DIFF", "PSEUDO_DIFF")

#: DAQmx error codes a run can meet, and what they mean at the rig
DAQMX_MEANINGS = {
    -200279: "buffer overflow: the program did not read the samples before the device "
    "overwrote them",
    -200284: "timeout: the samples asked for did not arrive (sample clock stopped, or the "
    "device is gone)",
    -201003: "device cannot be accessed: removed, unpowered or reset",
    -50405: "transfer stopped: the device was removed or lost power (USB)",
    -200473: "read before the task was started",
    -200088: "the task was closed or is invalid",
    -200608: "buffer too small for the sample rate",
    -200077: "a value the device does not support (rate or range)",
    -200170: "no such physical channel on this device",
}


def daqmx_line(exc: BaseException) -> str:
    """``DAQmx error -200279 (buffer overflow: ...)`` for a DaqError, else its first line."""
    code = getattr(exc, "error_code", None)
    if isinstance(code, int):
        meaning = DAQMX_MEANINGS.get(code)
        if meaning is None:
            text = str(exc).strip().splitlines()
            meaning = text[0][:160] if text else "no description"
        return f"DAQmx error {code} ({meaning})"
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:160]}" if text else type(exc).__name__


def _nidaqmx():
    try:
        import nidaqmx  # pyright: ignore[reportMissingImports]  # optional: pmalab[nidaq]
        import nidaqmx.constants  # pyright: ignore[reportMissingImports]  # optional: pmalab[nidaq]
        import nidaqmx.errors  # pyright: ignore[reportMissingImports]  # optional: pmalab[nidaq]
        import nidaqmx.stream_readers  # pyright: ignore[reportMissingImports]  # optional: pmalab[nidaq]
    except ImportError:
        raise ConfigError(
            "rig kind 'nidaqmx' needs NI's driver (NI-DAQmx) and the nidaqmx "
            "package: pip install 'pmalab[nidaq]'"
        ) from None
    return nidaqmx


# --------------------------------------------------------------------------- rig file
@dataclass
class AiSpec:
    name: str
    channel: str
    terminal: str
    range_V: tuple[float, float]
    raw_range: tuple[float, float] | None
    calibration: Calibration


@dataclass
class AoSpec:
    name: str
    channel: str
    range_V: tuple[float, float]
    calibration: Calibration
    max_pressure_MPa: float


@dataclass
class NidaqRigSpec:
    name: str
    device: str
    inputs: list[AiSpec]
    outputs: dict[str, AoSpec]
    buffer_s: float = 2.0
    read_block_s: float = 0.01
    read_timeout_s: float = 1.0
    vent_confirm_s: float = 2.0
    vent_confirm_MPa: float = 0.03
    path: Path | None = None


def _pair(x: Any, where: str) -> tuple[float, float]:
    if (
        not isinstance(x, list | tuple)
        or len(x) != 2
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in x)
    ):
        raise ConfigError(f"{where}: expected [low, high] in volts")
    lo, hi = float(x[0]), float(x[1])
    if not lo < hi:
        raise ConfigError(f"{where}: low must be < high, got [{lo:g}, {hi:g}]")
    return lo, hi


def _pos(x: Any, where: str, lo: float, hi: float) -> float:
    if not isinstance(x, int | float) or isinstance(x, bool) or not lo <= float(x) <= hi:
        raise ConfigError(f"{where}: must be a number in [{lo:g}, {hi:g}], got {x!r}")
    return float(x)


def parse_nidaq_rig(section: Mapping[str, Any], rig_file: Path | None = None) -> NidaqRigSpec:
    """The ``[rig]`` table of a ``kind = "nidaqmx"`` rig file (module doc); one-line errors."""
    where = str(rig_file) if rig_file else "rig"
    top = {
        "name",
        "device",
        "buffer_s",
        "read_block_s",
        "read_timeout_s",
        "vent_confirm_s",
        "vent_confirm_MPa",
        "inputs",
        "outputs",
    }
    check_keys(
        section,
        top,
        "{where}: rig.{key}: unknown key for kind 'nidaqmx' (known: {known})",
        where=where,
    )
    device = section.get("device")
    if not isinstance(device, str) or not device:
        raise ConfigError(f'{where}: rig.device: missing (the NI device name, e.g. "Dev1")')
    inputs_t = section.get("inputs")
    if not isinstance(inputs_t, Mapping):
        raise ConfigError(f"{where}: [rig.inputs]: missing (one table per sensor channel)")
    inputs = []
    for name, t in inputs_t.items():
        w = f"{where}: [rig.inputs.{name}]"
        if name not in INPUTS:
            raise ConfigError(f"{w}: unknown channel (known: {', '.join(INPUTS)})")
        if not isinstance(t, Mapping):
            raise ConfigError(f"{w}: must be a table")
        check_keys(
            t,
            {"channel", "terminal", "range_V", "raw_range", "points", "polynomial", "tare"},
            "{w}: {key}: unknown key (known: {known})",
            w=w,
        )
        ch = t.get("channel")
        if not isinstance(ch, str) or not ch.startswith("ai"):
            raise ConfigError(f'{w}.channel: expected an analog input such as "ai0", got {ch!r}')
        term = str(t.get("terminal", "DEFAULT")).upper()
        if term not in TERMINALS:
            raise ConfigError(
                f"{w}.terminal: {t.get('terminal')!r} (known: {', '.join(TERMINALS)})"
            )
        rng = _pair(t.get("range_V", [-10.0, 10.0]), f"{w}.range_V")
        raw = _pair(t["raw_range"], f"{w}.raw_range") if "raw_range" in t else None
        inputs.append(AiSpec(name, ch, term, rng, raw, parse_calibration(t, w)))
    for need in ("position", "force", "muscle_pressure"):
        if need not in {i.name for i in inputs}:
            raise ConfigError(f"{where}: [rig.inputs.{need}]: missing")
    used = [i.channel for i in inputs]
    dup = {c for c in used if used.count(c) > 1}
    if dup:
        raise ConfigError(f"{where}: [rig.inputs]: {', '.join(sorted(dup))} used twice")
    outputs_t = section.get("outputs", {})
    if not isinstance(outputs_t, Mapping) or "cylinder_regulator" not in outputs_t:
        raise ConfigError(
            f"{where}: [rig.outputs.cylinder_regulator]: missing (the cylinder's "
            "regulator on an analog output)"
        )
    outputs = {}
    for name, t in outputs_t.items():
        w = f"{where}: [rig.outputs.{name}]"
        if name not in VENT_SENSOR:
            raise ConfigError(f"{w}: unknown output (known: {', '.join(VENT_SENSOR)})")
        check_keys(
            t,
            {"channel", "range_V", "points", "polynomial", "max_pressure_MPa"},
            "{w}: {key}: unknown key (known: {known})",
            w=w,
        )
        ch = t.get("channel")
        if not isinstance(ch, str) or not ch.startswith("ao"):
            raise ConfigError(f'{w}.channel: expected an analog output such as "ao0", got {ch!r}')
        outputs[name] = AoSpec(
            name,
            ch,
            _pair(t.get("range_V", [0.0, 10.0]), f"{w}.range_V"),
            parse_calibration(t, w),
            _pos(t.get("max_pressure_MPa", 0.9), f"{w}.max_pressure_MPa", 0.0, 1.2),
        )
        if VENT_SENSOR[name] not in {i.name for i in inputs}:
            raise ConfigError(
                f"{w}: needs [rig.inputs.{VENT_SENSOR[name]}]: its vent is "
                "confirmed by that pressure falling"
            )
    return NidaqRigSpec(
        name=str(section.get("name", f"NI-DAQmx {device}")),
        device=device,
        inputs=inputs,
        outputs=outputs,
        buffer_s=_pos(section.get("buffer_s", 2.0), f"{where}: rig.buffer_s", 0.1, 60.0),
        read_block_s=_pos(
            section.get("read_block_s", 0.01), f"{where}: rig.read_block_s", 0.001, 0.5
        ),
        read_timeout_s=_pos(
            section.get("read_timeout_s", 1.0), f"{where}: rig.read_timeout_s", 0.05, 30.0
        ),
        vent_confirm_s=_pos(
            section.get("vent_confirm_s", 2.0), f"{where}: rig.vent_confirm_s", 0.05, 30.0
        ),
        vent_confirm_MPa=_pos(
            section.get("vent_confirm_MPa", 0.03), f"{where}: rig.vent_confirm_MPa", 0.001, 0.5
        ),
        path=rig_file,
    )


# --------------------------------------------------------------------------- devices
class NidaqSampler(Sampler):
    """Hardware-timed sampler: one continuous AI task on the device's sample clock."""

    hardware_timed = True
    #: the sample clock is programmed to the protocol's rate (the card's own maximum is
    #: checked by DAQmx when the task starts)
    rate_range_Hz = (1.0, 100_000.0)

    def __init__(self, spec: NidaqRigSpec) -> None:
        self.spec = spec
        self.sample_rate_Hz = 500.0
        self.task = None
        self.reader = None
        self.running = False
        self.k = 0  # samples read since the task started
        self.failed: str | None = None  # the DAQmx error that stopped the stream
        self._latest: dict[str, float] = {}
        self.stats_counts = {"blocks": 0, "samples": 0}

    # -- task life
    def _make_task(self, rate: float):
        ni = _nidaqmx()
        from nidaqmx.constants import AcquisitionType, TerminalConfiguration  # pyright: ignore[reportMissingImports]  # optional: pmalab[nidaq]

        task = ni.Task()
        try:
            for ai in self.spec.inputs:
                task.ai_channels.add_ai_voltage_chan(
                    f"{self.spec.device}/{ai.channel}",
                    terminal_config=getattr(TerminalConfiguration, ai.terminal),
                    min_val=ai.range_V[0],
                    max_val=ai.range_V[1],
                )
            buffer = max(int(rate * self.spec.buffer_s), 2 * self._block(rate))
            task.timing.cfg_samp_clk_timing(
                rate, sample_mode=AcquisitionType.CONTINUOUS, samps_per_chan=buffer
            )
        except Exception:
            task.close()
            raise
        return task

    def _block(self, rate: float) -> int:
        return max(1, int(round(rate * self.spec.read_block_s)))

    def configure(self, rate_Hz: float) -> None:
        """Set the sample clock's rate (Hz) for the next :meth:`start`."""
        self.sample_rate_Hz = float(rate_Hz)

    def start(self) -> None:
        from nidaqmx.stream_readers import AnalogMultiChannelReader  # pyright: ignore[reportMissingImports]  # optional: pmalab[nidaq]

        self.stop()
        try:
            self.task = self._make_task(self.sample_rate_Hz)
            self.reader = AnalogMultiChannelReader(self.task.in_stream)
            self.task.start()
        except Exception as exc:
            self.stop()
            raise RigError(
                f"{self.spec.device}: cannot start the analog-input task: {daqmx_line(exc)}"
            ) from None
        self.running = True
        self.failed = None
        self.k = 0

    def stop(self) -> None:
        task, self.task, self.reader, self.running = self.task, None, None, False
        if task is not None:
            try:
                task.stop()
            finally:
                task.close()

    def close(self) -> None:
        self.stop()

    # -- data
    def _convert(self, volts: np.ndarray, check: bool = True) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for i, ai in enumerate(self.spec.inputs):
            val = ai.calibration.apply(
                volts[i],
                ai.raw_range if check else None,
                f"{self.spec.device}/{ai.channel} ({ai.name})",
            )
            out[ai.name] = val
        return out

    def read_block(self) -> Block:
        if not self.running or self.reader is None:
            raise RigError(f"{self.spec.device}: read with no running acquisition")
        n = self._block(self.sample_rate_Hz)
        buf = np.zeros((len(self.spec.inputs), n))
        try:
            got = self.reader.read_many_sample(
                buf, number_of_samples_per_channel=n, timeout=self.spec.read_timeout_s
            )
        except Exception as exc:
            self.running = False
            self.failed = daqmx_line(exc)
            raise RigError(
                f"{self.spec.device}: acquisition stopped after {self.k} samples: {self.failed}"
            ) from None
        got = int(got) if got is not None else n
        buf = buf[:, :got]
        vals = self._convert(buf)
        t = (self.k + np.arange(got)) / self.sample_rate_Hz  # the device's sample clock
        self.k += got
        self.stats_counts["blocks"] += 1
        self.stats_counts["samples"] += got
        for name, v in vals.items():
            if len(v):
                self._latest[name] = float(v[-1])
        zeros = np.zeros(got)
        return Block(
            t,
            vals["position"],
            vals["force"],
            vals["muscle_pressure"],
            vals.get("cylinder_pressure", zeros),
        )

    def read_now(self, name: str) -> float:
        """The latest value of one sensor (engineering units), for vent confirmation: from
        the running stream (what has arrived since the last read), else from a one-sample
        on-demand task.  Raises on a device that cannot be read."""
        ai = next(a for a in self.spec.inputs if a.name == name)
        if self.running and self.task is not None and self.reader is not None:
            avail = int(self.task.in_stream.avail_samp_per_chan)
            if avail > 0:
                buf = np.zeros((len(self.spec.inputs), avail))
                self.reader.read_many_sample(
                    buf, number_of_samples_per_channel=avail, timeout=self.spec.read_timeout_s
                )
                self.k += avail  # read for the confirmation; the run has ended
                return float(self._convert(buf[:, -1:], check=False)[name][-1])
            return self._latest.get(name, float("nan"))
        ni = _nidaqmx()
        from nidaqmx.constants import TerminalConfiguration  # pyright: ignore[reportMissingImports]  # optional: pmalab[nidaq]

        with ni.Task() as task:
            task.ai_channels.add_ai_voltage_chan(
                f"{self.spec.device}/{ai.channel}",
                terminal_config=getattr(TerminalConfiguration, ai.terminal),
                min_val=ai.range_V[0],
                max_val=ai.range_V[1],
            )
            v = float(task.read())
        return float(ai.calibration(v))

    def stats(self) -> dict[str, Any]:
        return {
            "blocks_read": self.stats_counts["blocks"],
            "samples_read": self.stats_counts["samples"],
            "stream_error": self.failed,
        }


class NidaqRegulator(PressureRegulator):
    """A proportional regulator on an analog output, written on demand (value MPa → volts).

    :meth:`start_vent` writes 0 MPa's voltage; the confirmation waits for the regulator's
    own pressure sensor to fall below ``vent_confirm_MPa`` (module doc).
    """

    def __init__(
        self,
        spec: AoSpec,
        device: str,
        sampler: NidaqSampler,
        confirm_s: float,
        confirm_MPa: float,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.spec = spec
        self.device = device
        self.sampler = sampler
        self.max_pressure_MPa = spec.max_pressure_MPa
        self.confirm_s = confirm_s
        self.confirm_MPa = confirm_MPa
        self.sleep = sleep
        self.task = None
        self.last_command_MPa = 0.0
        self.name = spec.name.replace("_", " ")

    def _open(self):
        if self.task is None:
            ni = _nidaqmx()
            task = ni.Task()
            try:
                task.ao_channels.add_ao_voltage_chan(
                    f"{self.device}/{self.spec.channel}",
                    min_val=self.spec.range_V[0],
                    max_val=self.spec.range_V[1],
                )
            except Exception:
                task.close()
                raise
            self.task = task
        return self.task

    def volts_for(self, mpa: float) -> float:
        v = self.spec.calibration.inverse(mpa, self.spec.range_V)
        return min(max(v, self.spec.range_V[0]), self.spec.range_V[1])

    def set_pressure(self, mpa: float) -> None:
        if not -1e-9 <= mpa <= self.max_pressure_MPa + 1e-9:
            raise RigError(
                f"{self.name}: command {mpa:.4f} MPa outside 0–{self.max_pressure_MPa} MPa"
            )
        try:
            self._open().write(self.volts_for(max(mpa, 0.0)))
        except Exception as exc:
            raise RigError(
                f"{self.device}/{self.spec.channel} ({self.name}): write failed: {daqmx_line(exc)}"
            ) from None
        self.last_command_MPa = float(mpa)

    def vent(self) -> VentResult:
        return self.start_vent()()

    def start_vent(self) -> Callable[[], VentResult]:
        v0 = self.volts_for(0.0)
        where = f"{self.device}/{self.spec.channel}"
        try:
            self._open().write(v0)
        except Exception as exc:  # vent never raises: it runs on every exit path
            res = VentResult.failed(f"0 V write to {where} failed: {daqmx_line(exc)}")
            return lambda: res
        self.last_command_MPa = 0.0
        return lambda: self._confirm(where, v0)

    def _confirm(self, where: str, v0: float) -> VentResult:
        sensor = VENT_SENSOR[self.spec.name]
        deadline = time.monotonic() + self.confirm_s
        last = float("nan")
        polls = 0
        while True:
            try:
                last = self.sampler.read_now(sensor)
            except Exception as exc:
                return VentResult.failed(
                    f"{v0:g} V written to {where}, but {sensor} cannot be "
                    f"read back: {daqmx_line(exc)}"
                )
            polls += 1
            if last == last and last <= self.confirm_MPa:
                return VentResult.confirmed(
                    f"{v0:g} V written to {where}; {sensor} reads {last:.3f} MPa"
                )
            if time.monotonic() > deadline or polls > 10_000:
                shown = f"{last:.3f} MPa" if last == last else "no reading"
                return VentResult.failed(
                    f"{v0:g} V written to {where}, but {sensor} still "
                    f"reads {shown} after {self.confirm_s:g} s"
                )
            self.sleep(0.01)

    def close(self) -> None:
        task, self.task = self.task, None
        if task is not None:
            task.close()


# --------------------------------------------------------------------------- building
def make_nidaq_rig(
    section: Mapping[str, Any],
    rig_file: Path | None = None,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
) -> Rig:
    """``RIG_KINDS["nidaqmx"]``: parse, open the device's channels, vent, build the rig."""
    spec = parse_nidaq_rig(section, rig_file)
    _nidaqmx()
    where = str(rig_file) if rig_file else "rig"
    sampler = NidaqSampler(spec)
    regs: dict[str, NidaqRegulator] = {}
    # open every channel once before anything moves: a wrong device or channel name is
    # one line now, not an abort later
    try:
        probe = sampler._make_task(500.0)
        probe.close()
    except Exception as exc:
        raise ConfigError(f"{where}: [rig.inputs] on {spec.device}: {daqmx_line(exc)}") from None
    for name, o in spec.outputs.items():
        reg = NidaqRegulator(o, spec.device, sampler, spec.vent_confirm_s, spec.vent_confirm_MPa)
        try:
            reg._open().write(reg.volts_for(0.0))  # vented before anything else
        except Exception as exc:
            for r in regs.values():
                r.close()
            raise ConfigError(
                f"{where}: [rig.outputs.{name}] {spec.device}/{o.channel}: {daqmx_line(exc)}"
            ) from None
        regs[name] = reg
    supply = (
        RegulatedMuscleSupply(regs["muscle_regulator"])
        if "muscle_regulator" in regs
        else ManualMuscleSupply()
    )
    info: dict[str, Any] = {
        "kind": "nidaqmx",
        "name": spec.name,
        "rig_file": str(rig_file) if rig_file else None,
        "device": spec.device,
        "time_base": "device sample clock",
        "channels": {
            a.name: {
                "channel": f"{spec.device}/{a.channel}",
                "terminal": a.terminal,
                "range_V": list(a.range_V),
                "calibration": a.calibration.as_dict(),
                "raw_range": list(a.raw_range) if a.raw_range else None,
            }
            for a in spec.inputs
        },
        "outputs": {
            n: {
                "channel": f"{spec.device}/{o.channel}",
                "range_V": list(o.range_V),
                "calibration": o.calibration.as_dict(),
            }
            for n, o in spec.outputs.items()
        },
        "read_block_s": spec.read_block_s,
        "buffer_s": spec.buffer_s,
    }
    rig = Rig(clock or RealClock(), sampler, regs["cylinder_regulator"], supply, Limits(), info)
    _close = rig.close

    def close() -> None:  # the rig's close also releases the output tasks
        try:
            _close()
        finally:
            for r in regs.values():
                r.close()

    rig.close = close  # type: ignore[method-assign]
    return rig
