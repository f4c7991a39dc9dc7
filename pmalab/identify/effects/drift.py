"""Sensor drift: a slow change of a sensor's zero during the run.

Strain-gauge load cells drift with temperature (the muscle and the air warm up while it
cycles), position sensors creep.  Over a run the force reading gains d·(t − t̄), with d in
N/s and t̄ the run's mid time (centred so d does not trade with c0).  Between runs the zero
differs by the drift accumulated since the rig was switched on: that offset is not a
property of the muscle, so the rate is a per-run nuisance parameter in the campaign fit
and predictions of other runs tare the force (see :mod:`pmalab.identify.effects.base`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals


class SensorDrift(Effect):
    id = "sensor-drift"
    order = 7
    title = "Slow drift of the force sensor's zero"
    explanation = (
        "Load-cell zeros drift as the cell warms (and position sensors creep), so a "
        "constant offset is not constant over a run. Modelled as a force d·(t − t̄) growing "
        "linearly with time."
    )
    signature = (
        "Residual against time is a ramp: early cycles have the opposite error to late "
        "ones, whatever the branch or position; the autocorrelation stays high at long lags."
    )

    experiment = "repeat the same run twice in a row, or record a long run: drift grows with elapsed time while loop-shape effects repeat every cycle"

    #: the drift rate belongs to the record (the sensor's warm-up during that run), not to
    #: the muscle: one value per run in the joint fit, never a pressure law; 0 when another
    #: run is predicted
    nuisance_params: ClassVar[tuple[str, ...]] = ("drift_d",)
    #: the zero accumulated before the run (since switch-on) differs from run to run: a
    #: prediction of another run tares the force on its first ~50 ms
    tare: ClassVar[bool] = True

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        dur = max(float(sig.t[-1] - sig.t[0]), 1e-3)
        lim = 5.0 * force_scale / dur
        return [Param("drift_d", 0.0, -lim, lim, "N/s", doc="force zero drift rate")]

    def force(self, sig: Signals, h: np.ndarray, theta: Mapping[str, float]) -> np.ndarray:
        # centred on the record's reference time (the middle of its span, kept by a part of
        # the record: the term is the same function of absolute time whatever part a fit sees)
        return theta["drift_d"] * (sig.t - sig.reference_time)
