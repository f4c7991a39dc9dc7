"""Modbus analog I/O (LabJack T7, generic Modbus ADC/DAC modules): sampler and regulator output.

:class:`ModbusSampler` reads every Modbus analog input of the rig in ONE block request per
sample (the span from the lowest to the highest channel register), decodes each channel's
registers (:class:`~.calibration.RegisterCodec`) and calibrates volts → engineering units.
It is software-polled (``hardware_timed = False``): the runner calls :meth:`read_block` at
each deadline and gets one sample stamped on the rig's clock at the middle of the request
(the instant the device most likely sampled its inputs).

Channels that do not come over Modbus (a serial load-cell indicator) are plugged in as
``extra`` sources: callables returning the latest value.

:class:`ModbusAnalogOutput` is a :class:`~pmalab.rig.base.PressureRegulator` on an analog
output register (LabJack DAC0 at 1000: 0–10 V → ITV1050 0–0.9 MPa).

Timing honesty: :meth:`ModbusSampler.probe_rate` measures the block-read latency of the
configured link; :meth:`ModbusSampler.check_rate` refuses a rate it cannot sustain, or (only
with ``allow_reduced_rate``) lowers :attr:`sample_rate_Hz` to one it can.  A probe on a busy
computer also measures the computer: every read waits until the scheduler gives the driver
(and an emulator running in the same process) a CPU again.  The probe therefore records how
long this process's threads waited for a CPU (:func:`cpu_wait_s`); when that is a large share
of the probe and the link could still keep up (its fastest read fits the sample period's
budget, and so do its reads on average with every CPU wait taken out:
:func:`too_busy_to_judge`), the link is not blamed: the rig is refused with "too busy to
judge the link" instead.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from pmalab.errors import RigError
from pmalab.rig.base import (
    Block,
    Clock,
    MusclePressureSupply,
    PressureRegulator,
    Sampler,
    VentResult,
)
from pmalab.rig.drivers.adapters import DeviceExceptionReply, ValueOutOfRange
from pmalab.rig.drivers.calibration import Calibration, RegisterCodec
from pmalab.rig.drivers.modbus_link import FC_READ_HOLDING, ModbusLink, one_line

#: rates a reduced-rate run may fall back to (Hz), highest first
FALLBACK_RATES_HZ = (500.0, 400.0, 250.0, 200.0, 125.0, 100.0, 50.0, 25.0, 10.0)
#: share of the sample period a typical (median) block read may take; the runner, the
#: regulator write and the recorder need the rest.  The median judges the *link*: on a busy
#: machine a few reads in a hundred wait for the scheduler (p95/p99 are recorded, and the
#: runner counts the samples they make late or miss), which says nothing about the link.
PERIOD_BUDGET = 0.5
#: block reads done before timing starts (connection and caches warm up)
PROBE_WARMUP = 20
#: share of a probe's wall time this process's threads may wait for a CPU (summed over the
#: threads) before the probe counts as a measurement of the busy computer, not of the link
#: (an idle machine: a few per cent; other programs using every core: 0.5 and more)
HOST_BUSY_SHARE = 0.25

SAMPLED = ("position", "force", "muscle_pressure", "cylinder_pressure")


@dataclass(frozen=True)
class AnalogChannel:
    """One analog input: register address, encoding, calibration, electrical range."""

    name: str
    address: int
    codec: RegisterCodec
    calibration: Calibration
    raw_range: tuple[float, float] | None = None


def cpu_wait_s(tasks: str = "/proc/self/task") -> float | None:
    """Seconds this process's threads have spent runnable but waiting for a CPU.

    Summed over the process's threads (a thread that ended is no longer counted), from the
    Linux scheduler statistics (``<tasks>/<tid>/schedstat``: time on a CPU, time waiting
    for one (ns), times scheduled).  Returns None where the kernel does not report them:
    not Linux, no ``/proc``, or a kernel built without scheduler statistics (it writes
    ``0 0 0`` for every thread, though the calling thread has certainly been scheduled:
    no count, not a count of zero).
    """
    try:
        tids = os.listdir(tasks)
    except OSError:
        return None
    total = 0
    scheduled = 0
    for tid in tids:
        try:
            with open(f"{tasks}/{tid}/schedstat", "rb") as f:
                fields = f.read().split()
            total += int(fields[1])
            scheduled += int(fields[2])
        except FileNotFoundError:  # the thread ended meanwhile
            continue
        except (OSError, ValueError, IndexError):
            return None
    return total * 1e-9 if scheduled > 0 else None


@dataclass
class ProbeResult:
    """Block-read latency of a link (ms) and what rate it sustains."""

    n: int
    mean_ms: float
    p50_ms: float
    p95_ms: float
    p99_ms: float
    max_ms: float
    jitter_ms: float  # standard deviation of the latency
    max_rate_Hz: float  # 1 / mean latency: back-to-back reads
    sustainable_Hz: float  # PERIOD_BUDGET / median latency
    over_budget: float  # share of reads longer than PERIOD_BUDGET of the requested period
    min_ms: float = float("nan")  # the fastest read: what the link does when nothing waits
    #: seconds this process's threads waited for a CPU during the probe, per second of the
    #: probe (summed over the threads; NaN where the kernel does not report it)
    cpu_wait_share: float = float("nan")

    @property
    def host_busy(self) -> bool:
        """The computer was busy during the probe: this process's threads waited for a CPU
        more than :data:`HOST_BUSY_SHARE` of it (whether that, not the link, made the reads
        slow: :func:`too_busy_to_judge`)."""
        return self.cpu_wait_share > HOST_BUSY_SHARE  # False for NaN

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def too_busy_to_judge(res: ProbeResult, budget_ms: float) -> bool:
    """Whether a probe whose reads miss ``budget_ms`` measured the busy computer rather than
    the link (:attr:`ProbeResult.host_busy`), so the link may not be blamed for them.

    A link that is too slow is too slow on a busy computer too.  It is judged slow when its
    fastest read exceeds the budget, or when its reads exceed it on average even with all
    the time this process's threads waited for a CPU taken out of them (mean read x (1 −
    :attr:`ProbeResult.cpu_wait_share`): the waits, summed over the threads, overstate
    what the reads waited (a thread that ended during the probe aside), so what is left is
    no more than the link's own time).
    """
    if not res.host_busy:
        return False
    link_ms = res.mean_ms * (1.0 - res.cpu_wait_share)
    return res.min_ms <= budget_ms and link_ms <= budget_ms


class ModbusSampler(Sampler):
    """Software-polled sampler: one Modbus block read → one sample of the four channels."""

    hardware_timed = False

    def __init__(
        self,
        link: ModbusLink,
        channels: list[AnalogChannel],
        clock: Clock,
        *,
        function: int = FC_READ_HOLDING,
        sample_rate_Hz: float = 500.0,
        allow_reduced_rate: bool = False,
        extra: dict[str, Callable[[], float]] | None = None,
        extra_stats: dict[str, Callable[[], dict[str, Any]]] | None = None,
    ) -> None:
        self.link = link
        self.channels = channels
        self.clock = clock
        self.function = function
        self.sample_rate_Hz = float(sample_rate_Hz)
        self.requested_rate_Hz = float(sample_rate_Hz)
        self.allow_reduced_rate = bool(allow_reduced_rate)
        self.extra = dict(extra or {})
        self.extra_stats = dict(extra_stats or {})
        names = {c.name for c in channels} | set(self.extra)
        missing = [n for n in SAMPLED if n not in names]
        if missing:
            raise ValueError(f"no source for channel(s) {', '.join(missing)}")
        self.start_address = min(c.address for c in channels)
        end = max(c.address + c.codec.width for c in channels)
        self.count = end - self.start_address
        if self.count > 125:
            raise ValueError(
                f"analog inputs span {self.count} registers; one Modbus read carries at most 125"
            )
        self.last_probe: ProbeResult | None = None
        #: other devices to release with the sampler (serial indicator, ITV regulators)
        self.closers: list[Callable[[], None]] = []
        #: what else a sample period costs on this link: the runner commands the cylinder
        #: regulator once per sample, so the probe times read + that write (of 0 MPa: the
        #: regulator is vented during the probe anyway)
        self.probe_companion: Callable[[], None] | None = None

    # ----------------------------------------------------------------- reading
    def _convert(self, regs: list[int]) -> dict[str, float]:
        out: dict[str, float] = {}
        for ch in self.channels:
            i = ch.address - self.start_address
            raw = ch.codec.decode(regs[i : i + ch.codec.width])
            if not np.isfinite(raw) or (
                ch.raw_range is not None and not ch.raw_range[0] <= raw <= ch.raw_range[1]
            ):
                raise ValueOutOfRange(
                    f"{self.link.adapter.name}: channel {ch.name} raw value {raw:.4g} "
                    f"outside {ch.raw_range} (register {ch.address})"
                )
            out[ch.name] = ch.calibration(raw)
        return out

    def read_values(self) -> dict[str, float]:
        """One block read, calibrated (no timestamp)."""
        values = self.link.read_registers(
            self.start_address, self.count, self.function, self._convert
        )
        for name, source in self.extra.items():
            values[name] = source()
        return values

    def read_block(self) -> Block:
        t0 = self.clock.now()
        v = self.read_values()
        t1 = self.clock.now()
        return Block.single(
            0.5 * (t0 + t1), v["position"], v["force"], v["muscle_pressure"], v["cylinder_pressure"]
        )

    def tare(self, channel: str = "force", n: int = 50) -> float:
        """Zero ``channel`` on the mean of ``n`` readings (load cell unloaded); returns the tare."""
        idx = next((i for i, c in enumerate(self.channels) if c.name == channel), None)
        if idx is None:
            raise RigError(f"{channel}: not a Modbus channel of this rig, cannot tare")
        mean = float(np.mean([self.read_values()[channel] for _ in range(n)]))
        ch = self.channels[idx]
        cal = Calibration(ch.calibration.coefficients, ch.calibration.tare + mean)
        self.channels[idx] = AnalogChannel(ch.name, ch.address, ch.codec, cal, ch.raw_range)
        return cal.tare

    # ----------------------------------------------------------------- timing honesty
    def probe_rate(self, n: int = 300, rate_Hz: float | None = None) -> ProbeResult:
        """Time ``n`` back-to-back sample cycles (block read + regulator write) on the link."""
        extra = self.probe_companion
        for _ in range(min(PROBE_WARMUP, n)):
            self.read_values()
        lat = np.empty(n)
        waited0, wall0 = cpu_wait_s(), time.perf_counter()
        for i in range(n):
            t0 = time.perf_counter()
            self.read_values()
            if extra is not None:
                extra()
            lat[i] = time.perf_counter() - t0
        waited1, wall = cpu_wait_s(), time.perf_counter() - wall0
        share = float("nan")
        if waited0 is not None and waited1 is not None and wall > 0:
            share = (waited1 - waited0) / wall
        ms = lat * 1e3
        p95 = float(np.percentile(ms, 95))
        budget_ms = PERIOD_BUDGET * 1e3 / float(rate_Hz or self.requested_rate_Hz)
        res = ProbeResult(
            n=n,
            mean_ms=float(ms.mean()),
            p50_ms=float(np.median(ms)),
            p95_ms=p95,
            p99_ms=float(np.percentile(ms, 99)),
            max_ms=float(ms.max()),
            jitter_ms=float(ms.std()),
            max_rate_Hz=float(1e3 / ms.mean()),
            sustainable_Hz=float(PERIOD_BUDGET * 1e3 / float(np.median(ms))),
            over_budget=float(np.mean(ms > budget_ms)),
            min_ms=float(ms.min()),
            cpu_wait_share=share,
        )
        self.last_probe = res
        return res

    def check_rate(self, rate_Hz: float | None = None, n: int = 300) -> ProbeResult:
        """Probe, then accept ``rate_Hz``, lower it (``allow_reduced_rate``) or refuse.

        A probe that falls short is repeated once and the faster of the two kept.  Raises
        :class:`RigError` with one line when the link cannot sustain the rate and a
        reduced rate was not allowed, and when the computer was too busy to judge the link
        (:func:`too_busy_to_judge`: the reads may have been slow because the driver waited
        for a CPU, which says nothing about the link).  Sets :attr:`sample_rate_Hz` to the
        rate to run at.
        """
        rate = float(rate_Hz or self.requested_rate_Hz)
        res = self.probe_rate(n, rate)
        if res.sustainable_Hz < rate and n > 0:
            # one more probe before refusing or lowering the rate: a stall of the host
            # (another process, a hypervisor pause) during the first one says nothing
            # about the link; the faster of the two medians is the link's
            again = self.probe_rate(n, rate)
            if again.p50_ms < res.p50_ms:
                res = again
            self.last_probe = res
        if res.sustainable_Hz >= rate:
            self.sample_rate_Hz = rate
            return res
        where = self.link.name
        too_busy = (
            f"{where}: this computer was too busy to judge the link: during the rate probe "
            f"pmalab's threads, summed, waited for a CPU {100 * res.cpu_wait_share:.0f} % of "
            f"the time, and block reads took {res.p50_ms:.2f} ms (median) though the fastest took "
            f"{res.min_ms:.2f} ms; close other programs and connect again"
        )
        if not self.allow_reduced_rate:
            if too_busy_to_judge(res, PERIOD_BUDGET * 1e3 / rate):
                raise RigError(too_busy)
            raise RigError(
                f"{where}: block reads take {res.p50_ms:.2f} ms (median; p95 {res.p95_ms:.2f} ms), "
                f"sustainable about {res.sustainable_Hz:.0f} Hz < {rate:.0f} Hz requested; "
                "use a faster link or set allow_reduced_rate = true in the rig file"
            )
        fallback = [r for r in FALLBACK_RATES_HZ if r <= min(res.sustainable_Hz, rate)]
        if not fallback:
            if too_busy_to_judge(res, PERIOD_BUDGET * 1e3 / FALLBACK_RATES_HZ[-1]):
                raise RigError(too_busy)
            raise RigError(
                f"{where}: sustainable rate {res.sustainable_Hz:.1f} Hz is too low to record"
            )
        self.sample_rate_Hz = fallback[0]
        return res

    def stats(self) -> dict[str, Any]:
        """Fault counters of the link(s), for the run's metadata."""
        out: dict[str, Any] = {"modbus": self.link.stats.as_dict()}
        for name, fn in self.extra_stats.items():
            out[name] = fn()
        return out

    def close(self) -> None:
        """Release the Modbus link and every device registered in :attr:`closers`."""
        for close in self.closers:
            try:
                close()
            except Exception:
                pass
        self.closers.clear()
        self.link.close()


