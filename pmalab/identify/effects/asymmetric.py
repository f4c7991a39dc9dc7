"""Asymmetric hysteresis: loops whose contracting and stretching branches differ in shape.

For Bouc-Wen this is Song & Der Kiureghian's generalized law (2006): the shape term
β·sgn(ẋh) + γ gains ψ_v·sgn(ẋ) + ψ_h·sgn(h) + ψ_x·sgn(x − x_c), so the loop can saturate
faster on one branch, on one side of zero h, or on one side of the mid-stroke x_c (here the
run's mean contraction, not fitted).  For Duhem the memory rate α and the reversal slope b
become direction dependent: α·(1 + ψ_α·σ), b·(1 + ψ_b·σ) with σ = sgn(ẋ).
"""

from __future__ import annotations

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class AsymmetricHysteresis(Effect):
    id = "asymmetric-hysteresis"
    title = "Asymmetric hysteresis (generalized Bouc-Wen / direction-dependent Duhem)"
    explanation = (
        "The braid and bladder do not load and unload symmetrically: the stretching branch "
        "of a McKibben loop is often steeper than the contracting one and the loop is "
        "fuller at high contraction. The symmetric Bouc-Wen/Duhem law forces mirror-image "
        "branches; the generalized law lets each branch and each end of the stroke saturate "
        "at its own rate."
    )
    signature = (
        "Residual that differs in shape between the two branches (binned residual against "
        "branch and position not mirror-symmetric), largest just after reversals and at one "
        "end of the stroke, unchanged with frequency."
    )

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        # the ψ's carry the same units as β, γ (sizes relative to them); Duhem's are ratios
        return [
            Param("asym_psi_v", 0.0, -5.0, 5.0, "1/mm·N^(1-n)",
                  doc="Bouc-Wen: shape term for the direction of motion (ψ_v); Duhem: ψ_α"),
            Param("asym_psi_h", 0.0, -5.0, 5.0, "1/mm·N^(1-n)",
                  doc="Bouc-Wen: shape term for the sign of h (ψ_h); Duhem: ψ_b"),
            Param("asym_psi_x", 0.0, -5.0, 5.0, "1/mm·N^(1-n)",
                  doc="Bouc-Wen: shape term for the side of mid-stroke (ψ_x); unused for Duhem"),
        ]

    def law_extras(self, law_name: str, sig: Signals, theta: dict[str, float]) -> dict[str, float]:
        if law_name == "duhem":
            # ratios, kept inside (−1, 1) so α and b keep their sign on both branches
            return {"psi_alpha": float(np.tanh(theta["asym_psi_v"])),
                    "psi_b": float(np.tanh(theta["asym_psi_h"]))}
        return {"psi_v": theta["asym_psi_v"], "psi_h": theta["asym_psi_h"],
                "psi_x": theta["asym_psi_x"], "x_c": float(np.mean(sig.x))}

    def fixed_for_law(self, law_name: str) -> tuple[str, ...]:
        return ("asym_psi_x",) if law_name == "duhem" else ()
