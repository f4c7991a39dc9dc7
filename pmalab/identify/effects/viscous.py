"""Viscous (rate-dependent) friction: F_visc = −c·ẋ.

Sign: ẋ is the contraction rate (mm/s).  While the muscle is stretched (ẋ < 0) friction in
the braid and between braid and bladder resists the motion and raises the tension, so with
c ≥ 0 the term −c·ẋ is positive then and negative while the muscle contracts.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class ViscousFriction(Effect):
    id = "viscous-friction"
    order = 1
    plant: ClassVar[dict[str, str] | None] = {"damping": "visc_c"}
    title = "Viscous (velocity-proportional) friction"
    explanation = (
        "Friction between the braid fibres and between braid and bladder grows with the "
        "sliding speed; a rate-independent hysteresis law cannot produce it, so the loop "
        "widens with frequency and amplitude. Modelled as a force −c·ẋ (c ≥ 0, N·s/mm)."
    )
    signature = (
        "Residual proportional to velocity: binned residual against velocity is a straight "
        "line through zero (positive while stretching), largest mid-stroke where |ẋ| peaks, "
        "growing with test frequency."
    )

    experiment = "repeat at two or more frequencies and amplitudes with a triangle wave: viscous force is constant along each constant-speed branch and jumps at reversals, while a channel delay only shifts the loop in time"
    rate_dependent = True
    absent: ClassVar[dict[str, float] | None] = {"visc_c": 0.0}

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        vmax = float(np.max(np.abs(sig.v))) or 1.0
        # bound: a viscous force up to 3 force standard deviations at the peak velocity
        return [
            Param(
                "visc_c",
                0.0,
                0.0,
                3.0 * force_scale / vmax,
                "N·s/mm",
                doc="viscous coefficient (tension rise per mm/s of stretching speed)",
            )
        ]

    def force(self, sig: Signals, h: np.ndarray, theta: Mapping[str, float]) -> np.ndarray:
        return -theta["visc_c"] * sig.v
