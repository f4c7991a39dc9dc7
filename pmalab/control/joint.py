"""Joint-angle control of an antagonistic pair with a co-contraction setting.

The pair's two regulators get a common pressure p0 — the **co-contraction**, which sets the
joint's stiffness — and a differential Δp that turns the joint::

    (r, ṙ) → set point (s, ṡ)                       rate/acceleration-limited (shaping)
    Δp_ff  = static inversion at s                   the identified muscles' static curves:
                                                     F_f(x0 + r·s, p0 + Δ/2) = F_e(x0 − r·s, p0 − Δ/2)
             + τ_lead · dΔp_ff/dt                    the lead that undoes the pneumatic lag
    Δp     = loop(s, θ, Δp_ff)                       one loop controller (pid | sn-pid | rbf-pid)
    p_f    = p0 + Δp/2,  p_e = p0 − Δp/2             each clipped to [0, p_max]

θ is the measured joint angle (deg, positive towards the flexor), s the shaped set point
(deg), x0 the muscles' contraction at θ = 0 and r the pulley radius (the pair's
:class:`~pmalab.rig.pair.PairGeometry`).  The loop is the same controller class the
single-muscle cascade uses (:mod:`pmalab.control.pid`, its adaptive subclasses), on
angle error (deg) → differential pressure (MPa), with one set of initial gains for all
three kinds (:func:`default_joint_settings`: a small hand grid on the simulated joint's
20° square at p0 = 0.2 and 0.35 MPa with the classic PID, gains and lead together;
never per experiment).  Without a model the feedforward is 0
and the loop's integral finds the differential alone.

The run goes through the one sample loop (:func:`pmalab.acquisition.loop.sample_loop`)
over the rig's declared channels, with the rig's safety limits on every sample; every exit
vents both regulators and says whether the vent was confirmed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pmalab.acquisition.loop import (
    LATE_THRESHOLD_S,
    LoopStats,
    Terminated,
    Trip,
    deferred_signals,
    sample_loop,
)
from pmalab.acquisition.safety import SafetyMonitor
from pmalab.control.controllers import make_loop
from pmalab.control.metrics import summarize
from pmalab.control.model import IdentifiedModel
from pmalab.control.pid import Gains, LoopSettings
from pmalab.control.reference import Reference, ReferenceShaper
from pmalab.errors import ConfigError, PmalabError
from pmalab.rig.base import sampled
from pmalab.rig.pair import PairRig

#: the adaptive laws' learning rates on the joint loop (dimensionless, tuned once with the
#: classic PID's gains fixed: a few rates 0.01 … 10 on the 20° square)
LEARNING_JOINT = {"sn-pid": {"eta_d": 10.0}, "rbf-pid": {"eta_p": 1.0}}


@dataclass(frozen=True)
class JointSettings:
    """The joint controller's settings.

    ``loop``: angle error (deg) → differential pressure Δp (MPa), output within
    ±``loop.u_max``; ``cocontraction_MPa``: p0; ``shaping_velocity_deg_s`` /
    ``shaping_accel_deg_s2``: the set point's limits (0: follow the raw reference);
    ``settle_s``: time at θ = 0 with both muscles at p0 before the reference starts;
    ``feedforward``: invert the identified muscles' static curves for Δp_ff;
    ``feedforward_lead_s``: add this × dΔp_ff/dt (low-passed), the lead that undoes the
    regulator → muscle pressure lag (as the single-muscle cascade's).
    """

    loop: LoopSettings
    cocontraction_MPa: float = 0.25
    shaping_velocity_deg_s: float = 40.0
    shaping_accel_deg_s2: float = 150.0
    settle_s: float = 2.0
    feedforward: bool = True
    feedforward_lead_s: float = 0.2

    def with_cocontraction(self, p0: float) -> JointSettings:
        return replace(self, cocontraction_MPa=float(p0))


def default_joint_settings(
    cocontraction_MPa: float = 0.25, p_max: float = 0.6, dt: float = 0.002
) -> JointSettings:
    """The one set of initial gains every joint controller starts from (module docstring)."""
    loop = LoopSettings(
        gains=Gains(kp=0.012, ki=0.03, kd=0.0012),
        u_min=-p_max,
        u_max=p_max,
        e_scale=5.0,
        u_scale=0.3,
        y_scale=20.0,
        dt=dt,
        d_filter_Hz=20.0,
        learning={k: dict(v) for k, v in LEARNING_JOINT.items()},
    )
    return JointSettings(loop=loop, cocontraction_MPa=float(cocontraction_MPa))


class StaticPair:
    """The identified muscles' static curves F = k(p)·x + c0(p) (h = 0) for the feedforward.

    ``flexor``/``extensor``: identified models (the same one for a pair of like muscles);
    ``x0``: each muscle's contraction at θ = 0 (mm); ``radius_mm``: the pulley.
    """

    def __init__(
        self, flexor: IdentifiedModel, extensor: IdentifiedModel, x0: float, radius_mm: float
    ) -> None:
        self.f, self.e, self.x0, self.r = flexor, extensor, float(x0), float(radius_mm)

    def differential(self, angle_deg: float, p0: float, p_max: float) -> float:
        """Δp (MPa) that balances the static tensions at ``angle_deg`` with common ``p0``,
        within what the pressures can give (bisection: the net torque grows with Δp)."""
        y = self.r * math.radians(angle_deg)
        xf, xe = self.x0 + y, self.x0 - y

        def net(d: float) -> float:
            pf = min(max(p0 + 0.5 * d, 0.0), p_max)
            pe = min(max(p0 - 0.5 * d, 0.0), p_max)
            return self.f.force(xf, pf, 0.0) - self.e.force(xe, pe, 0.0)

        lo, hi = -2.0 * p_max, 2.0 * p_max
        if net(lo) > 0.0:
            return lo
        if net(hi) < 0.0:
            return hi
        for _ in range(30):  # 1.2 MPa / 2^30: far below the regulator's quantum
            mid = 0.5 * (lo + hi)
            if net(mid) < 0.0:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)


class JointController:
    """One joint controller (``pid``, ``sn-pid`` or ``rbf-pid``) and its co-contraction."""

    #: low-pass (Hz) on the feedforward's rate of change that the lead multiplies
    LEAD_FILTER_HZ = 20.0

    def __init__(
        self,
        controller: str,
        settings: JointSettings,
        p_max: float,
        statics: StaticPair | None = None,
    ) -> None:
        p0 = settings.cocontraction_MPa
        if not 0.0 < p0 < p_max:
            raise ConfigError(
                f"co-contraction {p0:g} MPa: must be within (0, {p_max:g}) MPa (the regulators)"
            )
        self.controller = controller
        self.s = settings
        self.p0 = p0
        self.p_max = float(p_max)
        self.loop = make_loop(controller, settings.loop)
        self.statics = statics if settings.feedforward else None
        v, a = settings.shaping_velocity_deg_s, settings.shaping_accel_deg_s2
        self.shaper = ReferenceShaper(v, a, settings.loop.dt) if v > 0 and a > 0 else None
        self._ff1: float | None = None
        self._rate = 0.0
        self._a = 1.0 - math.exp(-2.0 * math.pi * self.LEAD_FILTER_HZ * settings.loop.dt)

    def step(self, r: float, r_d: float, angle: float) -> tuple[float, float, float, float]:
        """One sample: reference ``r`` (deg) and its rate, measured ``angle`` (deg) →
        (p_flexor, p_extensor, set point deg, feedforward Δp MPa)."""
        if self.shaper is not None:
            if self.shaper.s is None:
                self.shaper.start(angle)
            s, _, _ = self.shaper.step(r, r_d)
        else:
            s = r
        ff = self.statics.differential(s, self.p0, self.p_max) if self.statics else 0.0
        if self._ff1 is not None:
            self._rate += self._a * ((ff - self._ff1) / self.s.loop.dt - self._rate)
        self._ff1 = ff
        ff += self.s.feedforward_lead_s * self._rate
        d = self.loop.step(s, angle, ff)
        pf = min(max(self.p0 + 0.5 * d, 0.0), self.p_max)
        pe = min(max(self.p0 - 0.5 * d, 0.0), self.p_max)
        return pf, pe, s, ff


@dataclass
class JointRun:
    """One joint-control run: signals (s from the reference's start, deg, MPa), status."""

    name: str
    controller: str
    reference: Reference
    cocontraction_MPa: float
    signals: dict[str, np.ndarray]
    status: str
    vent: str
    vent_confirmed: bool
    wall_s: float
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def completed(self) -> bool:
        return self.status == "completed"


#: the signals a joint run keeps (deg, MPa; time in s from the reference's start)
JOINT_SIGNALS = (
    "time",
    "angle",
    "angle_reference",
    "angle_setpoint",
    "muscle_pressure_flexor",
    "muscle_pressure_extensor",
    "muscle_pressure_command_flexor",
    "muscle_pressure_command_extensor",
    "differential_feedforward",
)


def run_joint(
    rig: PairRig,
    controller: str,
    reference: Reference,
    duration_s: float,
    settings: JointSettings,
    statics: StaticPair | None = None,
    *,
    name: str | None = None,
    progress: Callable[[float], None] | None = None,
) -> JointRun:
    """Run ``controller`` on the pair's joint angle following ``reference`` (deg) for
    ``duration_s`` s after ``settings.settle_s`` at θ = 0 with both muscles at the
    co-contraction pressure.

    Never raises for a limit trip or Ctrl-C: the run comes back with ``status =
    "aborted: …"`` and both regulators vented (check :attr:`JointRun.completed`).
    """
    if reference.unit != "deg":
        raise PmalabError(f"--reference {reference.text}: a joint follows an angle (deg)")
    if len(rig.muscles) != 2:
        raise PmalabError("joint control needs a rig with two muscles (an antagonistic pair)")
    a, b = rig.muscles
    dt = settings.loop.dt
    p_max = float(
        min(
            rig.limits.max_muscle_pressure_MPa,
            *(r.max_pressure_MPa for r in rig.regulators.values()),
        )
    )
    ctl = JointController(controller, settings, p_max, statics)
    names = sampled(rig.channels)
    i_angle = names.index("angle")
    i_pf, i_pe = names.index(f"muscle_pressure_{a}"), names.index(f"muscle_pressure_{b}")
    monitor = SafetyMonitor(rig.limits, channels=[rig.channels[n] for n in names])
    settle = float(settings.settle_s)
    n = int(round((settle + duration_s) / dt)) + 1
    sig = {k: np.full(n, np.nan) for k in JOINT_SIGNALS}
    cols = [sig[k] for k in JOINT_SIGNALS]
    done = [0]
    reg_a, reg_b = rig.regulators[a], rig.regulators[b]
    every = max(1, int(1.0 / dt))

    def step(k: int, tr: float, v: tuple[float, ...], lk: float) -> tuple[float, float]:
        t_ref = tr - settle
        if t_ref < 0.0:
            r, r_d = 0.0, 0.0
        else:
            r, r_d, _ = reference.value(t_ref)
        ang = v[i_angle]
        pf, pe, s, ff = ctl.step(r, r_d, ang)
        if not (math.isfinite(pf) and math.isfinite(pe)):
            raise _Diverged("controller output is not finite (diverged)")
        i = done[0]
        for col, val in zip(cols, (t_ref, ang, r, s, v[i_pf], v[i_pe], pf, pe, ff), strict=True):
            col[i] = val
        done[0] = i + 1
        if progress is not None and k % every == 0:
            progress(tr)
        return pf, pe

    def command(u: tuple[float, float]) -> None:
        reg_a.set_pressure(u[0])
        reg_b.set_pressure(u[1])

    vented = None

    def on_trip(reason: str, *_sample: object) -> None:
        nonlocal vented
        vented = rig.vent()  # in this sample period

    status = "completed"
    pending: dict[str, int | None] = {"sig": None}
    wall0 = time.perf_counter()
    try:
        with deferred_signals(pending):
            rig.sampler.start()
            sample_loop(
                rig.clock,
                rig.sampler,
                1.0 / dt,
                n,
                check=monitor.check,
                step=step,
                command=command,
                on_trip=on_trip,
                pending=pending,
                stats=LoopStats(),
                late_threshold_s=LATE_THRESHOLD_S,
                channels=names,
            )
    except Trip as exc:
        status = f"aborted: {exc}"
    except _Diverged as exc:
        status = f"aborted: {exc}"
    except Terminated:
        status = "aborted: terminated (SIGTERM)"
    except KeyboardInterrupt:
        status = "aborted: interrupted (Ctrl-C)"
    except PmalabError as exc:
        status = f"aborted: {exc}"
    finally:
        if vented is None or not vented.ok:
            vented = rig.vent()
        try:
            rig.sampler.stop()
        except Exception:  # the vent above is what matters
            pass
    keep = slice(0, done[0])
    signals = {k: v[keep] for k, v in sig.items()}
    run = JointRun(
        name or controller,
        controller,
        reference,
        settings.cocontraction_MPa,
        signals,
        status,
        vented.line(),
        vented.ok,
        time.perf_counter() - wall0,
    )
    run.metrics = joint_metrics(run, duration_s)
    return run


def joint_metrics(run: JointRun, duration_s: float) -> dict[str, Any]:
    """Step metrics of the angle (python-control's ``step_info``, 2 % settling) over the
    reference's steps, from its start (the settle time is left out)."""
    s = run.signals
    keep = s["time"] >= 0.0
    t, y, r = s["time"][keep], s["angle"][keep], s["angle_reference"][keep]
    if t.size < 2:
        return {"kind": run.reference.kind}
    return summarize(run.reference.kind, t, y, r, run.reference.step_times(duration_s))


class _Diverged(Exception):
    """The controller's output is not finite (the run aborts, vented)."""


__all__ = [
    "JointController",
    "JointRun",
    "JointSettings",
    "StaticPair",
    "default_joint_settings",
    "run_joint",
]
