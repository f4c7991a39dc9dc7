"""Nonlinear stiffness: a static force–contraction curve that is not a straight line.

The braid geometry (fibre angle approaching its locking angle) and the bladder's rubber
elasticity bend the static characteristic: McKibben tension falls faster than linearly as
the contraction nears its maximum.  Added as k₂·x² + k₃·x³ in the absolute contraction x
(not centred per run: runs of one pressure level share k₂, k₃, so the term must be the
same function of x in each of them).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class NonlinearStiffness(Effect):
    id = "nonlinear-stiffness"
    order = 3
    plant: ClassVar[dict[str, str] | None] = {"k2": "stiff_k2", "k3": "stiff_k3"}
    title = "Nonlinear (geometric / bladder) stiffness"
    explanation = (
        "The braid's fibre angle changes with contraction and the rubber bladder stiffens "
        "as it is strained, so the static tension–contraction curve bends (steeper near "
        "full contraction); the base model's k·x is a straight line. Modelled as "
        "k₂·x² + k₃·x³."
    )
    signature = (
        "Residual against position is a U or S curve, the same on both branches (the loop's "
        "centre line is curved), independent of velocity and frequency."
    )

    experiment = "run a slow loop over the full stroke: a curved static characteristic bends the loop's centre line the same way on both branches"

    #: a linear spring (the law's own k·x): no quadratic or cubic term
    absent: ClassVar[dict[str, float] | None] = {"stiff_k2": 0.0, "stiff_k3": 0.0}

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        xm = max(float(np.max(np.abs(sig.x))), 1e-3)
        # bounds: each term at most 10 force standard deviations at the largest contraction
        return [
            Param(
                "stiff_k2",
                0.0,
                -10.0 * force_scale / xm**2,
                10.0 * force_scale / xm**2,
                "N/mm²",
                doc="quadratic stiffness",
            ),
            Param(
                "stiff_k3",
                0.0,
                -10.0 * force_scale / xm**3,
                10.0 * force_scale / xm**3,
                "N/mm³",
                doc="cubic stiffness",
            ),
        ]

    def force(self, sig: Signals, h: np.ndarray, theta: Mapping[str, float]) -> np.ndarray:
        x = sig.x
        return (theta["stiff_k2"] + theta["stiff_k3"] * x) * x * x
