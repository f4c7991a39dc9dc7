"""Sensor delay: a time skew between the position and force channels.

Different sensor paths (an analogue filter in one amplifier, a buffered serial sensor, a
DAQ that samples channels in sequence) make the recorded position lag or lead the force by
τ seconds.  The model is then driven by the position τ later than recorded:
x_model(t) = x_rec(t + τ) (τ > 0: the position channel lags the force).  The derivatives
(:func:`pmalab.identify.signals.derivatives`) are shifted with it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
from numba import njit

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


def shift_in_time(t: np.ndarray, y: np.ndarray, tau: float) -> np.ndarray:
    """y evaluated at t + tau by linear interpolation (ends held)."""
    if tau == 0.0:
        return y
    return np.interp(t + tau, t, y)


def shift_all_in_time(t: np.ndarray, ys: Sequence[np.ndarray], tau: float) -> list[np.ndarray]:
    """Every y of ``ys`` evaluated at t + tau: :func:`shift_in_time` of each, the same numbers
    bit for bit, with the interval of each t + tau looked up once for all of them
    (:func:`_shift_rows`); each result is a row of one new array.  Where the time stamps do
    not rise strictly (or are fewer than two), :func:`shift_in_time` of each."""
    if tau == 0.0:
        return list(ys)
    n = int(np.shape(t)[0])
    if n >= 2 and ys:
        tc = np.ascontiguousarray(t, dtype=np.float64)
        Y = np.empty((len(ys), n))
        for r, y in enumerate(ys):
            Y[r] = y
        out = np.empty((len(ys), n))
        if _shift_rows(tc, float(tau), Y, out):
            return list(out)
    return [shift_in_time(t, y, tau) for y in ys]


@njit(cache=True, fastmath=False, error_model="numpy")
def _shift_rows(t, tau, Y, out):  # pragma: no cover - compiled (tested against np.interp)
    """Row r of ``out`` := ``np.interp(t + tau, t, Y[r])`` for every row, the same
    operations as NumPy's (q = t_i + τ; below t_0 the first value, above t_(n−1) the last,
    on a sample its value, else slope·(q − t_j) + y_j with slope = (y_(j+1) − y_j) /
    (t_(j+1) − t_j), the other end tried where that is NaN); returns False, writing
    nothing, unless the time stamps rise strictly."""
    n = t.shape[0]
    for i in range(n - 1):
        if not t[i + 1] > t[i]:
            return False
    rows = Y.shape[0]
    t0 = t[0]
    tn = t[n - 1]
    j = 0
    for i in range(n):
        q = t[i] + tau
        if not q >= t0:  # below the first stamp, or NaN
            for r in range(rows):
                out[r, i] = q if q != q else Y[r, 0]
            continue
        if q > tn:
            for r in range(rows):
                out[r, i] = Y[r, n - 1]
            continue
        while j + 1 < n and t[j + 1] <= q:  # the q rise with i: t_j <= q < t_(j+1)
            j += 1
        tj = t[j]
        if j == n - 1 or tj == q:
            for r in range(rows):
                out[r, i] = Y[r, j]
            continue
        d = t[j + 1] - tj
        u = q - tj
        for r in range(rows):
            a = Y[r, j]
            b = Y[r, j + 1]
            slope = (b - a) / d
            v = slope * u + a
            if v != v:
                v = slope * (q - t[j + 1]) + b
                if v != v and a == b:
                    v = a
            out[r, i] = v
    return True


class SensorDelay(Effect):
    id = "sensor-delay"
    order = 5
    title = "Time skew between the position and force channels"
    explanation = (
        "If the position channel lags (or leads) the force channel by a few milliseconds, "
        "every measured loop is sheared along the time axis: the force seems to anticipate "
        "the motion and the loop looks wider or narrower than the muscle's. Modelled by "
        "driving the law with the position shifted by τ (s)."
    )
    signature = (
        "Residual proportional to the loop slope times velocity (like viscous friction, but "
        "largest where the loop is steep, just after reversals); the residual's "
        "cross-correlation with the input peaks at a non-zero lag; phase error grows with "
        "frequency."
    )

    experiment = "repeat at two or more frequencies: a delay's phase error grows with frequency (ωτ) while viscous force grows with velocity amplitude; or time-stamp a sharp force step on both channels"
    rate_dependent = True
    absent: ClassVar[dict[str, float] | None] = {"delay_tau": 0.0}

    #: multi-start grid for τ (s) used by the diagnosis fitter: the least-squares cost of a
    #: time-shifted loop is multi-modal in τ (a local minimum wherever a shift lines up one
    #: feature of the loop, e.g. a reversal or a slack stretch), so a single descent from
    #: τ = 0 can stop short of the real lag.
    multistart: ClassVar[dict[str, tuple[float, ...]]] = {"delay_tau": (-0.08, -0.04, 0.04, 0.08)}
    #: τ is a property of the rig's sensor paths, not of the muscle: one value for every run
    #: of a campaign (pressure order 0 in the campaign's joint fit, whatever the other
    #: parameters' orders).  This is what separates a delay from viscous friction, whose
    #: coefficient is free to change with pressure.
    campaign_shared: ClassVar[tuple[str, ...]] = ("delay_tau",)

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        return [
            Param(
                "delay_tau",
                0.0,
                -0.1,
                0.1,
                "s",
                doc="position channel lag behind the force channel (s)",
            )
        ]

    def transform(self, sig: Signals, theta: Mapping[str, float]) -> Signals:
        tau = float(theta["delay_tau"])
        if tau == 0.0:
            return sig
        # the derivatives shift with the position (the one estimator's, not re-derived)
        ys = [sig.x, sig.v, sig.a] if sig.x_slide is None else [sig.x, sig.v, sig.a, sig.x_slide]
        got = shift_all_in_time(sig.t, ys, tau)
        return sig.with_position(got[0], got[1], got[2], got[3] if len(got) > 3 else None)
