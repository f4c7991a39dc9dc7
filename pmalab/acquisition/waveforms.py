"""Cylinder-pressure commands of a run (MPa), as functions of time since the run's zero.

Timeline of a run (``RunSpec``): ``settle_s`` at the preload command (default 0; muscle
already at its pressure), ``ramp_s`` raised-cosine ramp in (blending preload → waveform), ``cycles`` full periods, ``ramp_s`` ramp out,
ending at zero command.  The unit waveform is phased to start at −1 so the command starts
at ``offset − amplitude`` (0 for the seeds' ``magnitude`` runs) when the steady cycles
begin — a stretched muscle is a high cylinder pressure, so each cycle begins with the
muscle at its shortest.

Scalar functions of Python floats: the runner calls one per sample (500 Hz), which is
cheaper than numpy for a single value; :func:`command_array` vectorises for tests/plots.
"""

from __future__ import annotations

import math

import numpy as np

from pmalab.acquisition.protocol import RunSpec

TWO_PI = 2.0 * math.pi


def unit_wave(waveform: str, phase: float, square_edge: float = 0.05) -> float:
    """The unit waveform in [−1, 1] at ``phase`` (in cycles; 0 → −1, 0.5 → +1).

    * sine: −cos(2π·phase) (smooth, zero slope at the extremes);
    * triangle: linear from −1 to +1 over the first half period and back;
    * square: −1 for the first half, +1 for the second, each edge a raised-cosine
      transition lasting ``square_edge`` of a period (so the command never steps).
    """
    ph = phase - math.floor(phase)
    if waveform == "sine":
        return -math.cos(TWO_PI * ph)
    if waveform == "triangle":
        return 4.0 * ph - 1.0 if ph < 0.5 else 3.0 - 4.0 * ph
    if waveform == "steps":
        # the triangle held in 8 stairs each way (a static test's pressure steps)
        tri = 2.0 * ph if ph < 0.5 else 2.0 - 2.0 * ph
        return 2.0 * (math.floor(tri * 8.0 + 0.5) / 8.0) - 1.0
    if waveform == "square":
        e = square_edge
        if e <= 0:
            return -1.0 if ph < 0.5 else 1.0
        # edges centred on phase 0.25 (rising) and 0.75 (falling)
        for centre, sign in ((0.25, 1.0), (0.75, -1.0)):
            if abs(ph - centre) < e / 2:
                u = (ph - centre) / e + 0.5  # 0..1 across the edge
                return sign * -math.cos(math.pi * u)
        return 1.0 if 0.25 <= ph < 0.75 else -1.0
    raise ValueError(f"unknown waveform {waveform!r}")


def envelope(spec: RunSpec, t: float) -> float:
    """Raised-cosine envelope 0→1 over the ramp in, 1 while steady, 1→0 over the ramp out."""
    t0 = spec.settle_s
    if t < t0:
        return 0.0
    r = spec.ramp_s
    if r > 0 and t < t0 + r:
        return 0.5 - 0.5 * math.cos(math.pi * (t - t0) / r)
    if t <= spec.steady_end_s:
        return 1.0
    if r > 0 and t < spec.steady_end_s + r:
        return 0.5 + 0.5 * math.cos(math.pi * (t - spec.steady_end_s) / r)
    return 0.0


def command(spec: RunSpec, t: float) -> float:
    """Cylinder-pressure command (MPa) at ``t`` s after the run's zero; never negative.

    The waveform's phase counts from the start of the steady window, so the full-amplitude
    cycles begin (and, for whole ``cycles``, end) at the waveform's minimum.
    """
    env = envelope(spec, t)
    if env == 0.0:
        return spec.preload_MPa if t < spec.steady_start_s else 0.0
    phase = (t - spec.steady_start_s) * spec.frequency_Hz
    # full-amplitude part is periodic in the steady window; in the ramps the envelope
    # scales offset and amplitude together, so the command stays within [0, max]
    val = spec.offset_MPa + spec.amplitude_MPa * unit_wave(spec.waveform, phase, spec.square_edge)
    if t < spec.steady_start_s:  # ramp in: from the preload to the waveform
        return max(0.0, (1.0 - env) * spec.preload_MPa + env * val)
    return max(0.0, env * val)


def command_array(spec: RunSpec, t: np.ndarray) -> np.ndarray:
    """:func:`command` over an array of times (s)."""
    return np.array([command(spec, float(x)) for x in np.asarray(t, dtype=float)])


def unit_wave_array(waveform: str, phase: np.ndarray, square_edge: float = 0.05) -> np.ndarray:
    """Vectorised :func:`unit_wave` (same values)."""
    ph = phase - np.floor(phase)
    if waveform == "sine":
        return -np.cos(TWO_PI * ph)
    if waveform == "triangle":
        return np.where(ph < 0.5, 4.0 * ph - 1.0, 3.0 - 4.0 * ph)
    if waveform == "square":
        out = np.where((ph >= 0.25) & (ph < 0.75), 1.0, -1.0)
        e = square_edge
        if e > 0:
            for centre, sign in ((0.25, 1.0), (0.75, -1.0)):
                m = np.abs(ph - centre) < e / 2
                u = (ph[m] - centre) / e + 0.5
                out[m] = sign * -np.cos(np.pi * u)
        return out
    if waveform == "steps":
        tri = np.where(ph < 0.5, 2.0 * ph, 2.0 - 2.0 * ph)
        return 2.0 * (np.floor(tri * 8.0 + 0.5) / 8.0) - 1.0
    raise ValueError(f"unknown waveform {waveform!r}")


def envelope_array(spec: RunSpec, t: np.ndarray) -> np.ndarray:
    """Vectorised :func:`envelope` (same values)."""
    t0, r, te = spec.settle_s, spec.ramp_s, spec.steady_end_s
    env = np.where((t >= t0) & (t <= te), 1.0, 0.0)
    if r > 0:
        up = (t >= t0) & (t < t0 + r)
        env[up] = 0.5 - 0.5 * np.cos(np.pi * (t[up] - t0) / r)
        down = (t > te) & (t < te + r)
        env[down] = 0.5 + 0.5 * np.cos(np.pi * (t[down] - te) / r)
    return env


def command_samples(spec: RunSpec, rate_Hz: float, n: int) -> np.ndarray:
    """The command at the ``n`` sample deadlines ``k / rate_Hz`` (MPa): what the runner
    sends after sample ``k``; equal to :func:`command` at those times."""
    return command_block(spec, rate_Hz, 0, n)


def command_block(spec: RunSpec, rate_Hz: float, start: int, stop: int) -> np.ndarray:
    """The command at the deadlines ``k / rate_Hz`` for ``start ≤ k < stop`` (MPa): one
    block of :func:`command_samples`, so a long run is generated as it is played."""
    t = np.arange(start, stop) / rate_Hz
    env = envelope_array(spec, t)
    phase = (t - spec.steady_start_s) * spec.frequency_Hz
    val = spec.offset_MPa + spec.amplitude_MPa * unit_wave_array(
        spec.waveform, phase, spec.square_edge
    )
    before = t < spec.steady_start_s  # settle and ramp in: from the preload to the waveform
    out = np.where(before, (1.0 - env) * spec.preload_MPa + env * val, env * val)
    return np.maximum(0.0, out)
