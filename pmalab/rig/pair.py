"""The antagonistic-joint interface: two muscles around a pulley behind the one rig class.

A :class:`PairRig` *is* a :class:`~pmalab.rig.base.Rig` — the same runner, loop, safety
monitor, recorder and run file record it — whose channels are declared as data
(:mod:`pmalab.channels`): time, the joint ``angle`` (deg, limited to the joint's stops)
and each muscle's ``position_<m>``, ``force_<m>``, ``muscle_pressure_<m>`` and
``muscle_pressure_command_<m>``.

Isobaric tests on a pair (``pmalab run``): a run names the muscle it holds
(``muscle = "flexor"`` in the protocol); :meth:`PairRig.hold` makes that muscle's
regulator the rig's ``muscle_supply`` (held at the run's pressure) and the other muscle's
regulator the ``cylinder_regulator`` — it is driven with the run's waveform and stretches
and releases the held muscle through the joint, as the cylinder does on the isobaric rig.
Every exit vents both regulators.  Units and signs: time s, contraction mm (positive =
shorter), tension N, pressure MPa gauge, angle deg (positive = towards the flexor).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from pmalab.channels import Channel, Channels, muscle_channels
from pmalab.errors import ConfigError
from pmalab.rig.base import (
    PressureRegulator,
    RegulatedMuscleSupply,
    Rig,
    VentReport,
    start_vent_safely,
)


def pair_channels(muscles: Sequence[str], stop_deg: float) -> Channels:
    """A pair's declaration: time, the joint angle (held within ±``stop_deg``), then each
    muscle's sampled channels, then each muscle's command."""
    sampled = [c for m in muscles for c in muscle_channels(m, command=False)]
    commands = [c for m in muscles for c in muscle_channels(m) if c.kind == "command"]
    return Channels(
        (
            Channel("time", "time"),
            Channel("angle", "angle", lo=-float(stop_deg), hi=float(stop_deg), label="joint angle"),
            *sampled,
            *commands,
        )
    )


@dataclass(frozen=True)
class PairGeometry:
    """What a joint controller is told about the mechanics (a rig file would hold these):
    pulley radius (mm), each muscle's contraction at θ = 0 (mm), the joint's inertia
    (kg·m²) and its end stops (deg)."""

    radius_mm: float
    mount_contraction_mm: float
    inertia_kg_m2: float
    stop_deg: float


@dataclass
class PairRig(Rig):
    """A rig with two muscles on one joint (see the module docstring).

    ``regulators``: each muscle's regulator by name, flexor first.  ``cylinder_regulator``
    and ``muscle_supply`` are the driven and the held muscle's, set by :meth:`hold`.
    """

    regulators: dict[str, PressureRegulator] = field(default_factory=dict)
    geometry: PairGeometry | None = None
    #: the muscle the current run holds isobaric
    held: str = ""

    def __post_init__(self) -> None:
        if len(self.regulators) != 2:
            raise ConfigError(
                f"a pair rig needs two muscles' regulators, got {list(self.regulators)}"
            )
        stop = self.geometry.stop_deg if self.geometry is not None else 90.0
        self.channels = pair_channels(list(self.regulators), stop)

    @property
    def muscles(self) -> tuple[str, ...]:
        return tuple(self.regulators)

    def hold(self, muscle: str) -> None:
        """Hold ``muscle`` at the run's pressure and drive the other with the waveform."""
        if muscle not in self.regulators:
            raise ConfigError(
                f"rig has muscles {', '.join(self.regulators)}: no muscle {muscle!r} to hold"
            )
        (other,) = [m for m in self.regulators if m != muscle]
        self.held = muscle
        self.muscle_supply = RegulatedMuscleSupply(self.regulators[muscle])
        self.cylinder_regulator = self.regulators[other]

    @property
    def held_pressure(self) -> str:
        """The channel reading the held muscle's pressure (the runner waits on it)."""
        return f"muscle_pressure_{self.held or self.muscles[0]}"

    def command_values(self, cmd: float, spec: Any) -> tuple[float, ...]:
        """The recorded command of each muscle (declaration order): the held one's
        requested pressure, the driven one's waveform value ``cmd`` (MPa)."""
        return tuple(
            float(spec.muscle_pressure_MPa) if m == self.held else cmd for m in self.regulators
        )

    def vent(self) -> VentReport:
        """Command both regulators to zero, then confirm both (never raises)."""
        a, b = self.muscles
        ca = start_vent_safely(self.regulators[a], f"{a} regulator")
        cb = start_vent_safely(self.regulators[b], f"{b} regulator")
        self.last_vent = VentReport(ca(), cb(), (f"{a} regulator", f"{b} regulator"))
        return self.last_vent

    def __enter__(self) -> PairRig:
        return self
