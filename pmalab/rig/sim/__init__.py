"""Simulated rig: physics truth model, sensor models and a virtual clock.

* :mod:`~pmalab.rig.sim.truth` — the TOML truth file (:func:`load_truth`);
* :mod:`~pmalab.rig.sim.kernel` — compiled equations (muscle, braid friction, cylinder,
  regulators, sensors) and the sub-stepped integrator;
* :mod:`~pmalab.rig.sim.physics` — :class:`RigPhysics`, the whole rig's state;
* :mod:`~pmalab.rig.sim.rig` — the :class:`~pmalab.rig.base.Rig` wrapper;
* :mod:`~pmalab.rig.sim.demo` — :func:`demo_cycle`, one isobaric cycle with its numbers;
* :mod:`~pmalab.rig.sim.reference` — the effects-off law restated in plain numpy, to
  cross-check the compiled kernel in tests and benchmarks.

The truth model imports nothing from :mod:`pmalab.identify` (no inverse crime).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pmalab.rig.base import Clock, Rig
from pmalab.rig.sim.demo import demo_cycle, run_isobaric
from pmalab.rig.sim.physics import RigPhysics
from pmalab.rig.sim.rig import build_sim_rig
from pmalab.rig.sim.truth import Truth, load_truth

__all__ = ["RigPhysics", "Truth", "demo_cycle", "load_truth", "make_sim_rig", "run_isobaric"]


def make_sim_rig(
    truth: Truth | str | Path | None = None,
    *,
    seed: int = 0,
    clock: Clock | None = None,
    manual_muscle_regulator: bool = False,
    prompt: Callable[[str], None] | None = None,
) -> Rig:
    """A simulated :class:`~pmalab.rig.base.Rig` (software-polled sampler, 500 Hz nominal).

    ``truth``: a :class:`Truth`, a truth TOML path, or ``None`` (defaults, every effect off).
    ``clock``: default :class:`~pmalab.rig.base.VirtualClock` (as fast as possible); pass a
    :class:`~pmalab.rig.base.RealClock` to run in real time.  The muscle supply is a second
    regulator unless ``manual_muscle_regulator``, in which case ``request`` calls
    ``prompt(text)`` and the simulated operator sets the pressure.  ``rig.info["physics"]``
    is the underlying :class:`RigPhysics` (tests read its ``truth_state()``).
    """
    physics = RigPhysics(truth, seed=seed)
    rig = build_sim_rig(
        physics, clock=clock, manual_muscle_regulator=manual_muscle_regulator, prompt=prompt
    )
    rig.info["physics"] = physics
    return rig
