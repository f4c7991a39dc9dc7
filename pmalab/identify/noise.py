"""The measurement-noise floor of a force record, estimated from the record alone.

A model of the muscle can at best predict the force *without* the load cell's noise, so the
lowest normalised error any model can reach on a record is ``noise rms / std(force)``:
:func:`noise_floor_nrmse`.  Model errors are only meaningful against it (2× the floor: a
missing effect worth looking for; 1.05×: nothing left to explain).

Method (:func:`noise_sigma`)
----------------------------
1. **Remove the signal with a third-order difference.**  A PMA test moves at 0.1–2 Hz and
   is sampled at ~500 Hz; the third difference ``Δ³F[n] = F[n] − 3F[n−1] + 3F[n−2] − F[n−3]``
   multiplies a sinusoid of frequency f by ``(2·sin(π·f·Δt))³`` (1.6·10⁻⁵ at 2 Hz, 500 Hz)
   and removes any constant, ramp or parabola exactly, while a white noise of variance σ²
   comes out with variance ``20·σ²``.  With ``t`` given, the differences never span a gap
   in the time stamps (a step > 1.5× the median step splits the record).
2. **Robust scale.**  Hysteresis reversals, stick-slip of the cylinder seals or a trip give
   a few large third differences; a median-absolute-deviation scale flags values beyond
   4 MADs, and the rms of the rest (corrected for the 4σ truncation of a Gaussian) is the
   estimate — nearly as efficient as a plain standard deviation on Gaussian noise, and
   blind to sparse outliers.
3. **Coloured noise.**  A sensor's first-order lag (an amplifier's anti-alias filter, a
   load-cell indicator's time constant τ) applied *to the noise* makes it an AR(1) process
   with ``a = exp(−Δt/τ)``: neighbouring samples correlate and the third difference
   under-reads σ (by 30 % at τ = Δt).  The third difference taken at a stride of two
   samples tells which: its variance equals the stride-one variance for white noise and
   approaches twice it as ``a`` grows.  When the measured ratio exceeds 1 by more than two
   standard errors (its scatter over eight pieces of the record), it is inverted for ``a``
   (tabulated up to a = 0.8, τ ≈ 4.5 Δt: slower noise cannot be told from the signal) and
   σ² = var(Δ³F) / g(a), where g(a) is the variance gain of the third difference on a
   unit-variance AR(1) process (20 for white noise).  σ is the rms of the noise as it is
   *in the record* (after the lag): the floor a model of that record faces.  A lag applied
   to the signal before the noise is added (pmalab's simulated sensors) leaves the noise
   white, and the estimate then finds ``a ≈ 0``.

Assumptions: the noise is stationary over the record, white or AR(1) (first-order lag),
and larger than the signal's third difference (true for smooth PMA forces at ≥ 100 Hz
sampling; not for a zero-order-held serial load cell read faster than it updates).
Quantisation of step r adds r²/12 to the variance (as the floor does: it is part of what
no model can predict); below about half a step the noise is mostly quantisation error.

Pure numpy: no other pmalab import, so any tool can use it on any array.
"""

from __future__ import annotations

import math

import numpy as np

#: order of the difference that removes the slow signal
ORDER = 3
#: binomial coefficients of the ORDER-th difference, Δ³ = [1, −3, 3, −1]
_COEF = np.array([(-1) ** k * math.comb(ORDER, k) for k in range(ORDER + 1)], dtype=float)
#: values beyond this many robust standard deviations are outliers (signal events)
_CLIP = 4.0
#: variance of a unit Gaussian truncated at ±_CLIP (its rms underestimates σ by this)
_TRUNC_VAR = 1.0 - 2.0 * _CLIP * math.exp(-0.5 * _CLIP**2) / math.sqrt(2.0 * math.pi) / math.erf(
    _CLIP / math.sqrt(2.0)
)
#: the AR(1) coefficients over which the colour correction is tabulated: up to a lag of
#: τ ≈ 4.5 sample periods; beyond, lagged noise is too slow to tell from the signal
_A_GRID = np.linspace(0.0, 0.8, 401)
#: fewest third differences for an estimate
MIN_SAMPLES = 16
#: pieces of the record over which the scatter of the colour ratio is measured
_CHUNKS = 8


def _ar1_gain(a: float, stride: int = 1) -> float:
    """Variance of the third difference at ``stride`` of a unit-variance AR(1) noise (a)."""
    c = _COEF
    n = len(c)
    return float(sum(c[j] * c[m] * a ** (stride * abs(j - m)) for j in range(n) for m in range(n)))


_G1 = np.array([_ar1_gain(a, 1) for a in _A_GRID])  # 20 at a = 0, falling with a
#: var(Δ³ at stride 2) / var(Δ³ at stride 1): 1 for white noise, rising towards 2 with a
_RATIO = np.array([_ar1_gain(a, 2) for a in _A_GRID]) / _G1


