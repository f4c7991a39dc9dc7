"""The position filter keeps the sensor's noise out of a stiff friction element.

A Maxwell-slip element of 0.3 mm slip displacement and 120 N/mm (the project's own
Maxwell-slip muscle at 450 kPa) turns 0.015 mm of position noise into ±1.8 N while it sticks,
and every noise reversal near its slip force makes it slide: the prediction driven by the
measured position then differs from the one driven by the true path.  The default cut-off
(``CUTOFF_MULTIPLE`` × the excitation) must keep that difference well below the load cell's
own noise (≈ 4 N rms on the simulated rig).
"""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals

#: the own Maxwell-slip muscle's elements at 450 kPa (data/truth/hysteresis-maxwell-slip.toml)
THETA = {
    "k": -38.4, "c0": 1072.5, "h0": 0.0,
    "d1": 0.3, "k1": 121.7, "d2": 1.0, "k2": 31.3,
    "d3": 2.5, "k3": 8.35, "d4": 5.0, "k4": 3.13,
}
FS = 500.0  # Hz, the simulated rig's sample rate
POS_NOISE_MM = 0.015


@pytest.mark.parametrize(("f", "bound_N"), [(2.0, 0.85), (0.5, 0.45)])
def test_position_noise_costs_a_stiff_element_little(f: float, bound_N: float) -> None:
    # 4 cycles of a 4.5 mm sine (the held-out runs' stroke); the first cycle is skipped
    # (start state); rms of (prediction from noisy filtered x − from the true path),
    # averaged over 8 noise seeds.  At a 60× cut-off it is 0.98 N (2 Hz) and 0.54 N (0.5 Hz).
    m = ForceModel("maxwell-slip")
    t = np.arange(int(FS * 4 / f)) / FS
    x = 14.0 + 4.5 * np.sin(2 * np.pi * f * t)
    clean = m.predict(Signals.from_arrays(t, x, 0.45, p_nom=0.45, frequency_Hz=f, cutoff_Hz=1e9),
                      THETA)
    rms = []
    for seed in range(8):
        xn = x + POS_NOISE_MM * np.random.default_rng(seed).standard_normal(t.size)
        got = m.predict(Signals.from_arrays(t, xn, 0.45, p_nom=0.45, frequency_Hz=f), THETA)
        d = (got - clean)[t.size // 4:]
        rms.append(float(np.sqrt(np.mean(d**2))))
    assert np.mean(rms) <= bound_N, f"{f} Hz: {np.mean(rms):.3f} N"
