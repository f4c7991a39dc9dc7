"""nidaqmx.Task: channels, timing, start/stop/close, read/write — strict like the driver."""

from __future__ import annotations

import time

import numpy as np

from nidaqmx import _device
from nidaqmx.constants import AcquisitionType, TerminalConfiguration, VoltageUnits
from nidaqmx.errors import DaqError

_MIN_BUFFER_S = 0.1  # this fake's rule: a continuous buffer below 100 ms of samples is refused


class _Chan:
    def __init__(self, device, name: str, lo: float, hi: float, terminal) -> None:
        self.device, self.name, self.lo, self.hi, self.terminal = device, name, lo, hi, terminal


class _Channels:
    def __init__(self, task: Task, kind: str) -> None:
        self._task, self._kind = task, kind

    def _add(self, physical_channel: str, lo: float, hi: float, terminal) -> None:
        t = self._task
        t._alive()
        if t._running:
            raise DaqError("Specified operation cannot be performed while the task is running.",
                           -200479, t.name)
        dev_name, _, chan = physical_channel.partition("/")
        dev = _device.DEVICES.get(dev_name)
        if dev is None:
            raise DaqError(f"Device identifier is invalid.\nDevice Specified: {dev_name}",
                           -200220, t.name)
        if dev.removed:
            raise DaqError("Device cannot be accessed.", -201003, t.name)
        prefix, limit = ("ai", dev.n_ai) if self._kind == "ai" else ("ao", dev.n_ao)
        if (not chan.startswith(prefix) or not chan[2:].isdigit() or int(chan[2:]) >= limit):
            raise DaqError(f"Physical channel specified does not exist on this device.\n"
                           f"Physical Channel Name: {chan}", -200170, t.name)
        if not (-10.0 <= lo < hi <= 10.0):
            raise DaqError(f"Requested value is not a supported value for this property "
                           f"(range [{lo}, {hi}] V; the device supports -10 to 10 V).",
                           -200077, t.name)
        if any(c.name == chan and c.device is dev for c in t._ai + t._ao):
            raise DaqError("Channel already in task.", -200489, t.name)
        (t._ai if self._kind == "ai" else t._ao).append(_Chan(dev, chan, lo, hi, terminal))

    def add_ai_voltage_chan(self, physical_channel, name_to_assign_to_channel="",
                            terminal_config=TerminalConfiguration.DEFAULT, min_val=-5.0,
                            max_val=5.0, units=VoltageUnits.VOLTS, custom_scale_name=""):
        if not isinstance(terminal_config, TerminalConfiguration):
            raise DaqError("Requested value is not a supported value for this property "
                           "(terminal configuration).", -200077, self._task.name)
        self._add(physical_channel, float(min_val), float(max_val), terminal_config)

    def add_ao_voltage_chan(self, physical_channel, name_to_assign_to_channel="", min_val=-10.0,
                            max_val=10.0, units=VoltageUnits.VOLTS, custom_scale_name=""):
        self._add(physical_channel, float(min_val), float(max_val), None)


class _Timing:
    def __init__(self, task: Task) -> None:
        self._task = task

    def cfg_samp_clk_timing(self, rate, source="", active_edge=None,
                            sample_mode=AcquisitionType.FINITE, samps_per_chan=1000):
        t = self._task
        t._alive()
        if t._running:
            raise DaqError("Specified operation cannot be performed while the task is running.",
                           -200479, t.name)
        if not t._ai:
            raise DaqError("Task contains no channels.", -200478, t.name)
        dev = t._ai[0].device
        if not (0 < rate <= dev.max_rate / len(t._ai)):
            raise DaqError(f"Requested value is not a supported value for this property.\n"
                           f"Property: SampClk.Rate\nRequested Value: {rate}\nMaximum: "
                           f"{dev.max_rate / len(t._ai)}", -200077, t.name)
        t._rate, t._mode, t._buffer = float(rate), sample_mode, int(samps_per_chan)


class _InStream:
    def __init__(self, task: Task) -> None:
        self._task = task

    @property
    def avail_samp_per_chan(self) -> int:
        t = self._task
        t._alive()
        if not t._running:
            raise DaqError("Specified operation cannot be performed when the task is not "
                           "running.", -200475, t.name)
        # samples the device clocked in since the last read, in real time, up to the buffer
        n = int((time.monotonic() - t._last_read_wall) * t._rate)
        return max(0, min(n, t._buffer))


class _OutStream:
    def __init__(self, task: Task) -> None:
        self._task = task


