"""Asymmetric hysteresis: loops whose stretching and contracting branches differ in shape.

Bouc-Wen: Song & Der Kiureghian's generalized law (2006) lets the shape term depend on the
direction of motion, β·sgn(ẋh) + γ + ψ_v·sgn(ẋ) + ψ_h·sgn(h) (see
:mod:`pmalab.identify.laws`), which changes each branch's decay rate — and with it
its saturation level, since the initial slope A is common to both.  Braid friction also
has a different *initial* stiffness on each branch (different pre-sliding lengths), so we
add a direction-dependent slope: the law integrates the path dx' = (1 + ψ_a·σ)·dx
(σ = sgn(ẋ)), which scales both A and the decay rate of one branch.  All three enter the
law through its extras, so h is integrated once.

Loops of a McKibben muscle are also not point-symmetric along the stroke: the braid
presses harder on the bladder where the muscle is stretched, so the loop is wide at low
contraction and narrow at high contraction.  Both laws therefore get a position-dependent
loop width: h → h·(1 + g·x), x the absolute contraction (mm; shared by every run of a
pressure level).

Duhem (Coleman–Hodgdon): the memory rate α and the reversal slope b become direction
dependent, α·(1 + ψ_α·σ), b·(1 + ψ_b·σ), through the law's own extras.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.laws import LAWS
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class AsymmetricHysteresis(Effect):
    id = "asymmetric-hysteresis"
    order = 2
    plant: ClassVar[dict[str, str] | None] = {"hx": "asym_g"}
    title = "Asymmetric hysteresis (generalized Bouc-Wen / direction-dependent Duhem)"
    explanation = (
        "The braid and bladder do not load and unload symmetrically: friction and the "
        "pre-sliding stiffness differ between stretching and contracting, so the two "
        "branches of the loop have different shapes. The symmetric Bouc-Wen/Duhem law forces "
        "mirror-image branches; the generalized law (Song & Der Kiureghian) gives each "
        "direction its own slope and saturation."
    )
    signature = (
        "Residual that differs between the two branches (binned residual against branch "
        "and position not mirror-symmetric), largest just after reversals, unchanged with "
        "frequency."
    )
    experiment = (
        "record minor loops (small reversals at several points of the stroke) at a low "
        "frequency: branch asymmetry changes the shape after every reversal in the same way"
    )

    #: symmetric branches: no direction-dependent slope or decay, a loop of constant width
    absent: ClassVar[dict[str, float] | None] = {
        "asym_psi_a": 0.0,
        "asym_psi_v": 0.0,
        "asym_psi_h": 0.0,
        "asym_g": 0.0,
    }

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        return [
            Param(
                "asym_psi_a",
                0.0,
                -0.95,
                0.95,
                "-",
                doc="Bouc-Wen: direction-dependent slope, dx' = (1 + ψ_a·σ)dx; held for the other laws",
            ),
            Param(
                "asym_psi_v",
                0.0,
                -5.0,
                5.0,
                "1/mm",
                doc="Bouc-Wen: decay-rate term for the direction of motion (ψ_v); Duhem: ψ_α; held for element laws",
            ),
            Param(
                "asym_psi_h",
                0.0,
                -5.0,
                5.0,
                "1/mm",
                doc="Bouc-Wen: decay-rate term for the sign of h (ψ_h); Duhem: ψ_b; held for element laws",
            ),
            # the width factor 1 + g·x stays positive over the stroke (x ≤ 30 mm)
            Param(
                "asym_g",
                0.0,
                -0.03,
                0.2,
                "1/mm",
                doc="loop width change per mm of contraction (h scaled by 1 + g·x)",
            ),
        ]

    def fixed_for_law(self, law_name: str) -> tuple[str, ...]:
        # a shape term enters only through the law's extras: a law that does not accept it
        # (Duhem has no path-length term; the element laws, whose loops are set by their
        # elements, accept none) leaves it without any effect on the force, so it is held,
        # not estimated (a column of zeros would only slow the fit down)
        law = LAWS.get(law_name)
        if law is None:  # a law not registered: nothing known, everything estimated
            return ()
        accepted = set(law.extras)
        uses = {
            "asym_psi_a": {"psi_a"},
            "asym_psi_v": {"psi_v", "psi_alpha"},
            "asym_psi_h": {"psi_h", "psi_b"},
        }
        return tuple(n for n, extras in uses.items() if not extras & accepted)

    def law_extras(
        self, law_name: str, sig: Signals, theta: Mapping[str, float]
    ) -> dict[str, float]:
        if law_name == "duhem":
            # ratios kept inside (−1, 1) so α and b keep their sign on both branches
            return {
                "psi_alpha": float(np.tanh(theta["asym_psi_v"])),
                "psi_b": float(np.tanh(theta["asym_psi_h"])),
            }
        # Bouc-Wen: the generalized shape terms and the direction-dependent path length
        # (the law integrates dx' = (1 + ψ_a·σ)·dx itself, so h is computed once)
        return {
            "psi_v": float(theta["asym_psi_v"]),
            "psi_h": float(theta["asym_psi_h"]),
            "psi_a": float(theta["asym_psi_a"]),
        }

    def force(self, sig: Signals, h: np.ndarray, theta: Mapping[str, float]) -> np.ndarray | float:
        # the loop width changes along the stroke: h·(1 + g·x) = h + h·g·x
        return h * (theta["asym_g"] * sig.x)
