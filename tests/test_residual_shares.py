"""Where an unexplained residual lies: loop shape, above the motion band, session offset.

Synthetic residuals on a 0.5 Hz triangle with known parts; white noise of a stated sigma
is added to each and must not be counted as structure.
"""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.identify.diagnosis.diagnostics import residual_next_step, residual_shares

FS, F0, T = 200.0, 0.5, 40.0
SIGMA = 0.5  # N, the record's noise


def _motion():
    t = np.arange(0.0, T, 1.0 / FS)
    x = 10.0 * (2.0 * np.abs(2.0 * ((t * F0) % 1.0) - 1.0) - 1.0)  # triangle, ±10 mm
    return t, x


def _shares(r, seed=0):
    t, x = _motion()
    noise = np.random.default_rng(seed).normal(0.0, SIGMA, t.size)
    return residual_shares(t, x, r(t, x) + noise, SIGMA, F0)


def loop_error(t, x):
    v = np.gradient(x, t)
    return 2.0 * np.sign(v) * np.exp(-((x - 5.0) / 3.0) ** 2)  # a wrong loop corner


def rig_hum(t, x):
    return 2.0 * np.sin(2 * np.pi * 50.0 * t + 0.3)  # mains pickup, 100 f0


def offset(t, x):
    return np.full_like(t, 2.0)


def slow_drift(t, x):
    return 2.0 * np.sin(2 * np.pi * 0.0371 * t)  # not a harmonic, below the loop's rate


@pytest.mark.parametrize("part,key", [(loop_error, "loop"), (rig_hum, "above_band"),
                                      (offset, "offset"), (slow_drift, "other")])
def test_each_part_lands_in_its_own_share(part, key):
    for seed in range(5):
        d = _shares(part, seed)
        assert d[key] > 0.8, (key, d)
        assert sum(d[k] for k in ("loop", "above_band", "offset", "other")) <= 1.0 + 1e-9
        assert all(0.0 <= d[k] <= 1.0 for k in ("loop", "above_band", "offset", "other"))


def test_noise_alone_is_not_structure():
    """At the noise floor the structured power is a small fraction of the noise power."""
    for seed in range(10):
        d = _shares(lambda t, x: np.zeros_like(t), seed)
        assert d["structured_power_N2"] < 0.1 * SIGMA**2, d


def test_next_step_names_the_largest_share_and_weights_runs_by_their_power():
    a = _shares(loop_error, 1)
    b = _shares(lambda t, x: 0.3 * rig_hum(t, x), 2)  # a small hum on another run
    nxt = residual_next_step([a, b])
    assert nxt["next"] == "loop"
    assert "loop's shape" in nxt["text"]
    assert nxt["loop"] > nxt["above_band"] > 0.0
    assert residual_next_step([])["next"] is None


def test_fast_content_of_the_models_own_is_told_from_the_rigs():
    """A model term that differentiates a noisy position puts fast content into the
    prediction; a rig disturbance puts it into the measurement.  Same residual, two sources."""
    t, x = _motion()
    smooth = 500 + 8 * x
    hum = rig_hum(t, x)
    model_noisy = residual_shares(t, x, -hum, SIGMA, F0, model_force=smooth + hum)
    rig_noisy = residual_shares(t, x, hum, SIGMA, F0, model_force=smooth)
    assert model_noisy["above_band"] > 0.8 and rig_noisy["above_band"] > 0.8
    assert model_noisy["above_band_source"] == "model"
    assert rig_noisy["above_band_source"] == "measurement"
    assert "the model's own" in residual_next_step([model_noisy])["text"]
    assert "from the rig" in residual_next_step([rig_noisy])["text"]
