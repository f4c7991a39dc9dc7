"""The muscle pressure is not the run's label: within-run variation, and a per-run offset.

Two effects, told apart by what they describe:

* ``pressure-variation`` — the pressure is not constant *during* an "isobaric" run.  The
  muscle's volume changes with contraction and a slow manual regulator cannot hold the
  pressure, so the measured muscle pressure p(t) wanders around the run's mean p̄ (rising as
  the muscle is stretched and its volume shrinks, recovering with the regulator's time
  constant).  Tension is nearly proportional to pressure (F ≈ p·S(x)), so the force gains
  (g₀ + g₁·x)·(p − p̄): the sensitivity ∂F/∂p (N/MPa) and its change along the stroke (x
  absolute, so runs of one pressure level share g₀, g₁).  Only the within-run part p − p̄
  of the measured channel: a run whose mean differs from its label is the other effect's.
* ``pressure-offset`` — the run's pressure is not its label: the measured mean p̄ differs
  from the nominal pressure (a file name, a protocol setpoint, a lab notebook) by a
  constant.  The pressure laws θ(p) are then evaluated at each run's measured mean instead
  of its label, in the identification runs and in the held-out runs alike — exactly what
  ``--pressure measured`` does (:func:`pmalab.identify.labels.use_measured`).  No new
  parameter: the evidence is the held-out error with the runs at their measured pressures.
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

    #: the tension does not follow the pressure within a run
    absent: ClassVar[dict[str, float] | None] = {"pv_g0": 0.0, "pv_g1": 0.0}

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
        # within-run variation only: the run's mean pressure is the laws' business (its
        # label, or its measured mean with pressure-offset)
        dp = sig.p - sig.mean_pressure
        return (theta["pv_g0"] + theta["pv_g1"] * sig.x) * dp


class PressureOffset(Effect):
    id = "pressure-offset"
    order = 4.5
    #: no force term of its own: it changes the pressure the laws are evaluated at
    plant: ClassVar[dict[str, str] | None] = {}
    pressure_source = "measured"
    title = "Run pressure offset from its label (measured mean, not nominal)"
    explanation = (
        "A run's nominal pressure comes from a protocol, a file name or a notebook; the "
        "pressure the muscle held is what its gauge measured.  When the measured mean "
        "differs from the label, the pressure laws are evaluated at the wrong pressure and "
        "the whole loop of that run is off (stiffness, offset and friction alike).  With "
        "this effect every run, identification and held-out, is taken at its measured mean "
        "pressure (the same as --pressure measured)."
    )
    signature = (
        "A per-run error that follows the label's offset (measured mean − nominal): runs "
        "labelled too low are predicted too slack, runs labelled too high too stiff; the "
        "within-run pressure ripple plays no part."
    )
    experiment = (
        "compare each run's measured mean pressure with its label (pmalab import and identify "
        "print the offsets); set the regulator against a reference gauge and repeat one level"
    )
