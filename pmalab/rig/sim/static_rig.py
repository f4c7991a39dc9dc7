"""The simulated static stand as a :class:`~pmalab.rig.base.Rig` the 500 Hz runner drives.

The muscle of :mod:`pmalab.rig.sim.static_stand` (Chou–Hannaford static force, braid
friction in the pressure domain) on a stand whose muscle pressure regulator is *commanded*
sample by sample (``rig.muscle_regulator``), its lower end either clamped at a contraction
(:meth:`StaticPhysics.hold_length`, isometric) or carrying a hanging mass
(:meth:`StaticPhysics.hang_load`, isotonic).  There is no cylinder: its regulator is a
stub that reads 0 MPa.  Imports nothing from ``identify``.

Units: time s, contraction mm (+ = shorter), tension N, pressure MPa gauge.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pmalab.channels import KINDS, STANDARD_CHANNELS, Channel, Channels
from pmalab.errors import RigError
from pmalab.rig.base import (
    Block,
    Clock,
    MusclePressureSupply,
    PressureRegulator,
    Rig,
    Sampler,
    VentResult,
    VirtualClock,
)
from pmalab.rig.sim.regulator import SimulatedRegulator
from pmalab.rig.sim.static_stand import StaticTruth, _Slip, load_static_truth


class StaticPhysics:
    """State of the static stand, advanced on demand (exact first-order regulator for a
    command held between calls; quasi-static muscle).

    Parameters
    ----------
    truth
        The stand's :class:`StaticTruth`.
    seed
        Seeds the sensor noise.
    max_pressure_MPa
        The muscle regulator's range (MPa).
    """

    def __init__(self, truth: StaticTruth, seed: int = 0, max_pressure_MPa: float = 0.9) -> None:
        self.truth = truth
        self.seed = int(seed)
        self.max_pressure_MPa = float(max_pressure_MPa)
        self.rng = np.random.default_rng(self.seed)
        self.time = 0.0
        self.command = 0.0
        self.p = 0.0
        self.mode = "isometric"
        self.held_mm = 0.0
        self.load_N = 0.0
        self.x = 0.0
        self.force = float(truth.offset_N)
        self.hp = _Slip(
            truth.pressure_friction_N, truth.pressure_presliding_MPa, truth.pressure_weights
        )
        self.hx = _Slip(
            truth.position_friction_N, truth.position_presliding_mm, truth.position_weights
        )
        self.hp.start(-1.0)  # vented before switch-on
        self.hx.start(-1.0)
        self._h_p = self.hp.step(0.0)
        self._h_x = self.hx.step(0.0)
        th = math.radians(truth.braid_angle_deg)
        self._a = math.pi * truth.diameter_mm**2 / 4.0
        self._c1 = 3.0 / math.tan(th) ** 2
        self._c0 = 1.0 / math.sin(th) ** 2

    # ----------------------------------------------------------------- holding
    def hold_length(self, x_mm: float) -> None:
        """Clamp the muscle at contraction ``x_mm`` (isometric)."""
        self.mode, self.held_mm = "isometric", float(x_mm)
        self._move_to(float(x_mm))
        self._update_force()

    def hang_load(self, load_N: float) -> None:
        """Hang a mass whose weight is ``load_N`` (isotonic); the length follows."""
        self.mode, self.load_N = "isotonic", float(load_N)
        self._settle_length()

    def set_command(self, mpa: float) -> None:
        """The muscle regulator's setpoint (MPa)."""
        mpa = float(mpa)
        if not (-1e-9 <= mpa <= self.max_pressure_MPa + 1e-9):  # also NaN
            raise RigError(
                f"simulated muscle regulator: command {mpa:g} MPa outside its range "
                f"0–{self.max_pressure_MPa:g} MPa"
            )
        self.command = min(max(mpa, 0.0), self.max_pressure_MPa)

    # ----------------------------------------------------------------- physics
    def _fs(self, x: float, p: float) -> float:
        """Static tension F_s(x, p) (N), Chou–Hannaford with the end effect."""
        u = 1.0 - self.truth.end_effect * x / self.truth.length_mm
        return self._a * p * (self._c1 * u * u - self._c0) + self.truth.offset_N

    def _move_to(self, x: float) -> None:
        self._h_x = self.hx.step(x - self.x)
        self.x = x

    def _update_force(self) -> None:
        ref = self.truth.pressure_friction_reference_MPa
        scale = self.p / ref if ref > 0 else 1.0
        self.force = self._fs(self.x, self.p) + self._h_p * scale + self._h_x

    def _settle_length(self) -> None:
        """Isotonic: the contraction where the tension carries the load (bisection; the
        tension falls with the contraction).  A muscle too weak for the load lets it down
        onto the stand's rest at the nominal length (x = 0): the rest carries the balance
        and the load cell reads the muscle's tension."""
        ref = self.truth.pressure_friction_reference_MPa
        target = self.load_N - self._h_p * (self.p / ref if ref > 0 else 1.0)
        tr = self.truth
        lo = 0.0
        hi = 1.0 - math.cos(math.radians(tr.braid_angle_deg)) / math.sqrt(3.0)
        hi = hi / tr.end_effect * tr.length_mm
        for _ in range(2):  # the contraction-domain friction moves with the length
            goal = target - self._h_x
            a, b = lo, hi
            if self._fs(a, self.p) < goal:
                x = a
            elif self._fs(b, self.p) > goal:
                x = b
            else:
                for _ in range(50):
                    m = 0.5 * (a + b)
                    if self._fs(m, self.p) > goal:
                        a = m
                    else:
                        b = m
                x = 0.5 * (a + b)
            self._move_to(max(x, 0.0))
        if self.x <= 0.0:
            self._update_force()
        else:
            self.force = self.load_N

    def advance_to(self, t: float) -> None:
        """Integrate to time ``t`` (s) with the command held."""
        dt = t - self.time
        if not dt > 0:
            return
        if not math.isfinite(t):
            raise RigError(f"simulated static stand: cannot advance to t = {t}")
        tau = self.truth.regulator_time_constant_s
        a = math.exp(-dt / tau) if tau > 0 else 0.0
        p_new = a * self.p + (1.0 - a) * self.command
        self._h_p = self.hp.step(p_new - self.p)
        self.p = p_new
        self.time = float(t)
        if self.mode == "isotonic":
            self._settle_length()
        else:
            self._update_force()

    def sample(self) -> tuple[float, float, float, float, float]:
        """time s, position mm, force N, muscle pressure MPa, cylinder pressure MPa (none: 0)."""
        tr = self.truth
        n = self.rng.standard_normal(3)

        def q(v: float, step: float) -> float:
            return round(v / step) * step if step > 0 else v

        return (
            self.time,
            q(self.x + tr.position_noise_mm * n[0], tr.position_resolution_mm),
            q(self.force + tr.force_noise_N * n[1], tr.force_resolution_N),
            q(self.p + tr.pressure_noise_MPa * n[2], tr.pressure_resolution_MPa),
            0.0,
        )


