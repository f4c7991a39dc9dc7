"""The seeds' cascade: position loop → desired tension → model inversion → pressure loop.

Per sample (T = 2 ms), with x the measured position from home (mm), p the measured muscle
pressure (MPa) and r, r̈ the position reference and its acceleration::

    (r, ṙ, r̈) → set point (s, ṡ, s̈)                   rate/acceleration-limited (shaping)
    x̃      = low-pass(x)                              (drives the model, not the PID)
    h      = law.step(h, x_abs(k−1), x_abs(k), θ(p))   x_abs = x_home + x̃ (the identified
                                                       model is in absolute contraction)
    F_ff   = F_spring(x_home + s) + m·s̈               (the manipulator's known dynamics)
    F_d    = outer(s, x, F_ff)                         ∈ [0, F_max]  (a muscle only pulls)
    p_d    = model⁻¹(F_d; x_abs, h)                    ∈ [0, p_max]
    h_s    = law.step(h_s, x_home + s(k−1), x_home + s(k), θ(p_ff))   (h along the set point)
    p_ff   = model⁻¹(F_ff; x_home + s, h_s)            (what the model needs to hold s)
    u      = p_ff + τ_lead·ṗ_ff + inner(p_d, p)        ∈ [0, p_max]  → regulator command

Without shaping s = r; without ``reference_feedforward`` u = inner(p_d, p) (the seeds');
without ``hysteresis_compensation`` both inversions use h = h_s = 0 (the static curve only;
h is still tracked and recorded).

The pressure-loop experiment uses the inner loop alone: u = inner(p_ref, p).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pmalab.control.controllers import CascadeSettings, make_loop
from pmalab.control.model import HysteresisState, IdentifiedModel
from pmalab.control.reference import ReferenceShaper
from pmalab.errors import PmalabError
from pmalab.rig.manipulator import ManipulatorGeometry


@dataclass
class CascadeOutput:
    """One sample's internal signals (for recording)."""

    command: float  # MPa, to the regulator
    pressure_reference: float  # MPa, the inner loop's reference
    force_reference: float  # N (NaN in the pressure loop)
    hysteresis: float  # N (NaN in the pressure loop)
    setpoint: float = math.nan  # mm, the shaped position set point (NaN in the pressure loop)


class _NoModel:
    """Stands in for the model of a pressure-loop-only cascade: the position loop refuses."""

    def invert(self, *args: float) -> float:
        raise PmalabError("the position loop needs an identified model (--model)")


class Cascade:
    """Both loops of one controller kind (``pid``, ``sn-pid`` or ``rbf-pid``)."""

    #: low-pass (Hz) on the feedforward pressure's rate of change that the lead multiplies
    LEAD_FILTER_HZ = 20.0

    def __init__(
        self,
        controller: str,
        settings: CascadeSettings,
        model: IdentifiedModel | None,
        geometry: ManipulatorGeometry,
        p_max: float,
        hysteresis: HysteresisState | None = None,
    ) -> None:
        self.controller = controller
        self.settings = settings
        self.model = model
        self.geometry = geometry
        self.p_max = float(p_max)
        self.outer = make_loop(controller, settings.outer)
        self.inner = make_loop(controller, settings.inner)
        self.hyst = hysteresis
        if model is not None and hysteresis is None:
            self.hyst = HysteresisState(model, geometry.home_contraction_mm)
        self._model = model if model is not None else _NoModel()
        self._a = 1.0 - math.exp(-2.0 * math.pi * settings.position_filter_Hz * settings.outer.dt)
        self._xf: float | None = None
        self.shaper = None
        self.hyst_ref = None
        self._p_ff = 0.0
        self._dp_ff = 0.0
        self._first_ff = True
        self._a_lead = 1.0 - math.exp(-2.0 * math.pi * self.LEAD_FILTER_HZ * settings.outer.dt)
        if model is not None and settings.reference_feedforward:
            self.hyst_ref = HysteresisState(model, geometry.home_contraction_mm)
        if settings.shaping_velocity_mm_s > 0 and settings.shaping_accel_mm_s2 > 0:
            self.shaper = ReferenceShaper(
                settings.shaping_velocity_mm_s, settings.shaping_accel_mm_s2, settings.outer.dt
            )

    def position_step(self, r: float, r_d: float, r_dd: float, x: float, p: float) -> CascadeOutput:
        """One sample of the position loop (see the module docstring); ``r`` mm, ``r_d``
        mm/s, ``r_dd`` mm/s² (the reference and its derivatives)."""
        g = self.geometry
        if self.shaper is not None:
            if self.shaper.s is None:  # the first sample: start where the link is
                self.shaper.start(x)
            r, r_d, r_dd = self.shaper.step(r, r_d)
        xf = x if self._xf is None else self._xf + self._a * (x - self._xf)
        self._xf = xf
        x_abs = g.home_contraction_mm + xf
        h = self.hyst.update(x_abs, p) if self.hyst is not None else 0.0
        ff = 0.0
        if self.settings.feedforward:
            ff = g.spring_force(g.home_contraction_mm + r) + g.moving_mass_kg * r_dd * 1e-3
        f_d = self.outer.step(r, x, ff)
        comp = 1.0 if self.settings.hysteresis_compensation else 0.0
        p_d = self._model.invert(f_d, x_abs, comp * h, self.p_max)
        if self.settings.inner_feedforward:  # the regulator gets p_d itself (an option)
            u = self.inner.step(p_d, p, p_d)
        elif self.hyst_ref is not None:
            xr_abs = g.home_contraction_mm + r
            h_r = self.hyst_ref.update(xr_abs, self._p_ff)
            p_ff = self._model.invert(ff, xr_abs, comp * h_r, self.p_max)
            # ṗ_ff through a 20 Hz low-pass: h along the set point is advanced with θ bound
            # per 1 kPa (HysteresisState), so p_ff moves in small jumps a raw difference
            # would turn into one-sample spikes of the lead
            if self._first_ff:  # no history yet: no rate of change
                self._p_ff, self._first_ff = p_ff, False
            dp = (p_ff - self._p_ff) / self.settings.outer.dt
            self._dp_ff += self._a_lead * (dp - self._dp_ff)
            self._p_ff = p_ff
            u = self.inner.step(p_d, p, p_ff + self.settings.feedforward_lead_s * self._dp_ff)
        else:
            u = self.inner.step(p_d, p)
        return CascadeOutput(u, p_d, f_d, h, r)

    def pressure_step(self, p_ref: float, p: float) -> CascadeOutput:
        """One sample of the pressure loop alone."""
        u = self.inner.step(p_ref, p, p_ref if self.settings.inner_feedforward else 0.0)
        return CascadeOutput(u, p_ref, math.nan, math.nan)

    def gains(self) -> tuple[float, ...]:
        """(outer Kp, Ki, Kd, inner Kp, Ki, Kd) now."""
        return (*self.outer.gains, *self.inner.gains)
