"""A run whose excitation frequency is unknown (``frequency_Hz`` absent or 0) is filtered from
its own motion band: a broadband record is not low-passed as if it were a 0.5 Hz test."""

from __future__ import annotations

import numpy as np

from pmalab.identify.signals import Signals, filter_frequency_Hz, motion_band_Hz
from pmalab.runfile import Run


def _run(x: np.ndarray, fs: float, f: float | None) -> Run:
    t = np.arange(x.size) / fs
    return Run("r", t, x, 100.0 - 5.0 * x, np.full(x.size, 0.4),
               attrs={"frequency_Hz": f} if f is not None else {})


def test_a_multisine_with_frequency_zero_is_filtered_like_its_declared_band():
    fs, n = 750.0, 16384
    rng = np.random.default_rng(3)
    t = np.arange(n) / fs
    freqs = np.arange(5.0, 150.0, fs / 8192)
    x = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in freqs[::4])
    x = 0.5 * x / np.std(x) + 0.01 * rng.standard_normal(n)
    assert 100.0 < motion_band_Hz(t, x) <= 160.0
    unknown = Signals.from_run(_run(x, fs, 0.0))
    declared = Signals.from_run(_run(x, fs, 150.0))
    assert unknown.cutoff_Hz == declared.cutoff_Hz  # both at the cap, fs/5
    assert unknown.derivative_Hz == declared.derivative_Hz
    np.testing.assert_allclose(unknown.v, declared.v)


def test_a_slow_test_of_unknown_frequency_keeps_the_default_filters():
    fs = 500.0
    t = np.arange(20000) / fs
    x = 12.0 + 8.0 * np.sin(2 * np.pi * 0.15 * t) + 0.015 * np.random.default_rng(1).standard_normal(t.size)
    assert filter_frequency_Hz(_run(x, fs, None)) is None
    assert filter_frequency_Hz(_run(x, fs, 0.15)) == 0.15
