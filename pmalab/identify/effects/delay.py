"""Sensor delay: a time skew between the position and force channels.

Different sensor paths (an analogue filter in one amplifier, a buffered serial sensor, a
DAQ that samples channels in sequence) make the recorded position lag or lead the force by
τ seconds.  The model is then driven by the position τ later than recorded:
x_model(t) = x_rec(t + τ) (τ > 0: the position channel lags the force).  The derivatives
(:func:`pmalab.identify.signals.derivatives`) are shifted with it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


def shift_in_time(t: np.ndarray, y: np.ndarray, tau: float) -> np.ndarray:
    """y evaluated at t + tau by linear interpolation (ends held)."""
    if tau == 0.0:
        return y
    return np.interp(t + tau, t, y)


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
    #: of a campaign (diagnosis fits it per pressure group, pools the estimates and refits
    #: every group with the pooled τ).  This is what separates a delay from viscous
    #: friction, whose coefficient is free to change with pressure.
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
        return sig.with_position(
            shift_in_time(sig.t, sig.x, tau),
            shift_in_time(sig.t, sig.v, tau),
            shift_in_time(sig.t, sig.a, tau),
            None if sig.x_slide is None else shift_in_time(sig.t, sig.x_slide, tau),
        )
