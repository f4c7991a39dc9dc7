"""The hand-written zero-phase Butterworth equals SciPy's butter + sosfiltfilt."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

from pmalab.identify.zero_phase import butter2, filtfilt2


@pytest.mark.parametrize("wn", [0.01, 0.05, 0.2, 0.6])
@pytest.mark.parametrize("n", [40, 151, 5000])
def test_matches_scipy_sosfiltfilt(wn: float, n: int) -> None:
    rng = np.random.default_rng(int(wn * 1000) + n)
    t = np.arange(n) / 500.0
    y = 10 + 8 * np.sin(2 * np.pi * 0.3 * t) + 0.2 * rng.standard_normal(n)
    padlen = min(150, n - 1)
    ref = sosfiltfilt(butter(2, wn, output="sos"), y, padtype="odd", padlen=padlen)
    b, a = butter2(wn)
    out = filtfilt2(b, a, y, padlen)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-9 * np.max(np.abs(y)))


def test_coefficients_match_scipy() -> None:
    for wn in (0.003, 0.1, 0.45, 0.9):
        b, a = butter2(wn)
        bs, as_ = butter(2, wn)
        np.testing.assert_allclose(b, bs, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(a, as_, rtol=1e-12, atol=1e-15)


def test_moving_mean_matches_scipy_uniform_filter() -> None:
    from scipy.ndimage import uniform_filter1d

    from pmalab.identify.metrics import moving_mean

    x = np.random.default_rng(3).standard_normal(1000).cumsum()
    for w in (2, 3, 10, 51):
        np.testing.assert_allclose(moving_mean(x, w), uniform_filter1d(x, w, mode="nearest"),
                                   atol=1e-9)