class Task:
    _count = 0

    def __init__(self, new_task_name: str = "") -> None:
        Task._count += 1
        self.name = new_task_name or f"_unnamedTask<{Task._count}>"
        self._ai: list[_Chan] = []
        self._ao: list[_Chan] = []
        self._rate: float | None = None
        self._mode = None
        self._buffer = 0
        self._running = False
        self._closed = False
        self._k = 0
        self._t0 = 0.0
        self._last_read_wall = 0.0
        self.ai_channels = _Channels(self, "ai")
        self.ao_channels = _Channels(self, "ao")
        self.timing = _Timing(self)
        self.in_stream = _InStream(self)
        self.out_stream = _OutStream(self)

    # -- life
    def _alive(self) -> None:
        if self._closed:
            raise DaqError("Task specified is invalid or does not exist.", -200088, self.name)

    def _devices(self):
        return {c.device for c in self._ai + self._ao}

    def _check_present(self) -> None:
        for d in self._devices():
            if d.removed:
                raise DaqError("Device cannot be accessed. Possible causes: Device is no longer "
                               "present in the system. Device is not powered.", -201003,
                               self.name)

    def start(self) -> None:
        self._alive()
        self._check_present()
        if self._rate is not None and self._mode == AcquisitionType.CONTINUOUS:
            if self._buffer < _MIN_BUFFER_S * self._rate:
                raise DaqError(f"Buffer is too small to start the acquisition: "
                               f"{self._buffer} samples per channel at {self._rate:g} S/s.",
                               -200608, self.name)
        self._running = True
        self._k = 0
        if self._ai:
            self._t0 = self._ai[0].device.t
        self._last_read_wall = time.monotonic()

    def stop(self) -> None:
        self._alive()
        self._running = False

    def close(self) -> None:
        if not self._closed:
            self._running = False
            self._closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- input
    def _acquire(self, n: int, timeout: float) -> np.ndarray:
        self._alive()
        if not self._running:
            raise DaqError("Read cannot be performed when the auto start property is false "
                           "and the task is not running or committed.", -200473, self.name)
        self._check_present()
        dev = self._ai[0].device
        k0 = self._k
        for kind, code, text in (
                ("removed", -201003, "Device cannot be accessed. Possible causes: Device is no "
                                     "longer present in the system."),
                ("overflow", -200279, "The application is not able to keep up with the hardware "
                                      "acquisition. Attempted to read samples that are no "
                                      "longer available."),
                ("timeout", -200284, "Some or all of the samples requested have not yet been "
                                     "acquired.")):
            at = dev.faults.get(kind)
            if at is not None and dev.samples_streamed + n > at:
                dev.faults.pop(kind)
                if kind == "removed":
                    dev.removed = True
                self._running = kind != "overflow" and self._running
                raise DaqError(text, code, self.name)
        out = np.empty((len(self._ai), n))
        for j in range(n):
            vals = dev.sample(self._t0 + (k0 + j) / self._rate)
            for i, c in enumerate(self._ai):
                out[i, j] = dev.volts(c.name, vals, c.lo, c.hi)
        self._k += n
        dev.samples_streamed += n
        self._last_read_wall = time.monotonic()
        return out

    def read(self, number_of_samples_per_channel=None, timeout=10.0):
        """On demand (no timing configured): one sample per channel, now."""
        self._alive()
        self._check_present()
        if self._rate is not None:
            raise DaqError("This fake supports read() only for on-demand tasks; use a stream "
                           "reader.", -200525, self.name)
        if not self._ai:
            raise DaqError("Task contains no channels.", -200478, self.name)
        dev = self._ai[0].device
        vals = dev.sample(dev.t + dev.poll_dt)
        v = [dev.volts(c.name, vals, c.lo, c.hi) for c in self._ai]
        return v[0] if len(v) == 1 else v

    # -- output
    def write(self, data, auto_start=True, timeout=10.0):
        self._alive()
        self._check_present()
        if not self._ao:
            raise DaqError("Write cannot be performed: the task contains no output channels.",
                           -200526, self.name)
        values = [data] if not isinstance(data, list | tuple | np.ndarray) else list(data)
        if len(values) != len(self._ao):
            raise DaqError("Write cannot be performed, because the number of channels in the "
                           "data does not match the number of channels in the task.", -200524,
                           self.name)
        for c, v in zip(self._ao, values, strict=True):
            v = float(v)
            if not (c.lo <= v <= c.hi):
                raise DaqError(f"Requested value is not a supported value for this property "
                               f"(write of {v} V outside [{c.lo}, {c.hi}] V).", -200561,
                               self.name)
            c.device.write_ao(c.name, v)
        return 1