class ModbusAnalogOutput(PressureRegulator):
    """A regulator driven by an analog output register (value MPa → raw volts → register).

    :meth:`vent` writes the zero value (FC16) and is *confirmed* when the device
    acknowledges the write and the register reads back (FC3) as that value; a device that
    refuses to read its outputs back (exception 01/02) is confirmed by the acknowledgement
    alone.  No acknowledgement, or a read-back other than zero, is a FAILED vent.
    """

    def __init__(
        self,
        link: ModbusLink,
        address: int,
        codec: RegisterCodec,
        calibration: Calibration,
        raw_range: tuple[float, float] = (0.0, 10.0),
        max_pressure_MPa: float = 0.9,
        name: str = "regulator",
    ) -> None:
        self.link = link
        self.address = address
        self.codec = codec
        self.calibration = calibration
        self.raw_range = raw_range
        self.max_pressure_MPa = float(max_pressure_MPa)
        self.name = name
        self.last_command_MPa = 0.0

    def raw_for(self, mpa: float) -> float:
        """The analog-output value commanding ``mpa`` MPa, clamped to the output range."""
        raw = self.calibration.inverse(mpa, self.raw_range)
        return min(max(raw, self.raw_range[0]), self.raw_range[1])

    def set_pressure(self, mpa: float) -> None:
        if not -1e-9 <= mpa <= self.max_pressure_MPa + 1e-9:
            raise RigError(
                f"{self.name}: command {mpa:.4f} MPa outside 0–{self.max_pressure_MPa} MPa"
            )
        self.link.write_registers(self.address, self.codec.encode(self.raw_for(max(mpa, 0.0))))
        self.last_command_MPa = float(mpa)

    def vent(self) -> VentResult:
        """Command 0 MPa; the result says whether the device confirmed it (never raises)."""
        return self.start_vent()()

    def start_vent(self) -> Callable[[], VentResult]:
        """Write the zero value now; the returned confirmation reads the register back."""
        raw0 = self.raw_for(0.0)
        zero = self.codec.encode(raw0)
        link = self.link
        try:
            link.write_registers(self.address, zero)
        except Exception as exc:  # vent must never raise: it runs on every exit path
            last = link.last_error if link.last_error is not None else exc
            res = VentResult.failed(
                f"zero write to register {self.address} not acknowledged after "
                f"{link.retries + 1} attempts; last: {one_line(last)}"
            )
            return lambda: res
        self.last_command_MPa = 0.0
        return lambda: self._confirm_vent(zero, raw0)

    def _confirm_vent(self, zero: list[int], raw0: float) -> VentResult:
        link = self.link
        try:
            back = link.read_registers(self.address, len(zero), FC_READ_HOLDING)
        except Exception as exc:
            last = link.last_error if link.last_error is not None else exc
            how = (
                "the device does not read outputs back"
                if isinstance(last, DeviceExceptionReply) and last.code in (1, 2)
                else f"read-back failed: {one_line(last)}"
            )
            return VentResult.confirmed(
                f"zero write to register {self.address} acknowledged by {link.adapter.name}; {how}"
            )
        if list(back) != list(zero):
            return VentResult.failed(
                f"zero write to register {self.address} acknowledged, but it reads back "
                f"{self.codec.decode(list(back)):.4g} instead of {raw0:g}"
            )
        return VentResult.confirmed(
            f"write acknowledged by {link.adapter.name}, register {self.address} reads back {raw0:g}"
        )


class ManualMuscleSupply(MusclePressureSupply):
    """A hand-set regulator: the operator is asked to turn it; the runner waits for the reading."""

    automatic = False

    def request(self, mpa: float, prompt: Callable[[str], None] | None = None) -> None:
        if prompt is not None:
            prompt(f"set the muscle pressure regulator to {mpa:.3f} MPa")