def _segments(force: np.ndarray, t: np.ndarray | None) -> list[np.ndarray]:
    """Pieces of the record sampled without gaps (all of it when ``t`` is None)."""
    if t is None:
        return [force]
    t = np.asarray(t, dtype=float).ravel()
    if t.shape != force.shape:
        raise ValueError(f"time has {t.size} samples but force has {force.size}")
    dt = np.diff(t)
    if not np.all(np.isfinite(t)) or np.any(dt <= 0):
        raise ValueError("time stamps must be finite and strictly increasing")
    step = float(np.median(dt))
    cuts = np.flatnonzero(dt > 1.5 * step) + 1
    return list(np.split(force, cuts))


def _third_differences(segments: list[np.ndarray], stride: int) -> np.ndarray:
    """Δ³ at ``stride`` samples within each segment, concatenated."""
    coef = np.zeros(ORDER * stride + 1)
    coef[::stride] = _COEF
    parts = [np.convolve(s, coef, mode="valid") for s in segments if s.size > ORDER * stride]
    return np.concatenate(parts) if parts else np.empty(0)


def _robust_var(d: np.ndarray) -> float:
    """Variance of zero-mean differences with outliers (signal events) left out."""
    mad = 1.4826 * float(np.median(np.abs(d)))
    if mad == 0.0:  # more than half the differences are 0: quantisation dominates
        mad = float(np.sqrt(np.mean(d**2)))
    if mad == 0.0:
        return 0.0
    keep = np.abs(d) <= _CLIP * mad
    return float(np.mean(d[keep] ** 2)) / _TRUNC_VAR


def _colour_ratio(d1: np.ndarray, d2: np.ndarray, v1: float) -> float:
    """var(Δ³ at stride 2) / var(Δ³ at stride 1), or exactly 1 (white) unless the ratio is
    clear of its own scatter.

    On white noise the measured ratio scatters by ±10 % on a 1–4 s record; inverting that
    scatter would only ever *raise* σ (a ratio below 1 already means white), a bias of a few
    per cent.  The scatter is measured on ``_CHUNKS`` contiguous pieces of the record, and
    the colour correction applies only when the ratio exceeds 1 by more than two standard
    errors.
    """
    if v1 <= 0 or d2.size < _CHUNKS * MIN_SAMPLES:
        return 1.0
    ratio = _robust_var(d2) / v1
    pieces = [
        _robust_var(b) / max(_robust_var(a), 1e-300)
        for a, b in zip(np.array_split(d1, _CHUNKS), np.array_split(d2, _CHUNKS), strict=True)
    ]
    se = float(np.std(pieces, ddof=1)) / math.sqrt(_CHUNKS)
    return ratio if ratio > 1.0 + 2.0 * se else 1.0


def noise_sigma(force: np.ndarray, t: np.ndarray | None = None) -> float:
    """Rms of the measurement noise of a force record (N, the unit of ``force``).

    ``force``: 1-D samples at a constant rate; ``t``: their time stamps (s), optional — when
    given, the differences never span a gap in the sampling.  See the module docstring for
    the method (third differences, robust scale, AR(1) colour correction) and its
    assumptions.  Raises ``ValueError`` for fewer than ``MIN_SAMPLES`` usable samples or
    non-finite values.
    """
    f = np.asarray(force, dtype=float).ravel()
    if not np.all(np.isfinite(f)):
        raise ValueError("force has non-finite samples")
    segs = _segments(f, t)
    d1 = _third_differences(segs, 1)
    if d1.size < MIN_SAMPLES:
        raise ValueError(
            f"too few samples to estimate the noise ({f.size}; need ≥ {MIN_SAMPLES + ORDER})"
        )
    v1 = _robust_var(d1)
    d2 = _third_differences(segs, 2)
    # colour: white noise has the same Δ³ variance at strides 1 and 2, AR(1) noise more at 2
    ratio = _colour_ratio(d1, d2, v1)
    i = min(int(np.searchsorted(_RATIO, ratio)), len(_A_GRID) - 1)
    return math.sqrt(v1 / _G1[i])


def noise_floor_nrmse(force: np.ndarray, t: np.ndarray | None = None) -> float:
    """The lowest nrmse any model can reach on this record: ``noise_sigma / std(force)``.

    Pass the same samples the model's nrmse is computed on (e.g. the steady window), since
    nrmse normalises by that window's standard deviation.
    """
    f = np.asarray(force, dtype=float).ravel()
    sd = float(np.std(f))
    if sd == 0.0:
        raise ValueError("force is constant: nrmse is undefined")
    return noise_sigma(f, t) / sd
