"""Inertia of the mass between the muscle and the load cell: F_cell = F_muscle − m·ẍ.

The end fitting, half the muscle and the rod between muscle and load cell accelerate with
the contraction; the load cell reads the muscle tension minus m·ẍ (ẍ: contraction
acceleration, mm/s², converted to m/s²).  m is allowed either sign because which side of
the load cell the moving mass sits on depends on the rig.  Visible only at higher test
frequencies (the term grows with ω²).
"""

from __future__ import annotations

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class Inertia(Effect):
    id = "inertia"
    title = "Inertia of the moving mass in series with the load cell"
    explanation = (
        "The masses between muscle and load cell (end fitting, rod, part of the muscle) "
        "must be accelerated, so the load cell reads the muscle tension minus m·ẍ. "
        "Negligible at 0.1 Hz, it grows with the square of the test frequency."
    )
    signature = (
        "Residual proportional to acceleration (binned residual against acceleration is a "
        "line), in antiphase with position on a sine test, largest at the stroke ends, and "
        "growing with frequency squared."
    )

    experiment = (
        "repeat at a higher frequency (≥ 1 Hz): an inertial force grows with the square of the frequency, friction and delay effects only linearly"
    )

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        amax = float(np.max(np.abs(sig.a))) * 1e-3 or 1e-3
        lim = max(3.0 * force_scale / amax, 1.0)
        return [Param("inertia_m", 0.0, -lim, lim, "kg",
                      doc="moving mass between muscle and load cell")]

    def force(self, sig: Signals, h: np.ndarray, theta: dict[str, float]) -> np.ndarray:
        return -theta["inertia_m"] * sig.a * 1e-3
