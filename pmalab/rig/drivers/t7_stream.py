"""LabJack T7 in stream mode over the Modbus TCP link pmalab already speaks (no LJM library).

``[rig] kind = "labjack-t7-stream"``: the same rig file as ``kind = "modbus"`` (transport,
inputs, outputs, limits; ``data/rigs/labjack-t7-stream.toml``) plus ``buffer_size_bytes``.
The inputs' addresses are the T7's ``AIN#`` registers (0, 2, 4, …); instead of one block
read per sample timed by the host, the T7 scans them on its own clock:

1. configure: ``STREAM_SCANRATE_HZ`` (4002, the protocol's rate; the device's actual rate is
   read back and used), ``STREAM_NUM_ADDRESSES`` (4004), ``STREAM_SETTLING_US`` (4008, 0 =
   automatic), ``STREAM_RESOLUTION_INDEX`` (4010, 0), ``STREAM_BUFFER_SIZE_BYTES`` (4012),
   ``STREAM_AUTO_TARGET`` (4016) = 16: command-response mode, ``STREAM_DATATYPE`` (4018) = 0,
   ``STREAM_NUM_SCANS`` (4020) = 0: continuous, ``STREAM_SCANLIST_ADDRESS#`` (4100 + 2i),
   then ``STREAM_ENABLE`` (4990) = 1;
2. read ``STREAM_DATA_CR`` (4500) with FC3: four header words (samples in this read, backlog
   in bytes, status, additional status) then the samples, 16-bit ADC codes converted to volts
   with the T7's nominal ±10 V calibration (or the rig file's ``ain_calibration``) and to
   engineering units with each channel's calibration;
3. stop: ``STREAM_ENABLE`` = 0.

Scan *k* is stamped *k / rate* on the device's clock.  When the host falls behind and the
device's buffer fills, the T7 skips scans (auto-recovery, status 2940), marks the place with
a scan of 0xFFFF dummy codes and reports the number skipped (status 2941): the dummies are
dropped and the time stamps jump by the skipped scans, which the runner records as a gap —
never as invented samples.  Status 2942 (scan overlap) or 2943 (recovery ended with an
overflow) stop the run safely, with the code named.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, cast

import numpy as np

from pmalab.errors import ConfigError, RigError
from pmalab.rig.base import Block, Clock, Rig, Sampler

STREAM_SCANRATE_HZ = 4002
STREAM_NUM_ADDRESSES = 4004
STREAM_SETTLING_US = 4008
STREAM_RESOLUTION_INDEX = 4010
STREAM_BUFFER_SIZE_BYTES = 4012
STREAM_AUTO_TARGET = 4016
STREAM_DATATYPE = 4018
STREAM_NUM_SCANS = 4020
STREAM_SCANLIST_ADDRESS = 4100
STREAM_DATA_CR = 4500
STREAM_ENABLE = 4990
#: STREAM_AUTO_TARGET bit 4: command-response (the host reads STREAM_DATA_CR)
AUTO_TARGET_CR = 16
#: one FC3 read carries at most 125 registers: 4 header words + samples
MAX_READ_REGISTERS = 125
#: a skipped scan's place, marked by the device with this code in every channel
DUMMY = 0xFFFF
STATUS = {
    0: "ok",
    2940: "auto-recovery active (the device's buffer overflowed: scans are being skipped)",
    2941: "auto-recovery ended (additional status = scans skipped)",
    2942: "scan overlap: a scan started before the previous one finished (rate too high)",
    2943: "auto-recovery ended with an overflow: the count of skipped scans was lost",
    2944: "stream burst complete",
}
FATAL = (2942, 2943)

#: the T7's nominal ±10 V calibration (binary code → volts), used unless the rig file gives
#: the device's own (``ain_calibration``, read from its flash with LabJack Kipling)
NOMINAL = {"positive_slope": 0.000315805780, "negative_slope": -0.000315805800, "center": 33523.0}


def float32_words(v: float) -> list[int]:
    b = struct.pack(">f", float(v))
    return [int.from_bytes(b[:2], "big"), int.from_bytes(b[2:], "big")]


def uint32_words(v: int) -> list[int]:
    return [(int(v) >> 16) & 0xFFFF, int(v) & 0xFFFF]


def words_float32(w: list[int]) -> float:
    return struct.unpack(">f", struct.pack(">HH", int(w[0]), int(w[1])))[0]


def codes_to_volts(codes: np.ndarray, cal: Mapping[str, float] = NOMINAL) -> np.ndarray:
    """16-bit stream codes → volts (±10 V range), piecewise-linear about the center code."""
    c = np.asarray(codes, dtype=float)
    center = cal["center"]
    return np.where(
        c < center, (center - c) * cal["negative_slope"], (c - center) * cal["positive_slope"]
    )


def volts_to_codes(volts: np.ndarray, cal: Mapping[str, float] = NOMINAL) -> np.ndarray:
    """The inverse (the emulator's ADC), clipped to 0…65534 (65535 marks a skipped scan)."""
    v = np.asarray(volts, dtype=float)
    center = cal["center"]
    c = np.where(v < 0, center - v / cal["negative_slope"], center + v / cal["positive_slope"])
    return np.clip(np.rint(c), 0, 65534).astype(np.int64)


class T7StreamSampler(Sampler):
    """Hardware-timed: the T7 scans its inputs on its own clock; the host reads the backlog."""

    hardware_timed = True

    def __init__(
        self,
        link: Any,
        channels: list,
        *,
        buffer_size_bytes: int = 32768,
        read_timeout_s: float = 1.0,
        ain_calibration: Mapping[str, float] | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.link = link
        self.channels = list(channels)
        self.n_ch = len(self.channels)
        self.rate_range_Hz = (1.0, 100_000.0 / max(self.n_ch, 1))  # the T7's 100 kS/s
        self.buffer_size_bytes = int(buffer_size_bytes)
        self.read_timeout_s = float(read_timeout_s)
        self.cal = dict(ain_calibration or NOMINAL)
        self.sleep = sleep
        self.sample_rate_Hz = 500.0
        self.k = 0
        self.running = False
        self.counts = {
            "reads": 0,
            "scans": 0,
            "skipped_scans": 0,
            "dummy_scans": 0,
            "empty_reads": 0,
        }
        self.last_status = 0
        self.closers: list[Callable[[], None]] = []

    def configure(self, rate_Hz: float) -> None:
        self.sample_rate_Hz = float(rate_Hz)

    def start(self) -> None:
        link = self.link
        try:
            link.write_registers(STREAM_ENABLE, uint32_words(0))  # a stream left running
        except Exception:
            pass
        try:
            link.write_registers(STREAM_SCANRATE_HZ, float32_words(self.sample_rate_Hz))
            link.write_registers(STREAM_NUM_ADDRESSES, uint32_words(self.n_ch))
            link.write_registers(STREAM_SETTLING_US, float32_words(0.0))
            link.write_registers(STREAM_RESOLUTION_INDEX, uint32_words(0))
            link.write_registers(STREAM_BUFFER_SIZE_BYTES, uint32_words(self.buffer_size_bytes))
            link.write_registers(STREAM_AUTO_TARGET, uint32_words(AUTO_TARGET_CR))
            link.write_registers(STREAM_DATATYPE, uint32_words(0))
            link.write_registers(STREAM_NUM_SCANS, uint32_words(0))
            for i, c in enumerate(self.channels):
                link.write_registers(STREAM_SCANLIST_ADDRESS + 2 * i, uint32_words(c.address))
            link.write_registers(STREAM_ENABLE, uint32_words(1))
            actual = words_float32(link.read_registers(STREAM_SCANRATE_HZ, 2))
        except Exception as exc:
            raise RigError(f"{link.adapter.name}: cannot start the T7 stream: {exc}") from None
        if actual > 0 and abs(actual - self.sample_rate_Hz) > 1e-6 * self.sample_rate_Hz:
            self.sample_rate_Hz = float(actual)  # the device's clock is the truth
        self.k = 0
        self.running = True

    def stop(self) -> None:
        if self.running:
            self.running = False
            try:
                self.link.write_registers(STREAM_ENABLE, uint32_words(0))
            except Exception:
                pass

    def close(self) -> None:
        self.stop()
        for c in self.closers:
            c()
        self.closers.clear()
        self.link.close()

    def _read(self) -> tuple[list[int], int, int, int, int]:
        want = (MAX_READ_REGISTERS - 4) // self.n_ch * self.n_ch
        regs = self.link.read_registers(STREAM_DATA_CR, 4 + want)
        self.counts["reads"] += 1
        n, backlog, status, info = (int(v) for v in regs[:4])
        return regs, n, backlog, status, info

    def read_block(self) -> Block:
        if not self.running:
            raise RigError("T7 stream: read with the stream not running")
        deadline = time.monotonic() + self.read_timeout_s
        period = 1.0 / self.sample_rate_Hz
        while True:
            try:
                regs, n, _backlog, status, info = self._read()
            except RigError:
                raise
            except Exception as exc:
                raise RigError(f"{self.link.adapter.name}: stream read failed: {exc}") from None
            self.last_status = status
            if status in FATAL:
                self.running = False
                raise RigError(f"T7 stream status {status} ({STATUS[status]}) after {self.k} scans")
            if status == 2941:  # the recovery ended: `info` scans were skipped
                self.k += info
                self.counts["skipped_scans"] += info
            data = np.asarray(regs[4 : 4 + n], dtype=np.int64)
            scans = data[: len(data) // self.n_ch * self.n_ch].reshape(-1, self.n_ch)
            dummy = np.all(scans == DUMMY, axis=1)
            self.counts["dummy_scans"] += int(dummy.sum())
            scans = scans[~dummy]
            if len(scans):
                break
            self.counts["empty_reads"] += 1
            if time.monotonic() > deadline:
                raise RigError(
                    f"T7 stream: no scans for {self.read_timeout_s:g} s "
                    f"(status {status}: {STATUS.get(status, 'unknown')})"
                )
            self.sleep(min(0.005, 4 * period))
        volts = codes_to_volts(scans, self.cal)
        out: dict[str, np.ndarray] = {}
        for i, c in enumerate(self.channels):
            out[c.name] = c.calibration.apply(
                volts[:, i], c.raw_range, f"T7 stream: AIN at address {c.address} ({c.name})"
            )
        m = len(scans)
        t = (self.k + np.arange(m)) / self.sample_rate_Hz
        self.k += m
        self.counts["scans"] += m
        zeros = np.zeros(m)
        return Block(
            t,
            out["position"],
            out["force"],
            out["muscle_pressure"],
            out.get("cylinder_pressure", zeros),
        )

    def stats(self) -> dict[str, Any]:
        """The link's fault counters and the stream's (scans, skipped, dummies, reads)."""
        return {
            "modbus": self.link.stats.as_dict(),
            "stream": dict(self.counts, last_status=self.last_status),
        }


def make_t7_stream_rig(
    section: Mapping[str, Any],
    rig_file: Path | None = None,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
) -> Rig:
    """``RIG_KINDS["labjack-t7-stream"]``: a ``modbus`` rig whose inputs are streamed."""
    from pmalab.config import check_keys
    from pmalab.rig.drivers.modbus_daq import ModbusSampler
    from pmalab.rig.drivers.rigfile import build_modbus_rig, parse_modbus_rig

    where = str(rig_file) if rig_file else "rig"
    section = dict(section)
    buf = section.pop("buffer_size_bytes", 32768)
    cal = section.pop("ain_calibration", None)
    if not isinstance(buf, int) or buf < 256 or buf & (buf - 1):
        raise ConfigError(
            f"{where}: rig.buffer_size_bytes: must be a power of 2 ≥ 256, got {buf!r}"
        )
    if cal is not None:
        check_keys(
            cal,
            set(NOMINAL),
            "{where}: rig.ain_calibration.{key}: unknown key (known: {known})",
            where=where,
        )
        cal = {**NOMINAL, **{k: float(v) for k, v in cal.items()}}
    section.setdefault("probe_samples", 0)  # the polled-rate probe does not apply
    spec = parse_modbus_rig(section, rig_file)
    if spec.function != 3:
        raise ConfigError(
            f'{where}: [rig.inputs] function: the stream reads STREAM_DATA_CR with FC3 ("holding")'
        )
    rig = build_modbus_rig(spec, seed=seed or 0, clock=clock, probe=False)
    polled = cast(ModbusSampler, rig.sampler)  # what build_modbus_rig makes
    sampler = T7StreamSampler(
        polled.link, polled.channels, buffer_size_bytes=buf, ain_calibration=cal
    )
    sampler.closers = list(getattr(polled, "closers", []))
    rig.sampler = sampler
    rig.info.update(
        {
            "kind": "labjack-t7-stream",
            "time_base": "device sample clock",
            "stream": {
                "buffer_size_bytes": buf,
                "ain_calibration": cal or NOMINAL,
                "mode": "command-response (STREAM_DATA_CR)",
            },
        }
    )
    rig.info.pop("timing", None)
    return rig
