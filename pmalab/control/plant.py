"""Model-in-the-loop: the manipulator with the *identified* muscle as its plant.

``pmalab control --plant MODEL_DIR`` runs any controller against a manipulator whose muscle
is an ``identification.json`` integrated forward (:mod:`pmalab.identify.forward`, the one
integrator ``pmalab simulate`` and ``identify --output position`` use) instead of the
simulated rig's muscle truth.  A user tunes on the model first, then compares with the rig
run of the same experiment (``pmalab report`` overlays them).

Everything but the muscle is the simulated manipulator's (:mod:`pmalab.rig.sim.manipulator`,
same :class:`~pmalab.rig.sim.manipulator.ManipulatorSpec`): the link's moving mass, return
spring and preload, bearing viscous friction, end stops (here: position clamped, velocity
stopped), the home position (same coordinates, so model and rig runs overlay), and the
regulator of the truth file's ``[regulator]`` — the command quantised to ``bits``, applied
after ``dead_time_ms``, first-order lag ``time_constant_ms`` — whose output is taken as the
muscle pressure (the muscle's own filling lag and the bearing's Coulomb friction are left
out, as are sensor noise and delays: the plant is what the identified model knows).

Along the muscle (x absolute contraction, mm; F N; masses kg)::

    (m_link + m_model)·ẍ·10⁻³ = F_model(x, ẋ, h, p) − (F_s0 + k_s·x) − b·ẋ

with θ(p) from the identification's pressure laws at the current pressure.  Units as
everywhere in pmalab: s, mm, N, MPa gauge.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from pmalab.errors import ConfigError, RigError
from pmalab.identify.forward import (
    Coefficients,
    ForwardError,
    IdentifiedPlant,
    Load,
    _integrate_py,
    compiled_loops,
    substeps,
)
from pmalab.rig.base import Clock, Limits
from pmalab.rig.manipulator import ManipulatorGeometry, ManipulatorRig
from pmalab.rig.sim.manipulator import (
    ManipulatorPhysics,
    ManipulatorSpec,
    assemble_manipulator,
)
from pmalab.rig.sim.truth import Truth, default_truth


class PlantPhysics:
    """The manipulator with an identified muscle, integrated on demand (module docstring).

    Same interface as :class:`~pmalab.rig.sim.manipulator.ManipulatorPhysics`, so the
    simulated manipulator's sampler and regulator drive it unchanged."""

    def __init__(
        self,
        plant: IdentifiedPlant,
        truth: Truth | None = None,
        spec: ManipulatorSpec | None = None,
    ) -> None:
        self.plant = plant
        model = plant.model
        # a law with a compiled segment runs in the compiled loop; an element law (its
        # state a vector) in the same scheme in Python, its state carried between samples
        self.loops = compiled_loops(model.law)
        self.law_id: int | None = None if self.loops is None else self.loops.law_id
        self._state: Any = None
        self.truth = truth or default_truth()
        self.spec = (spec or ManipulatorSpec()).checked()
        # the rig's own geometry and home (same coordinates as a rig run of the experiment)
        ref = ManipulatorPhysics(self.truth, self.spec, 0)
        self.home_contraction_mm = ref.home_contraction_mm
        self._geometry = ref.geometry
        reg = self.truth.section("regulator")
        self.max_MPa = min(
            float(reg["max_pressure_MPa"]), float(self.truth.section("muscle")["max_pressure_MPa"])
        )
        levels = 2 ** int(reg["bits"]) - 1
        self._q = float(reg["max_pressure_MPa"]) / levels
        self._dead = float(reg["dead_time_ms"]) * 1e-3
        self._tau = max(float(reg["time_constant_ms"]) * 1e-3, 1e-6)
        try:
            self.coef = Coefficients(model, plant.free_laws(), plant.bounds)
        except ForwardError as exc:
            raise ConfigError(f"--plant {plant.source}: {exc}") from None
        # the bearing's viscous friction joins the model's damping term (slot "damping")
        self.coef.Q[3, 0] += self.spec.bearing_viscous_N_s_per_mm
        self.load = Load(
            self.spec.moving_mass_kg, self.spec.spring_N_per_mm, self.spec.spring_preload_N
        )
        p_lo, p_hi = plant.pressure_range
        ps = np.array(
            [0.0, p_lo if math.isfinite(p_lo) else 0.3, p_hi if math.isfinite(p_hi) else 0.6]
        )
        self.n_sub = substeps(model, self.coef, ps, 1.0 / 500.0, self.load)
        self._t = 0.0
        # at rest at the rig's home (the same coordinates as a rig run).  Below the
        # identified pressure range (a vented start) the model extrapolates θ(p): the
        # first fraction of a second of a run shows that, not the muscle
        self._x = self.home_contraction_mm
        self._v = 0.0
        self._h = 0.0
        self._p = 0.0
        self._command = 0.0
        self._pending: list[tuple[float, float]] = []  # (time applied, quantised MPa)
        self._target = 0.0
        self._tension = 0.0
        self._out = np.zeros(5)
        self._buf = [np.zeros(2) for _ in range(4)]
        self._tt = np.zeros(2)
        self._uu = np.zeros(2)
        self._pp = np.zeros(2)

    @property
    def geometry(self) -> ManipulatorGeometry:
        return self._geometry

    @property
    def time(self) -> float:
        return self._t

    @property
    def command(self) -> float:
        return self._command

    def set_command(self, mpa: float) -> None:
        mpa = float(mpa)
        if not -1e-9 <= mpa <= self.max_MPa + 1e-9:
            raise RigError(
                f"plant-model manipulator: command {mpa:g} MPa outside 0–{self.max_MPa:g} MPa"
            )
        self._command = min(max(mpa, 0.0), self.max_MPa)
        self._pending.append((self._t + self._dead, round(self._command / self._q) * self._q))

    def _step(self, t1: float) -> None:
        """One interval: the regulator's exact first-order response, then the muscle."""
        while self._pending and self._pending[0][0] <= t1:
            ta, q = self._pending.pop(0)
            if ta > self._t:  # the lag runs to ta with the old target first
                self._p = self._target + (self._p - self._target) * math.exp(
                    -(ta - self._t) / self._tau
                )
                self._advance_muscle(ta, self._p)
            self._target = q
        p1 = self._target + (self._p - self._target) * math.exp(-(t1 - self._t) / self._tau)
        self._advance_muscle(t1, p1)

    def _advance_muscle(self, t1: float, p1: float) -> None:
        if not t1 > self._t:
            self._p = p1
            return
        self._tt[0], self._tt[1] = self._t, t1
        self._pp[0], self._pp[1] = self._p, p1
        self._uu[:] = self.load.preload_N
        xo, vo, ho, fo = self._buf
        c = self.coef
        if self.law_id is None:
            code, _, self._state = _integrate_py(
                self.plant.model,
                c,
                self._tt,
                self._uu,
                self._pp,
                0.0,
                self.load,
                self._x,
                self._v,
                self._h,
                self.n_sub,
                xo,
                vo,
                ho,
                fo,
                state=self._state,
            )
            self._finish(code, t1, p1)
            return
        assert self.loops is not None
        code, _ = self.loops.integrate(
            self.law_id,
            self._tt,
            self._uu,
            self._pp,
            0.0,
            c.Q,
            c.lo,
            c.hi,
            c.extras,
            c.n_slots,
            self.load.mass_kg,
            self.load.stiffness_N_per_mm,
            self._x,
            self._v,
            self._h,
            self.n_sub,
            xo,
            vo,
            ho,
            fo,
        )
        self._finish(code, t1, p1)

    def _finish(self, code: int, t1: float, p1: float) -> None:
        xo, vo, ho, fo = self._buf
        if code != 0:
            raise RigError(
                f"plant-model manipulator: the identified model ran away at "
                f"t = {t1:.3f} s (pressure {p1:.3g} MPa)"
            )
        x, v = float(xo[1]), float(vo[1])
        s = self.spec
        if x < s.stop_min_mm or x > s.stop_max_mm:  # the link's end stops
            x = min(max(x, s.stop_min_mm), s.stop_max_mm)
            v = 0.0
        self._x, self._v, self._h = x, v, float(ho[1])
        self._tension = float(fo[1])
        self._t, self._p = t1, p1

    def advance_to(self, t: float) -> None:
        if not t > self._t:
            return
        if not math.isfinite(t):
            raise RigError(f"plant-model manipulator: cannot advance to t = {t}")
        dt = 1.0 / 500.0
        while self._t < t - 1e-12:
            self._step(min(self._t + dt, t))

    def advance_and_sample(self, t: float) -> np.ndarray:
        """Advance to ``t``: (time, position from home, tension, muscle pressure, 0)."""
        self.advance_to(t)
        o = self._out
        o[0], o[1], o[2], o[3], o[4] = (
            self._t,
            self._x - self.home_contraction_mm,
            self._tension,
            self._p,
            0.0,
        )
        return o

    def truth_state(self) -> dict[str, Any]:
        return {
            "time": self._t,
            "position": self._x - self.home_contraction_mm,
            "contraction": self._x,
            "velocity": self._v,
            "muscle_pressure": self._p,
            "command_applied": self._target,
            "tension": self._tension,
        }


def make_plant_manipulator(
    model_dir: str | Path,
    truth: Truth | None = None,
    *,
    spec: ManipulatorSpec | None = None,
    clock: Clock | None = None,
    limits: Limits | None = None,
) -> ManipulatorRig:
    """A :class:`~pmalab.rig.manipulator.ManipulatorRig` whose muscle is the identified
    model of ``model_dir`` (a directory holding ``identification.json``, or the file)."""
    try:
        plant = IdentifiedPlant.read(model_dir)
    except ForwardError as exc:
        raise ConfigError(f"--plant: {exc}") from None
    physics = PlantPhysics(plant, truth, spec)
    info = {
        "kind": "plant-model-manipulator",
        "truth": f"plant model {plant.source}",
        "plant": plant.source,
        "plant_law": plant.model.name,
    }
    return assemble_manipulator(physics, info, clock=clock, limits=limits)
