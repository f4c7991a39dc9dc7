"""Pressure variation: the muscle pressure is not constant during an "isobaric" run.

The muscle's volume changes with contraction and a slow manual regulator cannot hold the
pressure, so the *measured* muscle pressure p(t) wanders around the nominal p₀ (rising as
the muscle is stretched and its volume shrinks, recovering with the regulator's time
constant).  Tension is nearly proportional to pressure (F ≈ p·S(x)), so the force gains
(g₀ + g₁·x)·(p − p₀): the sensitivity ∂F/∂p (N/MPa) and its change along the
stroke (x absolute, so runs of one pressure level share g₀, g₁).  Uses the measured pressure channel, never the nominal value.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class PressureVariation(Effect):
    id = "pressure-variation"
    order = 4
    plant: ClassVar[dict[str, str] | None] = {"p0": "pv_g0", "p1": "pv_g1"}
    title = "Muscle pressure varying during the run (measured, not nominal)"
    explanation = (
        "An 'isobaric' test is held by a slow manual regulator while the muscle's volume "
        "changes with contraction, so the muscle pressure rises and falls during each cycle. "
        "Tension is nearly proportional to pressure; the base model, fitted at the nominal "
        "pressure, misses the part of the force that follows the measured pressure."
    )
    signature = (
        "Residual proportional to the measured pressure's deviation from nominal (binned "
        "residual against pressure deviation is a line), in phase with the pressure ripple "
        "rather than with position or velocity."
    )

    experiment = "repeat with a fast regulator or a large reservoir on the muscle line: the effect must vanish when the pressure stays constant"

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        # dF/dp of a DMSP-20 is of the order of F/p ≈ 2500 N/MPa; allow a wide margin
        lim = max(10.0 * force_scale / max(sig.p_nom, 0.05), 1e4)
        half = max(float(np.max(np.abs(sig.x))), 1e-3)
        return [
            Param(
                "pv_g0",
                0.0,
                -lim,
                lim,
                "N/MPa",
                doc="tension change per MPa of pressure deviation at x = 0",
            ),
            Param(
                "pv_g1",
                0.0,
                -lim / half,
                lim / half,
                "N/(MPa·mm)",
                doc="change of that sensitivity per mm of contraction",
            ),
        ]

    def force(self, sig: Signals, h: np.ndarray, theta: Mapping[str, float]) -> np.ndarray:
        dp = sig.p - sig.p_nom
        return (theta["pv_g0"] + theta["pv_g1"] * sig.x) * dp
