"""Residual diagnostics on synthetic residuals with known patterns."""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.identify.diagnosis.diagnostics import (
    BINNED_UNITS,
    binned_mean,
    campaign_diagnostics,
    correlation,
    integrated_act,
    run_diagnostics,
)
from pmalab.identify.estimation.solver import n_eff
from pmalab.identify.signals import Signals


def _sig(f: float = 0.5, cycles: float = 4, fs: float = 500.0) -> Signals:
    t = np.arange(0, cycles / f, 1 / fs)
    x = 10.0 + 8.0 * np.sin(2 * np.pi * f * t)
    return Signals.from_arrays(t, x, 0.4, p_nom=0.4, frequency_Hz=f)


def test_velocity_proportional_residual_shows_as_a_line_through_zero() -> None:
    sig = _sig()
    rng = np.random.default_rng(3)
    model = 1000.0 - 40.0 * sig.x
    force = model - 1.5 * sig.v + rng.normal(0, 0.5, sig.t.shape)  # viscous-like residual
    d = run_diagnostics(sig, force, model)
    assert set(d["binned"]) == set(BINNED_UNITS)
    b = d["binned"]["velocity"]
    c, m = np.array(b["centers"]), np.array(b["mean"], dtype=float)
    slope = np.polyfit(c, m, 1)[0]
    assert slope == pytest.approx(-1.5, rel=0.05)
    # stretch branch (ẋ < 0): the model's tension is too low there
    br = d["binned"]["branch"]
    assert br["centers"] == [-1.0, 1.0] and br["mean"][0] > 5 and br["mean"][1] < -5
    assert "stretch branch, mid contraction" in d["worst_region"]
    assert "model tension too low" in d["worst_region"]
    # every bin's CI covers its mean with a plausible width, ACF bound is 1.96/√N
    assert all(ci > 0 for ci in b["ci95"] if ci is not None)
    assert d["acf"]["bound95"] == pytest.approx(1.96 / np.sqrt(sig.t.size))
    assert d["acf"]["values"][0] == pytest.approx(1.0)
    assert len(d["acf"]["lags_s"]) == len(d["acf"]["values"])


def test_cross_correlation_peaks_at_the_input_lag() -> None:
    sig = _sig()
    x = sig.x - sig.x.mean()
    lag = 50  # samples, 0.1 s
    r = np.roll(x, lag)
    c = correlation(r, x, 200)
    assert abs(int(np.argmax(c)) - 200 - lag) <= 2
    d = run_diagnostics(sig, 1000 + r, np.full_like(r, 1000.0))
    assert d["ccf_input"]["peak_lag_s"] == pytest.approx(0.1, abs=0.02)


def test_white_residual_is_white_and_cis_are_honest() -> None:
    rng = np.random.default_rng(7)
    r = rng.normal(0, 1, 20000)
    assert integrated_act(r) < 1.2
    assert n_eff(r) > 15000
    # smooth residual: τ_int large, CI inflated accordingly
    s = np.convolve(r, np.ones(100) / 100, mode="same")
    assert integrated_act(s) > 50
    b_white = binned_mean(np.linspace(0, 1, r.size), r, 1.0, "-")
    covered = [abs(m) <= ci for m, ci in zip(b_white["mean"], b_white["ci95"])]
    assert np.mean(covered) >= 0.75


def test_campaign_groups_by_pressure_and_frequency() -> None:
    items = [(0.3, 0.25, np.full(100, 1.0)), (0.3, 1.0, np.full(100, 3.0)),
             (0.5, 0.25, np.full(100, -2.0))]
    c = campaign_diagnostics(items)
    assert c["pressure_level"]["centers"] == [0.3, 0.5]
    assert c["pressure_level"]["mean"] == pytest.approx([2.0, -2.0])
    assert c["frequency"]["centers"] == [0.25, 1.0]
    assert c["frequency"]["rms"][1] == pytest.approx(3.0)


@pytest.mark.parametrize("n", [1, 2, 5, 1000, 2001])
def test_the_loop_phase_signal_is_scipys_hilbert_bit_for_bit(n: int) -> None:
    import scipy.signal

    from pmalab.identify.diagnosis.diagnostics import analytic_signal

    x = np.random.default_rng(n).normal(3.0, 7.0, n)
    z, ref = analytic_signal(x), scipy.signal.hilbert(x)
    assert z.dtype == ref.dtype and z.shape == ref.shape
    assert z.tobytes() == ref.tobytes()  # the same operations, so the same bits (even and odd n)


def test_a_diagnosis_does_not_import_scipy_signal_or_stats() -> None:
    # their package imports cost a diagnosis start-up time it never uses
    import subprocess
    import sys

    code = (
        "import sys\nimport pmalab.identify.cli, pmalab.identify.diagnosis.diagnose\n"
        "import pmalab.identify.diagnosis.diagnostics\n"
        "print(sorted(m for m in ('scipy.signal', 'scipy.stats') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["[]"], out.stdout