class StaticSampler(Sampler):
    """Software-polled: one sample at ``clock.now()`` per :meth:`read_block`."""

    hardware_timed = False

    def __init__(self, physics: StaticPhysics, clock: Clock, sample_rate_Hz: float = 500.0):
        self.physics = physics
        self.clock = clock
        self.sample_rate_Hz = float(sample_rate_Hz)

    def read_block(self) -> Block:
        self.physics.advance_to(self.clock.now())
        t, x, f, pm, pc = self.physics.sample()
        return Block(np.array([t]), np.array([x]), np.array([f]), np.array([pm]), np.array([pc]))


class _NoCylinder(PressureRegulator):
    """The stand has no cylinder: commands must be 0 MPa; venting is trivially confirmed."""

    max_pressure_MPa = 0.0

    def set_pressure(self, mpa: float) -> None:
        if abs(float(mpa)) > 1e-12:
            raise RigError(f"static stand: no cylinder to command ({mpa:g} MPa)")

    def vent(self) -> VentResult:
        return VentResult.confirmed("static stand: no cylinder")


class _Supply(MusclePressureSupply):
    """The commanded muscle regulator seen as the runner's muscle supply."""

    automatic = True

    def __init__(self, physics: StaticPhysics, clock: Clock) -> None:
        self.physics, self.clock = physics, clock

    def request(self, mpa: float, prompt=None) -> None:
        self.physics.advance_to(self.clock.now())
        self.physics.set_command(mpa)

    def vent(self) -> VentResult:
        try:
            self.physics.advance_to(self.clock.now())
        except Exception:  # a bad state must not stop the vent
            pass
        self.physics.command = 0.0
        return VentResult.confirmed("simulated muscle regulator commanded to 0 MPa")


def _command_values(cmd: float, spec: object) -> tuple[float, float]:
    """The recorded commands (cylinder, muscle) in MPa for a waveform value ``cmd``: a static
    run plays it on the muscle's regulator; the stand has no cylinder."""
    return (0.0, float(cmd))


def make_static_rig(
    truth: str | Path | None = None,
    *,
    seed: int = 0,
    clock: Clock | None = None,
    sample_rate_Hz: float = 500.0,
) -> Rig:
    """A simulated static stand rig: ``rig.muscle_regulator`` (commanded per sample),
    ``rig.hold_length(mm)`` / ``rig.hang_load(N)``; truth from ``truth`` (a static truth
    file or shipped name; None: the defaults)."""
    tr = load_static_truth(truth)
    clock = clock if clock is not None else VirtualClock()
    physics = StaticPhysics(tr, seed)
    physics.time = clock.now()
    rig = Rig(
        clock=clock,
        sampler=StaticSampler(physics, clock, sample_rate_Hz),
        cylinder_regulator=_NoCylinder(),
        muscle_supply=_Supply(physics, clock),
        info={
            "kind": "sim-static",
            "truth": tr.source,
            "seed": seed,
            "clock": "virtual" if clock.virtual else "real",
        },
    )
    # the recorded commands: the (absent) cylinder's, then the muscle regulator's
    rig.channels = Channels(
        (*STANDARD_CHANNELS, Channel("muscle_pressure_command", "command", KINDS["command"]))
    )
    reg = SimulatedRegulator(physics, clock, physics.max_pressure_MPa, physics.set_command)
    # attributes the runner looks for: a commanded muscle regulator and the two holds
    rig.muscle_regulator = reg  # type: ignore[attr-defined]
    rig.hold_length = physics.hold_length  # type: ignore[attr-defined]
    rig.hang_load = physics.hang_load  # type: ignore[attr-defined]
    rig.has_cylinder = False  # type: ignore[attr-defined]
    rig.command_values = _command_values  # type: ignore[attr-defined]
    return rig
