"""The base of every law whose hysteretic force is a sum of elasto-slide elements.

    z_i ← clip(z_i − k_i·Δx, −f_i, +f_i),   h = Σ z_i

Maxwell-slip (free slip displacements), Prandtl-Ishlinskii (play operators at fixed
thresholds: an operator of threshold r and weight w is the element k = w, f = w·r) and the
structured element profiles (:mod:`.structures`) differ only in how their parameters give
each element's stiffness k_i (N/mm) and slip force f_i (N); the path, the start state, the
output and the step are the same elements integrated by :mod:`._slide`.  A subclass gives
:meth:`ElementSum._kf`; sign convention as every law: tension higher while stretching.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from pmalab.identify.laws._slide import branch, slide_h, slide_start, slide_stepper
from pmalab.identify.laws.base import HysteresisLaw
from pmalab.identify.signals import Signals


class ElementSum(HysteresisLaw):
    """A sum of elasto-slide elements (see the module docstring); not a law users choose
    (it has no ``name``): a subclass says how θ gives the elements."""

    def _kf(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """Each element's stiffness k_i (N/mm) and slip force f_i (N) at ``theta``."""
        raise NotImplementedError

    def drive_signals(self, sig: Signals) -> Signals:
        """``sig`` driven by its narrower-band position
        (:func:`pmalab.identify.signals.slide_cutoff_Hz`): a sticking element passes position
        noise to the force through its stiffness."""
        return sig.slide_drive()

    def h(self, x, theta, extras=None):
        k, f = self._kf(theta)
        return slide_h(
            np.ascontiguousarray(x, dtype=np.float64), k, f, float(theta["h0"]), branch(theta)
        )

    def initial_state(self, theta: Mapping[str, float], h0: float = 0.0, direction: float = 1.0):
        k, f = self._kf(theta)
        return slide_start(k, f, float(h0), float(direction))

    def output(self, state) -> float:
        return float(np.sum(state))

    def stepper(self, theta, extras=None) -> Callable:
        return slide_stepper(*self._kf(theta))
