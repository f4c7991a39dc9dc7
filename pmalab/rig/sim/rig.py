"""The simulated rig as a :class:`pmalab.rig.base.Rig`: software-polled sampler, ITV, supply.

Every device object shares one :class:`~pmalab.rig.sim.physics.RigPhysics` and one clock.
Before acting, each advances the physics to ``clock.now()``, so commands take effect at the
moment they are given and samples are stamped with the moment they are taken.  On a
:class:`~pmalab.rig.base.VirtualClock` this runs as fast as the physics integrates; on a
:class:`~pmalab.rig.base.RealClock` it runs in real time.
"""

from __future__ import annotations

from collections.abc import Callable

from pmalab.rig.base import (
    Block,
    Clock,
    MusclePressureSupply,
    Rig,
    Sampler,
    VentResult,
    VirtualClock,
)
from pmalab.rig.sim.physics import RigPhysics
from pmalab.rig.sim.regulator import SimulatedRegulator


class SimSampler(Sampler):
    """Software-polled: each :meth:`read_block` takes one sample at ``clock.now()``."""

    hardware_timed = False

    def __init__(self, physics: RigPhysics, clock: Clock, sample_rate_Hz: float = 500.0) -> None:
        self.physics = physics
        self.clock = clock
        self.sample_rate_Hz = float(sample_rate_Hz)

    def read_block(self) -> Block:
        o = self.physics.advance_and_sample(self.clock.now()).copy()
        return Block(o[0:1], o[1:2], o[2:3], o[3:4], o[4:5])


class SimCylinderRegulator(SimulatedRegulator):
    """The simulated ITV1050-class regulator driving the cylinder (0–0.9 MPa)."""

    def __init__(self, physics: RigPhysics, clock: Clock) -> None:
        super().__init__(physics, clock, physics.cylinder_max_MPa, physics.set_cylinder_command)


class SimMuscleSupply(MusclePressureSupply):
    """The muscle's pressure supply: a second regulator, or a manual one and an operator.

    Manual: :meth:`request` shows ``prompt(text)`` and the simulated operator turns the knob
    to the requested pressure (the slow dynamics of a manual regulator are the truth file's
    ``pressure_variation`` effect).
    """

    def __init__(
        self,
        physics: RigPhysics,
        clock: Clock,
        automatic: bool = True,
        prompt: Callable[[str], None] | None = None,
    ) -> None:
        self.physics = physics
        self.clock = clock
        self.automatic = automatic
        self.prompt = prompt
        self.prompts: list[str] = []

    def request(self, mpa: float, prompt: Callable[[str], None] | None = None) -> None:
        self.physics.advance_to(self.clock.now())
        self.physics.start_run()  # a run begins: re-tare drifting zeros if the truth says so
        if not self.automatic:
            text = f"Set the muscle regulator to {mpa:.4g} MPa, then confirm."
            self.prompts.append(text)
            show = prompt or self.prompt
            if show is not None:
                show(text)
        self.physics.set_muscle_supply(mpa)

    def vent(self) -> VentResult:
        if not self.automatic:
            return VentResult.manual()  # left as the operator set it: the operator vents it
        try:
            self.physics.advance_to(self.clock.now())
        except Exception:  # a diverged integration must not stop the vent
            pass
        try:
            self.physics.set_muscle_supply(0.0)
        except Exception as exc:  # vent must never raise
            return VentResult.failed(f"simulated regulator: {exc}")
        return VentResult.confirmed("simulated regulator commanded to 0 MPa")


def build_sim_rig(
    physics: RigPhysics,
    *,
    clock: Clock | None = None,
    manual_muscle_regulator: bool = False,
    prompt: Callable[[str], None] | None = None,
    sample_rate_Hz: float = 500.0,
) -> Rig:
    """Wrap ``physics`` into a :class:`Rig` (see :func:`pmalab.rig.sim.make_sim_rig`)."""
    clock = clock if clock is not None else VirtualClock()
    # the physics starts where the clock is
    if clock.now() > physics.time:
        physics.advance_to(clock.now())
    info = {
        "kind": "sim",
        "truth": physics.truth.source,
        "truth_values": physics.truth.to_dict(),
        "seed": physics.seed,
        "enabled_effects": physics.truth.enabled_effects(),
        "clock": "virtual" if clock.virtual else "real",
    }
    return Rig(
        clock=clock,
        sampler=SimSampler(physics, clock, sample_rate_Hz),
        cylinder_regulator=SimCylinderRegulator(physics, clock),
        muscle_supply=SimMuscleSupply(physics, clock, not manual_muscle_regulator, prompt),
        info=info,
    )
