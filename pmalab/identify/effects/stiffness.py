"""Nonlinear stiffness: a static force–contraction curve that is not a straight line.

The braid geometry (fibre angle approaching its locking angle) and the bladder's rubber
elasticity bend the static characteristic: McKibben tension falls faster than linearly as
the contraction nears its maximum.  Added as k₂·ξ² + k₃·ξ³ with ξ = x − x̄ (centred on
the run's mean contraction so the terms do not trade with k and c0).
"""

from __future__ import annotations

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class NonlinearStiffness(Effect):
    id = "nonlinear-stiffness"
    title = "Nonlinear (geometric / bladder) stiffness"
    explanation = (
        "The braid's fibre angle changes with contraction and the rubber bladder stiffens "
        "as it is strained, so the static tension–contraction curve bends (steeper near "
        "full contraction); the base model's k·x is a straight line. Modelled as "
        "k₂·ξ² + k₃·ξ³ with ξ the contraction about its mean."
    )
    signature = (
        "Residual against position is a U or S curve, the same on both branches (the loop's "
        "centre line is curved), independent of velocity and frequency."
    )

    experiment = (
        "run a slow loop over the full stroke: a curved static characteristic bends the loop's centre line the same way on both branches"
    )

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        half = max(0.5 * float(np.ptp(sig.x)), 1e-3)
        # bounds: each term at most 3 force standard deviations at the stroke end
        return [
            Param("stiff_k2", 0.0, -3.0 * force_scale / half**2, 3.0 * force_scale / half**2,
                  "N/mm²", doc="quadratic stiffness about the mean contraction"),
            Param("stiff_k3", 0.0, -3.0 * force_scale / half**3, 3.0 * force_scale / half**3,
                  "N/mm³", doc="cubic stiffness about the mean contraction"),
        ]

    def force(self, sig: Signals, h: np.ndarray, theta: dict[str, float]) -> np.ndarray:
        xi = sig.x - float(np.mean(sig.x))
        return theta["stiff_k2"] * xi**2 + theta["stiff_k3"] * xi**3
