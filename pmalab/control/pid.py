"""The classic digital incremental PID — the loop controller every other one extends.

Both seeds use the incremental (velocity) form at the sample period T::

    Δu(k) = Kp·x_P + Ki·x_I + Kd·x_D,   x_P = e(k) − e(k−1),  x_I = T·e(k),
                                         x_D = −(ỹ(k) − 2ỹ(k−1) + ỹ(k−2)) / T
    u(k)  = clamp(u(k−1) + Δu(k))

with ỹ the measurement through a first-order low-pass (``d_filter_Hz``) so the derivative
does not amplify sensor noise.  The derivative acts on the measurement, not the error (the
usual "derivative on measurement"): a square reference's step would otherwise kick the
output by Kd·Δr/T, and in the incremental form a kick the clamp cuts off on its way in but
not on its way out leaves a bias (a 15 mm step down drove the muscle *up* to 22 mm).  For a
constant reference both forms are the same.  Gains are in the loop's physical units (outer loop: N/mm,
N/(mm·s), N·s/mm; inner loop: MPa/MPa, 1/s, s).  The clamp is the anti-windup: the stored
u(k−1) is the clamped one, so the integral never runs away while the output saturates.
A feedforward ``ff`` adds to the output and the clamp applies to the sum.

Adaptive controllers subclass :class:`IncrementalPID` and override :meth:`adapt`, which
runs once per sample before the increment with the same x_P, x_I, x_D and may change
``self.kp/ki/kd`` (always inside ``gain_bounds``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

from pmalab.errors import ConfigError
from pmalab.registry import Registry


@dataclass(frozen=True)
class Gains:
    """PID gains in the loop's physical units."""

    kp: float
    ki: float
    kd: float

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.kp, self.ki, self.kd)


@dataclass(frozen=True)
class LoopSettings:
    """One loop's controller settings.

    ``u_min``/``u_max``: output range (N or MPa); ``e_scale``/``u_scale``/``y_scale``:
    typical magnitudes of error, output and measurement (same units), used by the adaptive
    laws to learn on dimensionless signals; ``gain_bounds``: each adapted gain stays within
    [lo·g0, hi·g0] of its initial value g0; ``learning``: the adaptive law's rates
    (``eta_p``, ``eta_i``, ``eta_d``, and ``eta``/``alpha`` for the RBF network), each
    clipped to [0, ``max_rate``].
    """

    gains: Gains
    u_min: float
    u_max: float
    e_scale: float
    u_scale: float
    y_scale: float
    dt: float = 0.002
    d_filter_Hz: float = 20.0
    gain_bounds: tuple[float, float] = (0.2, 5.0)
    learning: dict[str, dict[str, float]] = field(default_factory=dict)
    max_rate: float = 10.0

    def with_gains(self, kp: float, ki: float, kd: float) -> LoopSettings:
        return replace(self, gains=Gains(kp, ki, kd))

    def rate(self, controller: str, name: str, default: float) -> float:
        """``controller``'s learning rate ``name``, clipped to [0, max_rate]."""
        v = float(self.learning.get(controller, {}).get(name, default))
        if not math.isfinite(v):
            v = default
        return min(max(v, 0.0), self.max_rate)


#: every loop controller by the id users type (``--controller``), in declared order: a
#: subclass of :class:`IncrementalPID` that sets ``name`` registers itself
CONTROLLERS: Registry[type[IncrementalPID]] = Registry("controller", ConfigError)


class IncrementalPID:
    """Classic incremental PID with fixed gains (``name = "pid"``)."""

    name = "pid"
    title = "classic cascade PID (fixed gains)"
    order = 1

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("name"):
            CONTROLLERS.register(cls.name, cls, title=cls.title, order=cls.order)

    def __init__(self, settings: LoopSettings) -> None:
        self.s = settings
        g = settings.gains
        self.g0 = g
        self.kp, self.ki, self.kd = g.kp, g.ki, g.kd
        lo, hi = settings.gain_bounds
        self._bounds = tuple((lo * v, hi * v) if v >= 0 else (hi * v, lo * v) for v in g.as_tuple())
        self._a = 1.0 - math.exp(-2.0 * math.pi * settings.d_filter_Hz * settings.dt)
        self.reset()

    def reset(self, u0: float = 0.0) -> None:
        """Start from rest with output ``u0`` (the value the plant holds now)."""
        self.e1 = 0.0  # e(k−1)
        self.yf1 = self.yf2 = 0.0  # filtered measurement ỹ(k−1), ỹ(k−2) (ỹ(k−1): filter state)
        self.v = u0  # the PID's part of the output (output − feedforward)
        self.u = u0
        self.started = False

    @property
    def gains(self) -> tuple[float, float, float]:
        return (self.kp, self.ki, self.kd)

    def clip_gains(self) -> None:
        (lp, hp), (li, hi), (ld, hd) = self._bounds
        self.kp = min(max(self.kp, lp), hp)
        self.ki = min(max(self.ki, li), hi)
        self.kd = min(max(self.kd, ld), hd)

    def adapt(self, e: float, xp: float, xi: float, xd: float, y: float) -> None:
        """Hook for the adaptive laws (classic PID: gains stay fixed)."""

    def step(self, r: float, y: float, ff: float = 0.0) -> float:
        """One sample: reference ``r``, measurement ``y``, feedforward ``ff`` → output u."""
        e = r - y
        if not self.started:  # no history yet: no artificial derivative kick
            self.e1 = e
            self.yf1 = self.yf2 = y
            self.started = True
        yf = self.yf1 + self._a * (y - self.yf1)
        dt = self.s.dt
        xp = e - self.e1
        xi = dt * e
        xd = -(yf - 2.0 * self.yf1 + self.yf2) / dt
        self.adapt(e, xp, xi, xd, y)
        du = self.kp * xp + self.ki * xi + self.kd * xd
        v = self.v + du
        lo, hi = self.s.u_min - ff, self.s.u_max - ff
        if v > hi:
            v = hi
        elif v < lo:
            v = lo
        if v != v:  # NaN: hold the last output (the runner's limits decide what follows)
            v = self.v
        self.v = v
        self.e1 = e
        self.yf2, self.yf1 = self.yf1, yf
        self.u = ff + v
        return self.u


CONTROLLERS.register(
    IncrementalPID.name, IncrementalPID, title=IncrementalPID.title, order=IncrementalPID.order
)
