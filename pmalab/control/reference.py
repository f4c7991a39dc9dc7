"""Reference signals: ``square:0.1Hz:15mm``, ``sine:0.1Hz:20mm``, ``square:0.1Hz:0.5MPa``.

``KIND:FREQ Hz:MAGNITUDE UNIT`` with KIND ``square`` or ``sine``, the unit ``mm`` (a
position reference), ``MPa`` (a pressure reference) or ``deg`` (the joint angle of an
antagonistic pair).  Both run from 0 to the magnitude,
like the protocol files' ``magnitude_MPa = M`` (a muscle only contracts):

* square: M for the first half period, 0 for the second (the seeds' step up at t = 0 and
  step down at T/2);
* sine: M/2·(1 − cos 2πft), starting at 0 with zero velocity.

:meth:`Reference.value` gives r(t) and its first two time derivatives (units/s, units/s²),
which the outer loop's feedforward uses; a square's derivatives are 0 (its jumps are steps).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from pmalab.errors import ConfigError

_SPEC = re.compile(r"^(square|sine):([0-9.eE+-]+)hz:([0-9.eE+-]+)(mm|mpa|deg)$")

#: the largest references the manipulator and the DMSP-20 can take
MAX_POSITION_MM = 25.0
MAX_PRESSURE_MPA = 0.6
#: the largest joint-angle reference (deg) of an antagonistic pair (its stops are ±40°)
MAX_ANGLE_DEG = 35.0


@dataclass(frozen=True)
class Reference:
    """A periodic reference from 0 to ``magnitude`` (mm or MPa)."""

    kind: str
    frequency_Hz: float
    magnitude: float
    unit: str  # "mm" | "MPa" | "deg"

    @property
    def quantity(self) -> str:
        """``position``, ``pressure`` or ``angle`` (a joint of two muscles)."""
        return {"mm": "position", "deg": "angle"}.get(self.unit, "pressure")

    @property
    def period_s(self) -> float:
        return 1.0 / self.frequency_Hz

    @property
    def text(self) -> str:
        return f"{self.kind}:{self.frequency_Hz:g}Hz:{self.magnitude:g}{self.unit}"

    def value(self, t: float) -> tuple[float, float, float]:
        """(r, ṙ, r̈) at time ``t`` (s)."""
        if self.kind == "square":
            phase = (t * self.frequency_Hz) % 1.0
            return (self.magnitude if phase < 0.5 else 0.0), 0.0, 0.0
        w = 2.0 * math.pi * self.frequency_Hz
        half = 0.5 * self.magnitude
        return (
            half * (1.0 - math.cos(w * t)),
            half * w * math.sin(w * t),
            half * w * w * math.cos(w * t),
        )

    def step_times(self, duration_s: float) -> list[float]:
        """Instants (s) of the square's steps inside [0, duration) — empty for a sine."""
        if self.kind != "square":
            return []
        half = 0.5 * self.period_s
        n = int(math.floor(duration_s / half + 1e-9))
        return [i * half for i in range(n) if i * half < duration_s]


def parse_reference(text: str, where: str = "--reference") -> Reference:
    """Parse ``KIND:FREQHz:MAGNITUDE{mm|MPa}``; one-line :class:`ConfigError` on a mistake."""
    s = str(text).strip().replace(" ", "").lower()
    m = _SPEC.match(s)
    if not m:
        raise ConfigError(
            f"{where}: '{text}': expected KIND:FREQHz:MAGNITUDE with KIND square|"
            "sine and a magnitude in mm, MPa or deg (a joint), e.g. square:0.1Hz:15mm"
        )
    kind, f_txt, m_txt, unit = m.groups()
    try:
        f, mag = float(f_txt), float(m_txt)
    except ValueError:
        raise ConfigError(f"{where}: '{text}': frequency and magnitude must be numbers") from None
    unit = {"mm": "mm", "deg": "deg"}.get(unit, "MPa")
    if not (math.isfinite(f) and 0.0 < f <= 5.0):
        raise ConfigError(f"{where}: '{text}': frequency must be in (0, 5] Hz")
    top = {"mm": MAX_POSITION_MM, "deg": MAX_ANGLE_DEG}.get(unit, MAX_PRESSURE_MPA)
    if not (math.isfinite(mag) and 0.0 < mag <= top):
        raise ConfigError(
            f"{where}: '{text}': magnitude must be in (0, {top:g}] {unit} "
            "(the manipulator's travel / the DMSP-20's rating)"
        )
    return Reference(kind, f, mag, unit)


class ReferenceShaper:
    """Rate- and acceleration-limited set-point follower (online trajectory generation).

    Each sample it moves a set point (s, v) toward the reference r with at most ``a_max``
    (units/s²) of acceleration and ``v_max`` (units/s) of velocity, braking in time to
    arrive without overshoot (time-optimal: the velocity relative to the reference's own
    ṙ is at most √(2·a_max·|r − s|), and at most |r − s|/τ near arrival so it lands without
    chatter).  A reference that already moves within the limits (a 0.1 Hz, 20 mm sine:
    6.3 mm/s, 3.9 mm/s²) is passed through unchanged once locked on; a step becomes an
    S-free trapezoidal move (accelerate, cruise, brake).  What real manipulators do with a
    step command instead of handing it raw to the feedback loops.

    :meth:`step` returns (s, ṡ, s̈) in the reference's units.  Sign convention: the same
    as the reference (mm of contraction from home).
    """

    def __init__(self, v_max: float, a_max: float, dt: float, tau: float = 0.02) -> None:
        if not (v_max > 0 and a_max > 0 and dt > 0):
            raise ConfigError("reference shaping: velocity and acceleration limits must be > 0")
        self.v_max = float(v_max)
        self.a_max = float(a_max)
        self.dt = float(dt)
        self.tau = max(float(tau), float(dt))
        self.s: float | None = None
        self.v = 0.0

    def start(self, s0: float, v0: float = 0.0) -> None:
        """Start at ``s0`` (the plant's measured position) moving at ``v0``."""
        self.s, self.v = float(s0), float(v0)

    def step(self, r: float, r_d: float = 0.0) -> tuple[float, float, float]:
        if self.s is None:  # not started: start on the reference, at rest relative to it
            self.s, self.v = r, r_d
            return r, r_d, 0.0
        e = r - self.s
        ae = abs(e)
        # braking velocity one sample early (the discrete loop would otherwise overrun)
        rel = min(max(math.sqrt(2.0 * self.a_max * ae) - self.a_max * self.dt, 0.0), ae / self.tau)
        v_des = r_d + (rel if e >= 0.0 else -rel)
        if v_des > self.v_max:
            v_des = self.v_max
        elif v_des < -self.v_max:
            v_des = -self.v_max
        dv_max = self.a_max * self.dt
        dv = v_des - self.v
        if dv > dv_max:
            dv = dv_max
        elif dv < -dv_max:
            dv = -dv_max
        v_new = self.v + dv
        self.s += 0.5 * (self.v + v_new) * self.dt
        self.v = v_new
        return self.s, v_new, dv / self.dt
