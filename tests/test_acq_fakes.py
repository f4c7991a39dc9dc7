"""A tiny fake rig for the acquisition tests (fault injection, call recording).

Physics is a cartoon of the isobaric test (enough for the runner, not for identification):
the cylinder pressure follows the regulator command through a first-order lag; more
cylinder pressure stretches the muscle, so the contraction x (mm) falls and the tension
F (N) rises, with a friction offset that makes the tension higher while stretching.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from pmalab.errors import RigError
from pmalab.rig.base import (
    Block,
    Clock,
    Limits,
    MusclePressureSupply,
    PressureRegulator,
    Rig,
    Sampler,
    VentResult,
    VirtualClock,
)


class RecordingRegulator(PressureRegulator):
    """Records every call as (clock time, "set"|"vent", MPa)."""

    max_pressure_MPa = 0.9

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.calls: list[tuple[float, str, float]] = []
        self.value = 0.0

    def set_pressure(self, mpa: float) -> None:
        self.calls.append((self.clock.now(), "set", float(mpa)))
        self.value = float(mpa)

    def vent(self) -> VentResult:
        self.calls.append((self.clock.now(), "vent", 0.0))
        self.value = 0.0
        return VentResult.confirmed("fake regulator at 0 MPa")

    @property
    def max_commanded(self) -> float:
        return max((v for _, _, v in self.calls), default=0.0)

    def vent_times(self) -> list[float]:
        return [t for t, kind, _ in self.calls if kind == "vent"]


class FakeSupply(MusclePressureSupply):
    def __init__(self, automatic: bool = True) -> None:
        self.automatic = automatic
        self.target = 0.0
        self.requests: list[float] = []
        self.vents = 0
        self.prompts: list[str] = []

    def request(self, mpa: float, prompt: Callable[[str], None] | None = None) -> None:
        self.requests.append(mpa)
        if prompt is not None:
            prompt(f"fake operator asked for {mpa}")
        self.target = mpa

    def vent(self) -> VentResult:
        self.vents += 1
        if not self.automatic:
            return VentResult.manual()
        self.target = 0.0
        return VentResult.confirmed("fake supply at 0 MPa")


class FakeSampler(Sampler):
    """Software-polled sampler; ``fault(t, sample_index)`` may return overrides or raise."""

    hardware_timed = False

    def __init__(self, clock: Clock, reg: RecordingRegulator, supply: FakeSupply,
                 fault: Callable[[float, int], dict | None] | None = None,
                 noise: float = 0.0, seed: int = 0) -> None:
        self.clock, self.reg, self.supply, self.fault = clock, reg, supply, fault
        self.pc = 0.0
        self.pm = 0.0
        self.x_prev = 20.0
        self.last_t: float | None = None
        self.n = 0
        self.noise = noise
        #: load-cell noise (N): a real cell is never exactly still, and the run file's
        #: health check refuses a force that repeats one value where its noise resolves
        self.force_noise = 0.0
        self.rng = np.random.default_rng(seed)

    def read_block(self) -> Block:
        t = self.clock.now()
        dt = 0.002 if self.last_t is None else max(t - self.last_t, 1e-6)
        self.last_t = t
        # first-order lags: regulator (40 ms), muscle supply (100 ms)
        self.pc += (self.reg.value - self.pc) * (1 - math.exp(-dt / 0.04))
        self.pm += (self.supply.target - self.pm) * (1 - math.exp(-dt / 0.1))
        x = 20.0 - 30.0 * self.pc + 10.0 * self.pm
        dx = x - self.x_prev
        self.x_prev = x
        friction = 20.0 if dx < 0 else -20.0  # tension higher while stretching (x falling)
        f = 300.0 + 1500.0 * self.pc + friction
        vals = {"position": x, "force": f, "muscle_pressure": self.pm,
                "cylinder_pressure": self.pc}
        if self.noise:
            vals["muscle_pressure"] += self.noise * self.rng.standard_normal()
        if self.force_noise:
            vals["force"] += self.force_noise * self.rng.standard_normal()
        if self.fault is not None:
            over = self.fault(t, self.n)
            if over:
                vals.update(over)
        self.n += 1
        return Block.single(t, vals["position"], vals["force"], vals["muscle_pressure"],
                            vals["cylinder_pressure"])


def make_fake_rig(fault=None, *, automatic: bool = True, clock: Clock | None = None,
                  limits: Limits | None = None, noise: float = 0.0) -> Rig:
    clock = clock or VirtualClock()
    reg = RecordingRegulator(clock)
    supply = FakeSupply(automatic)
    sampler = FakeSampler(clock, reg, supply, fault, noise)
    return Rig(clock=clock, sampler=sampler, cylinder_regulator=reg, muscle_supply=supply,
               limits=limits or Limits(), info={"kind": "fake", "calibration": {"gain": 1.0}})


#: two isobaric runs for the safety tests ("first" has settle and ramps; "second" does not)
TWO_RUNS = """
[[run]]
name = "first"
muscle_pressure_MPa = 0.4
frequency_Hz = 0.5
magnitude_MPa = 0.3
cycles = 2
ramp_s = 0.5
settle_s = 0.5
[[run]]
name = "second"
muscle_pressure_MPa = 0.5
frequency_Hz = 0.5
magnitude_MPa = 0.3
cycles = 2
"""


def raise_at(t_fault: float, exc: BaseException) -> Callable[[float, int], dict | None]:
    def fault(t: float, n: int) -> dict | None:
        if t >= t_fault:
            raise exc
        return None

    return fault


def override_at(t_fault: float, **values: float) -> Callable[[float, int], dict | None]:
    def fault(t: float, n: int) -> dict | None:
        return values if t >= t_fault else None

    return fault


__all__ = ["TWO_RUNS", "RigError", "make_fake_rig", "override_at", "raise_at"]


def test_fake_rig_direction():
    """The fake's cartoon physics: more cylinder pressure → less contraction, more tension."""
    rig = make_fake_rig()
    rig.cylinder_regulator.set_pressure(0.3)
    for _ in range(500):
        rig.clock.advance(0.002)
        b = rig.sampler.read_block()
    assert b.cylinder_pressure[0] == np.float64(b.cylinder_pressure[0])
    assert abs(b.cylinder_pressure[0] - 0.3) < 1e-3
    assert b.position[0] < 20.0 - 8.0
