"""The 1-DOF manipulator interface: what a position controller needs from a rig, and no more.

The seeds' manipulator: one pneumatic muscle pulls a link on a rotary base of radius r
against a return spring; a proportional regulator (SMC ITV1050-class) sets the muscle's
pressure; a position sensor reads the link (expressed as the muscle's contraction), a gauge
the muscle pressure.  Units and signs as everywhere in pmalab (docs/explanation/physics.md): time s,
position mm (contraction, positive = shorter), force N (tension), pressures MPa gauge.

A :class:`ManipulatorRig` is a clock, a :class:`~pmalab.rig.base.Sampler` delivering the
five channels of :data:`pmalab.rig.base.CHANNELS` (``position`` is the contraction measured
from the *home* position, the equilibrium of the vented manipulator; ``force`` is the
load cell in series with the muscle where one is fitted, NaN-free; ``cylinder_pressure``
is 0: there is no cylinder), the muscle's :class:`~pmalab.rig.base.PressureRegulator`,
its :class:`~pmalab.rig.base.Limits` and the geometry a model-based controller needs
(:class:`ManipulatorGeometry`).  The simulated one is :mod:`pmalab.rig.sim.manipulator`;
a real one wraps its DAQ and regulator drivers the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pmalab.rig.base import (
    Clock,
    Limits,
    PressureRegulator,
    RigDevices,
    Sampler,
    VentResult,
    vent_safely,
)


@dataclass(frozen=True)
class ManipulatorGeometry:
    """What the controller is told about the mechanics (a rig file would hold these).

    ``home_contraction_mm``: the muscle's contraction from its nominal length at the home
    position (position 0), mm — the identified muscle model is written in absolute
    contraction.  ``spring_N_per_mm`` / ``spring_preload_N``: the return spring's force
    seen along the muscle, F_s = preload + k·x_abs (N, x_abs in mm).  ``moving_mass_kg``:
    J/r², the link's inertia seen along the muscle (kg).
    """

    home_contraction_mm: float
    spring_N_per_mm: float
    spring_preload_N: float
    moving_mass_kg: float
    radius_mm: float

    def spring_force(self, x_abs_mm: float) -> float:
        """Return-spring force (N) along the muscle at absolute contraction ``x_abs_mm``."""
        return self.spring_preload_N + self.spring_N_per_mm * x_abs_mm


@dataclass
class ManipulatorRig(RigDevices):
    """A complete 1-DOF manipulator: clock, sampler, muscle regulator, limits, geometry."""

    clock: Clock
    sampler: Sampler
    muscle_regulator: PressureRegulator
    geometry: ManipulatorGeometry
    limits: Limits = field(default_factory=Limits)
    #: provenance recorded with every run (truth file, seed, device ids, ...)
    info: dict[str, Any] = field(default_factory=dict)

    def vent(self) -> VentResult:
        """Vent the muscle; never raises (a fault is a failed :class:`VentResult`)."""
        return vent_safely(self.muscle_regulator.vent, "muscle regulator vent()")

    def close(self) -> VentResult:
        """Vent the muscle and release devices (:meth:`RigDevices.close`); returns the
        vent's outcome."""
        return super().close()

    def __enter__(self) -> ManipulatorRig:
        return self
