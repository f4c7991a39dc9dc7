"""The simulated 1-DOF manipulator of the seed papers, behind :mod:`pmalab.rig.manipulator`.

One DMSP-20-120 muscle pulls a link on a rotary base of radius r against a return spring::

    J·θ̈ = r·(F_muscle − F_spring) − τ_bearing        (N·m, θ in rad)

Written along the muscle with x_abs = x_home + r·θ (contraction, mm) and m = J/r² (kg)::

    m·ẍ = F_muscle(x, ẋ, p, slip states) − (F_s0 + k_s·x_abs) − b·ẋ − F_c·tanh(ẋ/ε) + F_stop

* ``F_muscle`` is the **simulated muscle truth** of :mod:`pmalab.rig.sim.kernel` — the
  same static force law, Maxwell-slip braid friction and hidden effects (viscous friction,
  asymmetric hysteresis, nonlinear stiffness) the isobaric rig uses, from the same truth
  file.  Nothing here comes from the identified models (no inverse crime).
* The muscle pressure goes through the **regulator model** of the truth file's
  ``[regulator]`` (ITV1050-class: command quantised to ``bits`` over 0..max, applied after
  ``dead_time_ms``, first-order lag ``time_constant_ms`` on the regulator's output) and then
  fills the **muscle volume** V(x) = V0 + dV/dx·x through the line: ṗ = (p_reg − p)/τ_fill ·
  V0/V − (p + p_atm)·V̇/V (isothermal; a bigger volume fills more slowly, a contracting
  muscle whose volume grows loses pressure — the oscillation S1 describes at full
  contraction).
* Sensors: the truth file's position and pressure gauge models (lag, noise, quantisation,
  delay and drift effects); ``force`` is a load cell in series with the muscle.

Position is reported from the *home* position: the equilibrium of the vented manipulator
(spring against the stretched muscle), so the controller's 0 mm is where the link rests.
Units: s, mm, N, MPa gauge, kg, cm³.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from pmalab.errors import RigError
from pmalab.rig.base import (
    Block,
    Clock,
    Limits,
    Sampler,
    VirtualClock,
)
from pmalab.rig.manipulator import ManipulatorGeometry, ManipulatorRig
from pmalab.rig.sim import kernel as K
from pmalab.rig.sim.physics import build_params
from pmalab.rig.sim.regulator import SimulatedRegulator
from pmalab.rig.sim.truth import Truth, default_truth, load_truth

_NOISE_BLOCK = 4096
#: _KERNEL_STAMP: the compiled manipulator kernel is built from the isobaric kernel's
#: functions and state/parameter layout (pmalab.rig.sim.kernel), but numba's disk cache is
#: keyed on *this* file only, so a change of the kernel would leave a stale compiled copy
#: reading the wrong slots.  :func:`_drop_stale_cache` (run at import) stores a hash of
#: kernel.py next to the cache and deletes this module's cached code when it changed.


@dataclass(frozen=True)
class ManipulatorSpec:
    """Mechanics and pneumatics of the simulated manipulator (the muscle is the truth file's).

    The defaults put 10 / 15 / 20 mm of travel at about 0.2 / 0.3 / 0.42 MPa, so the
    seeds' experiments stay inside the DMSP-20's 0.6 MPa rating with margin.
    """

    radius_mm: float = 30.0  #: rotary base radius r (mm)
    inertia_kg_m2: float = 0.02  #: link inertia J about the base (kg·m²)
    spring_N_per_mm: float = 10.0  #: return spring stiffness along the muscle (N/mm)
    spring_preload_N: float = 30.0  #: spring force at the muscle's nominal length (N)
    bearing_viscous_N_s_per_mm: float = 0.15  #: bearing viscous friction along the muscle
    bearing_coulomb_N: float = 2.0  #: bearing Coulomb friction along the muscle (N)
    smoothing_velocity_mm_s: float = 0.05  #: tanh smoothing of sign(ẋ) (mm/s)
    stop_min_mm: float = -3.0  #: link end stops, absolute contraction (mm)
    stop_max_mm: float = 29.0
    stop_stiffness_N_per_mm: float = 5000.0
    stop_damping_N_s_per_mm: float = 20.0
    volume_cm3: float = 50.0  #: muscle + tubing volume at nominal length (cm³)
    dvolume_cm3_per_mm: float = 1.0  #: volume growth per mm of contraction (cm³/mm)
    fill_time_constant_s: float = 0.12  #: regulator → muscle filling at volume_cm3 (s)

    def checked(self) -> ManipulatorSpec:
        """Self, or a :class:`~pmalab.errors.RigError` naming the implausible field."""
        for k, v in asdict(self).items():
            if not math.isfinite(v):
                raise RigError(f"manipulator: {k}: must be a finite number")
        positive = (
            "radius_mm",
            "inertia_kg_m2",
            "volume_cm3",
            "fill_time_constant_s",
            "smoothing_velocity_mm_s",
            "stop_stiffness_N_per_mm",
        )
        for k in positive:
            if getattr(self, k) <= 0:
                raise RigError(f"manipulator: {k}: must be > 0")
        for k in (
            "spring_N_per_mm",
            "spring_preload_N",
            "bearing_viscous_N_s_per_mm",
            "bearing_coulomb_N",
            "stop_damping_N_s_per_mm",
            "dvolume_cm3_per_mm",
        ):
            if getattr(self, k) < 0:
                raise RigError(f"manipulator: {k}: must be ≥ 0")
        if self.stop_min_mm >= self.stop_max_mm:
            raise RigError("manipulator: stop_min_mm: must be < stop_max_mm")
        return self

    @property
    def moving_mass_kg(self) -> float:
        """J/r²: the link's inertia seen along the muscle (kg)."""
        return self.inertia_kg_m2 / (self.radius_mm * 1e-3) ** 2


# ----------------------------------------------------------------- manipulator parameters
Q_MASS = 0
Q_KS = 1
Q_FS0 = 2
Q_BV = 3
Q_FC = 4
Q_EPS = 5
Q_XLO = 6
Q_XHI = 7
Q_KSTOP = 8
Q_CSTOP = 9
Q_V0 = 10
Q_DVDX = 11
Q_TFILL = 12
Q_TREG = 13
N_Q = 14


def _manip_params(spec: ManipulatorSpec, truth: Truth) -> np.ndarray:
    q = np.zeros(N_Q)
    q[Q_MASS] = spec.moving_mass_kg + ((truth.effect("inertia") or {}).get("mass_kg", 0.0))
    q[Q_KS] = spec.spring_N_per_mm
    q[Q_FS0] = spec.spring_preload_N
    q[Q_BV] = spec.bearing_viscous_N_s_per_mm
    q[Q_FC] = spec.bearing_coulomb_N
    q[Q_EPS] = spec.smoothing_velocity_mm_s
    q[Q_XLO] = spec.stop_min_mm
    q[Q_XHI] = spec.stop_max_mm
    q[Q_KSTOP] = spec.stop_stiffness_N_per_mm
    q[Q_CSTOP] = spec.stop_damping_N_s_per_mm
    q[Q_V0] = spec.volume_cm3
    q[Q_DVDX] = spec.dvolume_cm3_per_mm
    q[Q_TFILL] = spec.fill_time_constant_s
    q[Q_TREG] = truth.section("regulator")["time_constant_ms"] * 1e-3
    return q


@njit(cache=True)  # see _KERNEL_STAMP
def _advance(st, par, mq, pend, ptr, hist, t_target):
    """Integrate the manipulator from ``st[S_T]`` to ``t_target`` (sub-steps ≤ P_HMAX).

    State layout is the isobaric kernel's (x, v, muscle pressure, slip elements, sensor
    filters); ``S_PC`` holds the regulator's output pressure, ``S_CMD`` the command in
    effect.  Linearly implicit Euler on (x, v) as in :func:`pmalab.rig.sim.kernel._advance`.
    Returns 0, or 1 when the state became non-finite.
    """
    t0 = st[K.S_T]
    span = t_target - t0
    if span <= 0.0:
        return 0
    n = int(math.ceil(span / par[K.P_HMAX] - 1e-9))
    if n < 1:
        n = 1
    dt = span / n
    a_reg = 1.0 - math.exp(-dt / mq[Q_TREG]) if mq[Q_TREG] > 0.0 else 1.0
    a_yx = 1.0 - math.exp(-dt / par[K.P_TAU_YX]) if par[K.P_TAU_YX] > 0.0 else 1.0
    a_yf = 1.0 - math.exp(-dt / par[K.P_TAU_YF]) if par[K.P_TAU_YF] > 0.0 else 1.0
    a_ypm = 1.0 - math.exp(-dt / par[K.P_TAU_YPM]) if par[K.P_TAU_YPM] > 0.0 else 1.0
    kv = 1000.0 / mq[Q_MASS]
    ks = mq[Q_KS]
    fs0 = mq[Q_FS0]
    bv = mq[Q_BV]
    fcb = mq[Q_FC]
    eps = mq[Q_EPS]
    xlo = mq[Q_XLO]
    xhi = mq[Q_XHI]
    kstop = mq[Q_KSTOP]
    cstop = mq[Q_CSTOP]
    v0 = mq[Q_V0]
    dvdx = mq[Q_DVDX]
    tfill = mq[Q_TFILL]
    cv = par[K.P_CVISC]
    mb = par[K.P_MB]
    ne = int(par[K.P_NE])
    rd = par[K.P_RD]
    for j in range(n):
        t = t0 + j * dt
        while ptr[K.R_HEAD] < ptr[K.R_TAIL] and pend[ptr[K.R_HEAD] % K.PEND_SIZE, 0] <= t + 1e-12:
            st[K.S_CMD] = pend[ptr[K.R_HEAD] % K.PEND_SIZE, 1]
            ptr[K.R_HEAD] += 1
        x = st[K.S_X]
        v = st[K.S_V]
        # --- pneumatics: regulator output lag, then the line fills the muscle's volume
        st[K.S_PC] += a_reg * (st[K.S_CMD] - st[K.S_PC])
        vol = v0 + dvdx * x
        if vol < 0.1 * v0:
            vol = 0.1 * v0
        pm = st[K.S_PM]
        a_fill = 1.0 - math.exp(-dt * v0 / (tfill * vol))
        pm += a_fill * (st[K.S_PC] - pm)
        pm -= (pm + K.P_ATM) * dvdx * v * dt / vol  # isothermal: p·V = const while sealed
        if pm < 0.0:
            pm = 0.0
        st[K.S_PM] = pm
        # --- muscle tension (the truth model) and its stiffness
        fs, dfs, q, xm = K._static_terms(par, x, pm)
        ff, dff = K._friction_terms(par, st, q, v, x / xm)
        tension = fs + ff - cv * v
        if tension < 0.0:
            tension = 0.0
            dfs = 0.0
            dff = 0.0
        # --- the link: spring, bearing friction, end stops
        th = math.tanh(v / eps)
        fbear = fcb * th + bv * v
        dbear = fcb * (1.0 - th * th) / eps + bv
        fstop, sjx, sjv = K._end_stop(x, v, xlo, xhi, kstop, cstop)
        jx = dfs + dff - ks + sjx
        jv = -cv - dbear + sjv
        if jx > 0.0:
            jx = 0.0
        net = tension - (fs0 + ks * x) - fbear + fstop
        vn = (v + dt * kv * (net - jv * v)) / (1.0 - dt * kv * jv - dt * dt * kv * jx)
        xn = x + dt * vn
        acc = (vn - v) / dt
        dx = xn - x
        ds = K._slip_scale(par, q)
        for i in range(ne):
            d = par[K.P_DELTA0 + i] * ds
            u = st[K.S_U0 + i] + dx
            if u > d:
                u = d
            elif u < -d * rd:
                u = -d * rd
            st[K.S_U0 + i] = u
        st[K.S_X] = xn
        st[K.S_V] = vn
        st[K.S_A] = acc
        st[K.S_T] = t0 + (j + 1) * dt
        flc = tension - mb * acc * 1e-3
        st[K.S_FLC] = flc
        st[K.S_YX] += a_yx * (xn - st[K.S_YX])
        st[K.S_YF] += a_yf * (flc - st[K.S_YF])
        st[K.S_YPM] += a_ypm * (pm - st[K.S_YPM])
        st[K.S_YPC] = 0.0  # no cylinder
        h = ptr[K.R_HIDX]
        hist[h, 0] = st[K.S_T]
        hist[h, 1] = st[K.S_YX]
        hist[h, 2] = st[K.S_YF]
        hist[h, 3] = st[K.S_YPM]
        hist[h, 4] = 0.0
        ptr[K.R_HIDX] = (h + 1) % K.HIST_SIZE
        if ptr[K.R_HCNT] < K.HIST_SIZE:
            ptr[K.R_HCNT] += 1
    st[K.S_T] = t_target
    for k in range(K.N_STATE):
        if not math.isfinite(st[k]):
            return 1
    return 0


@njit(cache=True)  # see _KERNEL_STAMP
def advance_measure(w, mq, pend, ptr, hist, noise, t_target):
    """Integrate to ``t_target`` and write the five channels into ``w[O_OUT:]``.

    Returns bit 0 = non-finite state, bit 1 = noise block used up.
    """
    rc = _advance(w[K.O_ST : K.O_PAR], w[K.O_PAR : K.O_MPAR], mq, pend, ptr, hist, t_target)
    return rc | K.measure(w, ptr, hist, noise)


@njit(cache=True)  # see _KERNEL_STAMP
def advance_only(w, mq, pend, ptr, hist, t_target):
    return _advance(w[K.O_ST : K.O_PAR], w[K.O_PAR : K.O_MPAR], mq, pend, ptr, hist, t_target)


def _drop_stale_cache() -> None:
    """Delete this module's numba cache files when kernel.py changed since they were made."""
    import hashlib

    try:
        digest = hashlib.sha256(Path(K.__file__).read_bytes()).hexdigest()[:16]
    except OSError:
        return
    for fn in (_advance, advance_measure, advance_only):
        path = getattr(getattr(fn, "_cache", None), "_cache_path", None)
        if not path:
            continue
        stamp = Path(path) / f"{__name__.rsplit('.', 1)[-1]}.kernel-stamp"
        try:
            if stamp.read_text() == digest:
                continue
        except OSError:
            pass
        for old in Path(path).glob(f"{__name__.rsplit('.', 1)[-1]}.*.nb[ic]"):
            old.unlink(missing_ok=True)
        try:
            stamp.write_text(digest)
        except OSError:
            pass


_drop_stale_cache()


class ManipulatorPhysics:
    """State of the simulated manipulator, integrated on demand (see the module docstring).

    ``truth``: the muscle, regulator and sensors (a :class:`Truth`, a truth TOML path or
    ``None`` for the defaults); ``spec``: the link and the pneumatics; ``seed``: the
    sensor-noise seed (same seed and calls → bit-for-bit the same samples).  The manipulator
    starts vented and at rest at its home position.
    """

    def __init__(
        self,
        truth: Truth | str | Path | None = None,
        spec: ManipulatorSpec | None = None,
        seed: int = 0,
    ) -> None:
        if truth is None:
            truth = default_truth()
        elif not isinstance(truth, Truth):
            truth = load_truth(truth)
        self.truth = truth
        self.spec = (spec or ManipulatorSpec()).checked()
        self.seed = int(seed)
        self._w, self._pend, self._ptr, self._hist = K.new_buffers()
        st = self._w[K.O_ST : K.O_PAR]
        self._st = st
        self._par = self._w[K.O_PAR : K.O_MPAR]
        self._par[:], self._w[K.O_MPAR : K.O_OUT] = build_params(truth)
        self._out = self._w[K.O_OUT : K.N_W]
        self._mq = _manip_params(self.spec, truth)
        reg = truth.section("regulator")
        self.max_MPa = min(
            float(reg["max_pressure_MPa"]), float(truth.section("muscle")["max_pressure_MPa"])
        )
        levels = 2 ** int(reg["bits"]) - 1
        self._q_per_mpa = levels / float(reg["max_pressure_MPa"])
        self._mpa_per_q = float(reg["max_pressure_MPa"]) / levels
        self._dead = reg["dead_time_ms"] * 1e-3
        self._tail = 0
        self._command = 0.0
        self._rng = np.random.default_rng(self.seed)
        self._noise = self._rng.standard_normal((_NOISE_BLOCK, 4))
        # home: the vented muscle stretched by the spring preload (stretch stiffness only)
        self.home_contraction_mm = self._home()
        st[K.S_X] = self.home_contraction_mm
        st[K.S_YX] = self.home_contraction_mm
        self._st[K.S_YF] = self.spec.spring_preload_N + self.spec.spring_N_per_mm * st[K.S_X]
        st[K.S_FLC] = st[K.S_YF]

    def _home(self) -> float:
        """Absolute contraction (mm) where spring and vented muscle balance."""
        s = self.spec
        k_stretch = float(self._par[K.P_KSTRETCH])
        x = -s.spring_preload_N / (k_stretch + s.spring_N_per_mm) if k_stretch > 0 else 0.0
        return max(x, s.stop_min_mm)

    @property
    def geometry(self) -> ManipulatorGeometry:
        s = self.spec
        return ManipulatorGeometry(
            home_contraction_mm=self.home_contraction_mm,
            spring_N_per_mm=s.spring_N_per_mm,
            spring_preload_N=s.spring_preload_N,
            moving_mass_kg=s.moving_mass_kg,
            radius_mm=s.radius_mm,
        )

    @property
    def time(self) -> float:
        return float(self._st[K.S_T])

    def advance_to(self, t: float) -> None:
        """Integrate up to ``t`` (s); a ``t`` in the past is ignored."""
        if not t > self._st[K.S_T]:
            return
        if not math.isfinite(t):
            raise RigError(f"simulated manipulator: cannot advance to t = {t}")
        if advance_only(self._w, self._mq, self._pend, self._ptr, self._hist, float(t)):
            self._diverged()

    def _diverged(self) -> None:
        raise RigError(
            f"simulated manipulator: the physics left its envelope at "
            f"t = {self.time:.3f} s (non-finite state)"
        )

    def advance_and_sample(self, t: float) -> np.ndarray:
        """Advance to ``t`` and measure: (time, position from home, force, p_muscle, 0).

        The returned array is reused by the next call: copy it to keep it.
        """
        rc = advance_measure(
            self._w, self._mq, self._pend, self._ptr, self._hist, self._noise, float(t)
        )
        if rc:
            if rc & 1:
                self._diverged()
            self._noise = self._rng.standard_normal((_NOISE_BLOCK, 4))
            self._ptr[K.R_NI] = 0
        self._out[1] -= self.home_contraction_mm
        return self._out

    def set_command(self, mpa: float) -> None:
        """Command the muscle's regulator (MPa): quantised, applied after the dead time."""
        mpa = float(mpa)
        if not -1e-9 <= mpa <= self.max_MPa + 1e-9:  # also rejects NaN
            raise RigError(
                f"simulated muscle regulator: command {mpa:g} MPa outside 0–{self.max_MPa:g} MPa"
            )
        mpa = min(max(mpa, 0.0), self.max_MPa)
        self._command = mpa
        q = round(mpa * self._q_per_mpa) * self._mpa_per_q
        ptr = self._ptr
        tail = self._tail
        if tail - ptr[K.R_HEAD] >= K.PEND_SIZE:
            ptr[K.R_HEAD] += 1
        i = tail % K.PEND_SIZE
        self._pend[i, 0] = self._st[K.S_T] + self._dead
        self._pend[i, 1] = q
        self._tail = tail + 1
        ptr[K.R_TAIL] = tail + 1

    @property
    def command(self) -> float:
        return self._command

    def static_force(self, x: float, p: float) -> float:
        """The truth's static tension F_s(x, p) (N) at absolute contraction ``x`` (mm) —
        no friction, no dynamics (tests)."""
        fs, _, _, _ = K._static_terms(self._par, float(x), float(p))
        return float(fs)

    def truth_state(self) -> dict[str, Any]:
        """Noise-free values now (tests): position from home, velocity, pressures, tension."""
        st = self._st
        _, _, _, tension = K.forces_w(self._w)
        return {
            "time": float(st[K.S_T]),
            "position": float(st[K.S_X]) - self.home_contraction_mm,
            "contraction": float(st[K.S_X]),
            "velocity": float(st[K.S_V]),
            "muscle_pressure": float(st[K.S_PM]),
            "regulator_pressure": float(st[K.S_PC]),
            "command_applied": float(st[K.S_CMD]),
            "tension": float(tension),
        }


# ----------------------------------------------------------------- the rig devices
class ManipulatorSampler(Sampler):
    """Software-polled: each :meth:`read_block` takes one sample at ``clock.now()``."""

    hardware_timed = False

    def __init__(self, physics: ManipulatorPhysics, clock: Clock, rate_Hz: float = 500.0):
        self.physics = physics
        self.clock = clock
        self.sample_rate_Hz = float(rate_Hz)

    def read_block(self) -> Block:
        o = self.physics.advance_and_sample(self.clock.now()).copy()
        return Block(o[0:1], o[1:2], o[2:3], o[3:4], o[4:5])

    def read_now(self) -> np.ndarray:
        """Fast path: (time, position, force, muscle pressure, 0) now, as a reused array."""
        return self.physics.advance_and_sample(self.clock.now())


class ManipulatorRegulator(SimulatedRegulator):
    """The simulated ITV-class regulator feeding the muscle (0..rated pressure)."""

    def __init__(self, physics: ManipulatorPhysics, clock: Clock) -> None:
        super().__init__(physics, clock, physics.max_MPa, physics.set_command)


def make_sim_manipulator(
    truth: Truth | str | Path | None = None,
    *,
    spec: ManipulatorSpec | None = None,
    seed: int = 0,
    clock: Clock | None = None,
    limits: Limits | None = None,
) -> ManipulatorRig:
    """A simulated :class:`~pmalab.rig.manipulator.ManipulatorRig` on a virtual clock.

    ``truth``: the simulated muscle (a hidden effect switched on there is a plant/model
    mismatch the controller has to survive).  Limits default to the DMSP-20's 0.6 MPa and a
    travel of −3 … 27 mm from home.
    """
    physics = ManipulatorPhysics(truth, spec, seed)
    info = {
        "kind": "sim-manipulator",
        "truth": physics.truth.source,
        "enabled_effects": physics.truth.enabled_effects(),
        "seed": physics.seed,
    }
    return assemble_manipulator(physics, info, clock=clock, limits=limits)


def assemble_manipulator(
    physics: Any,
    info: dict[str, Any],
    *,
    clock: Clock | None = None,
    limits: Limits | None = None,
) -> ManipulatorRig:
    """A :class:`~pmalab.rig.manipulator.ManipulatorRig` around a manipulator physics
    object (:class:`ManipulatorPhysics` or any with its interface: ``time``,
    ``advance_to``, ``advance_and_sample``, ``set_command``, ``max_MPa``, ``geometry``,
    ``spec``, ``home_contraction_mm``): its sampler, regulator, clock (virtual by default)
    and limits (the DMSP-20's rating and a travel of −3 … 27 mm from home by default)."""
    clock = clock if clock is not None else VirtualClock()
    if clock.now() > physics.time:
        physics.advance_to(clock.now())
    lim = limits or Limits(
        max_muscle_pressure_MPa=physics.max_MPa,
        max_cylinder_pressure_MPa=0.9,
        max_force_N=2000.0,
        min_position_mm=-3.0,
        max_position_mm=27.0,
    )
    info = {
        **info,
        "manipulator": asdict(physics.spec),
        "home_contraction_mm": physics.home_contraction_mm,
        "clock": "virtual" if clock.virtual else "real",
        "physics": physics,
    }
    return ManipulatorRig(
        clock=clock,
        sampler=ManipulatorSampler(physics, clock),
        muscle_regulator=ManipulatorRegulator(physics, clock),
        geometry=physics.geometry,
        limits=lim,
        info=info,
    )


__all__ = ["ManipulatorPhysics", "ManipulatorSpec", "assemble_manipulator", "make_sim_manipulator"]
