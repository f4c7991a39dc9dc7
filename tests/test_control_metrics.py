"""Step metrics against analytic second-order responses (python-control step_info definitions)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from pmalab.control.metrics import square_steps, step_info, summarize

DT = 0.002


def second_order(t: np.ndarray, zeta: float, wn: float) -> np.ndarray:
    """Unit step response of wn²/(s² + 2ζwn·s + wn²), 0 < ζ < 1."""
    wd = wn * math.sqrt(1 - zeta * zeta)
    phi = math.acos(zeta)
    return 1 - np.exp(-zeta * wn * t) * np.sin(wd * t + phi) / math.sqrt(1 - zeta * zeta)


def _analytic_times(zeta: float, wn: float, band: float = 0.02) -> tuple[float, float, float]:
    """(t10, t90, t_settle) of the analytic response, by root finding."""
    def y(t):
        return float(second_order(np.array([t]), zeta, wn)[0])
    tp = math.pi / (wn * math.sqrt(1 - zeta * zeta))
    t10 = brentq(lambda t: y(t) - 0.1, 1e-9, tp)
    t90 = brentq(lambda t: y(t) - 0.9, 1e-9, tp)
    # last exit from the ±band: scan the extrema (every half damped period) backwards
    td = tp
    k = 1
    while math.exp(-zeta * wn * k * td) / 1.0 * 1.0 > band * 0.5 and k < 200:
        k += 1
    grid = np.arange(0, (k + 2) * td, 1e-4)
    outside = np.flatnonzero(np.abs(second_order(grid, zeta, wn) - 1) >= band)
    i = int(outside[-1])
    ts = brentq(lambda t: abs(y(t) - 1) - band, grid[i], grid[i + 1])
    return t10, t90, ts


@pytest.mark.parametrize("zeta,wn", [(0.2, 3.0), (0.45, 8.0), (0.7, 2.0)])
def test_step_info_matches_the_analytic_second_order_response(zeta, wn):
    t = np.arange(0, 12.0, DT)
    y = second_order(t, zeta, wn)
    info = step_info(t, y, y_final=1.0)
    mp = 100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta * zeta))
    t10, t90, ts = _analytic_times(zeta, wn)
    assert info.overshoot == pytest.approx(mp, abs=0.02)
    assert info.peak_time == pytest.approx(math.pi / (wn * math.sqrt(1 - zeta**2)), abs=DT)
    # sampled: the first sample at/after each crossing → within one sample of the analytic
    assert info.rise_time == pytest.approx(t90 - t10, abs=DT)
    assert info.settling_time == pytest.approx(ts, abs=DT)
    assert info.settled and info.reached


def test_step_info_on_a_down_step_with_offset_equals_the_up_step():
    """A square's down-step (15 → 0 mm) is the up-step mirrored: same numbers."""
    t = np.arange(0, 8.0, DT)
    up = 15.0 * second_order(t, 0.3, 5.0)
    a = step_info(t, up, y0=0.0, y_final=15.0)
    b = step_info(t, 15.0 - up, y0=15.0, y_final=0.0)
    for f in ("overshoot", "rise_time", "settling_time", "peak_time"):
        assert getattr(b, f) == pytest.approx(getattr(a, f), rel=1e-9)


def test_a_response_that_never_settles_is_flagged_not_given_a_time():
    t = np.arange(0, 10.0, DT)
    y = 1 - np.cos(3.0 * t)  # undamped: swings 0..2 around 1 for ever
    info = step_info(t, y, y_final=1.0)
    assert not info.settled
    assert math.isnan(info.settling_time)
    assert info.overshoot == pytest.approx(100.0, abs=0.1)


def test_overdamped_response_has_no_overshoot_and_the_first_order_rise_time():
    t = np.arange(0, 10.0, DT)
    tau = 0.5
    y = 1 - np.exp(-t / tau)
    info = step_info(t, y, y_final=1.0)
    assert info.overshoot == 0.0
    assert info.rise_time == pytest.approx(tau * math.log(9), abs=DT)  # 10→90 %: τ·ln 9
    assert info.settling_time == pytest.approx(tau * math.log(50), abs=DT)  # 2 %: τ·ln 50


def test_square_steps_finds_every_step_and_its_steady_state_error():
    """A first-order follower of a 0.1 Hz square 0 → 15 mm that stops 0.2 mm short."""
    t = np.arange(0, 20.0, DT)
    r = np.where((t % 10.0) < 5.0, 15.0, 0.0)
    target = np.where(r > 0, 14.8, 0.0)
    y = np.zeros_like(t)
    a = DT / 0.3
    for k in range(1, t.size):
        y[k] = y[k - 1] + a * (target[k] - y[k - 1])
    steps = square_steps(t, y, r, [0.0, 5.0, 10.0, 15.0])
    assert [s.t_step for s in steps] == [0.0, 5.0, 10.0, 15.0]
    assert steps[0].steady_state_error == pytest.approx(0.2, abs=0.005)
    assert steps[1].steady_state_error == pytest.approx(0.0, abs=0.005)
    assert all(s.info.overshoot < 1e-3 for s in steps)  # monotonic: none beyond round-off
    m = summarize("square", t, y, r, [0.0, 5.0, 10.0, 15.0])
    assert m["settled"] and m["steady_state_error"] == pytest.approx(0.2, abs=0.005)
    assert m["rise_time_s"] == pytest.approx(0.3 * math.log(9), abs=2 * DT)
