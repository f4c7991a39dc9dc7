"""Register data types and sensor calibrations, as a rig TOML declares them.

A channel's raw value is an electrical quantity (volts for the LabJack's AIN registers, or
ADC counts for a scaled-INT16 module); its calibration maps raw → engineering units:

* two-point: ``points = [[raw0, value0], [raw1, value1]]`` (a straight line through both;
  PSE510/530-class pressure sensor 1–5 V → 0–1 MPa is ``[[1, 0], [5, 1]]``);
* polynomial: ``polynomial = [c0, c1, c2, ...]`` with value = Σ cᵢ·rawⁱ (nonlinear LVDT,
  load-cell amplifier with a measured curve);
* plus an optional ``tare`` subtracted afterwards (load-cell zero, in the channel's unit).

``raw_range = [lo, hi]`` is the electrically possible window (a 1–5 V sensor outside about
0.8–5.2 V means a broken wire or short): a reading outside it raises
:class:`~.adapters.ValueOutOfRange` and is retried, and then refused.

Register encodings (:class:`RegisterCodec`): ``float32`` (IEEE-754, two registers, word order
``big`` = high word first as on the LabJack T7, or ``little``), ``int16``/``uint16`` (one
register; raw = register × ``scale`` + ``offset``, e.g. 0..32000 counts for 0..10 V).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmalab.errors import ConfigError, RigError


# --------------------------------------------------------------------------- calibration
@dataclass(frozen=True)
class Calibration:
    """raw → value with a polynomial (a two-point line is a degree-1 polynomial), minus tare."""

    coefficients: tuple[float, ...]  # c0, c1, ... (value = Σ cᵢ rawⁱ)
    tare: float = 0.0

    @classmethod
    def two_point(
        cls, raw0: float, value0: float, raw1: float, value1: float, tare: float = 0.0
    ) -> Calibration:
        if raw1 == raw0:
            raise ValueError("two-point calibration needs two different raw values")
        slope = (value1 - value0) / (raw1 - raw0)
        return cls((value0 - slope * raw0, slope), tare)

    def __call__(self, raw: float) -> float:
        value = 0.0
        for c in reversed(self.coefficients):  # Horner
            value = value * raw + c
        return value - self.tare

    def apply(
        self, raw: np.ndarray, raw_range: tuple[float, float] | None, where: str
    ) -> np.ndarray:
        """A block of raw values (volts, of a hardware-timed stream) → values, refusing
        the first raw value outside ``raw_range`` (a broken wire or an unpowered sensor)
        with one :class:`~pmalab.errors.RigError` line naming ``where``."""
        v = np.asarray(raw, dtype=float)
        if raw_range is not None:
            bad = np.flatnonzero((v < raw_range[0]) | (v > raw_range[1]))
            if bad.size:
                raise RigError(
                    f"{where} reads {v[bad[0]]:.3f} V, outside raw_range "
                    f"{list(raw_range)}: broken wire or sensor unpowered?"
                )
        c = self.coefficients
        if len(c) == 2:
            return c[0] + c[1] * v - self.tare
        return np.polynomial.polynomial.polyval(v, np.asarray(c, dtype=float)) - self.tare

    def inverse(self, value: float, raw_range: tuple[float, float] | None = None) -> float:
        """The raw value giving ``value`` (for outputs and the emulators).

        Linear calibrations invert exactly; a polynomial is inverted by root finding inside
        ``raw_range`` (the real root nearest the range centre).
        """
        target = value + self.tare
        c = self.coefficients
        if len(c) == 1:
            raise ValueError("a constant calibration has no inverse")
        if len(c) == 2:
            return (target - c[0]) / c[1]
        poly = np.array(c[::-1], dtype=float)
        poly[-1] -= target
        roots = np.roots(poly)
        real = roots[np.abs(roots.imag) < 1e-9].real
        if real.size == 0:
            raise ValueError(f"calibration cannot reach {value}")
        centre = 0.0 if raw_range is None else 0.5 * (raw_range[0] + raw_range[1])
        return float(real[np.argmin(np.abs(real - centre))])

    def as_dict(self) -> dict[str, Any]:
        return {"polynomial": list(self.coefficients), "tare": self.tare}


def parse_calibration(table: Mapping[str, Any], where: str) -> Calibration:
    """Build a :class:`Calibration` from a TOML table (``points`` or ``polynomial``, ``tare``)."""
    tare = _float(table.get("tare", 0.0), f"{where}.tare")
    if "points" in table and "polynomial" in table:
        raise ConfigError(f"{where}: give either 'points' or 'polynomial', not both")
    if "points" in table:
        pts = table["points"]
        if (
            not isinstance(pts, Sequence)
            or len(pts) != 2
            or any(not isinstance(p, Sequence) or len(p) != 2 for p in pts)
        ):
            raise ConfigError(f"{where}.points: expected [[raw0, value0], [raw1, value1]]")
        (r0, v0), (r1, v1) = (
            (_float(a, f"{where}.points"), _float(b, f"{where}.points")) for a, b in pts
        )
        if r0 == r1:
            raise ConfigError(f"{where}.points: the two raw values must differ")
        return Calibration.two_point(r0, v0, r1, v1, tare)
    if "polynomial" in table:
        coeffs = table["polynomial"]
        if not isinstance(coeffs, Sequence) or len(coeffs) < 2:
            raise ConfigError(f"{where}.polynomial: expected [c0, c1, ...] with at least two terms")
        return Calibration(tuple(_float(c, f"{where}.polynomial") for c in coeffs), tare)
    raise ConfigError(f"{where}: missing calibration ('points' or 'polynomial')")


# --------------------------------------------------------------------------- registers
@dataclass(frozen=True)
class RegisterCodec:
    """How a value sits in 16-bit Modbus registers."""

    data_type: str = "float32"  # float32 | int16 | uint16
    word_order: str = "big"  # float32 only: big = high word at the lower address
    scale: float = 1.0  # integer types: raw = register * scale + offset
    offset: float = 0.0

    @property
    def width(self) -> int:
        """Registers per value."""
        return 2 if self.data_type == "float32" else 1

    def decode(self, regs: Sequence[int]) -> float:
        if self.data_type == "float32":
            hi, lo = (regs[0], regs[1]) if self.word_order == "big" else (regs[1], regs[0])
            return struct.unpack(">f", struct.pack(">HH", hi, lo))[0]
        r = int(regs[0])
        if self.data_type == "int16" and r >= 0x8000:
            r -= 0x10000
        return r * self.scale + self.offset

    def encode(self, value: float) -> list[int]:
        if self.data_type == "float32":
            hi, lo = struct.unpack(">HH", struct.pack(">f", float(value)))
            return [hi, lo] if self.word_order == "big" else [lo, hi]
        counts = round((value - self.offset) / self.scale)
        lo, hi = (-0x8000, 0x7FFF) if self.data_type == "int16" else (0, 0xFFFF)
        counts = min(max(counts, lo), hi)
        return [counts & 0xFFFF]


def parse_codec(table: Mapping[str, Any], defaults: Mapping[str, Any], where: str) -> RegisterCodec:
    """A :class:`RegisterCodec` from a channel table, falling back to the section defaults."""

    def get(key: str, default: Any) -> Any:
        return table.get(key, defaults.get(key, default))

    data_type = str(get("data_type", "float32")).lower()
    if data_type not in ("float32", "int16", "uint16"):
        raise ConfigError(f"{where}.data_type: {data_type!r} is not float32, int16 or uint16")
    word_order = str(get("word_order", "big")).lower()
    if word_order not in ("big", "little"):
        raise ConfigError(f"{where}.word_order: {word_order!r} is not 'big' or 'little'")
    scale = _float(get("scale", 1.0), f"{where}.scale")
    if scale == 0:
        raise ConfigError(f"{where}.scale: must not be zero")
    return RegisterCodec(
        data_type, word_order, scale, _float(get("offset", 0.0), f"{where}.offset")
    )


def _float(x: Any, where: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise ConfigError(f"{where}: expected a number, got {x!r}")
    return float(x)
