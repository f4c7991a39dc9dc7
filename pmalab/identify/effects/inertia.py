"""Inertia of the mass between the muscle and the load cell: F_cell = F_muscle − m·ẍ.

The end fitting, half the muscle and the rod between muscle and load cell accelerate with
the contraction; the load cell reads the muscle tension minus m·ẍ (ẍ: contraction
acceleration, mm/s², converted to m/s²).  m is allowed either sign because which side of
the load cell the moving mass sits on depends on the rig.  Visible only at higher test
frequencies (the term grows with ω²).

Acceleration is the second derivative of a measured position: differentiating twice
amplifies the sensor noise by ω_c², so the term uses the one derivative estimator's
acceleration (:func:`pmalab.identify.signals.derivatives`: position low-passed zero phase at
6× the test frequency, ≥ 2 Hz), not the drive position's wide band.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class Inertia(Effect):
    id = "inertia"
    order = 6
    plant: ClassVar[dict[str, str] | None] = {"mass": "inertia_m"}
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

    experiment = "repeat at a higher frequency (≥ 1 Hz): an inertial force grows with the square of the frequency, friction and delay effects only linearly"
    rate_dependent = True
    absent: ClassVar[dict[str, float] | None] = {"inertia_m": 0.0}

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        # bound: a mass whose inertial force alone is 3× the force's spread at the rms
        # acceleration (a broadband record above its resonance is mostly inertia)
        arms = float(np.sqrt(np.mean(sig.a**2))) * 1e-3 or 1e-3
        lim = max(3.0 * force_scale / arms, 1.0)
        return [
            Param("inertia_m", 0.0, -lim, lim, "kg", doc="moving mass between muscle and load cell")
        ]

    def force(self, sig: Signals, h: np.ndarray, theta: Mapping[str, float]) -> np.ndarray:
        return -theta["inertia_m"] * sig.a * 1e-3
