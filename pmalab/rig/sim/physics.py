"""The whole simulated rig as one physical system: :class:`RigPhysics`.

It owns the truth model (muscle, braid friction, cylinder, ITV regulator, muscle supply,
sensors) and nothing else: no clock, no Rig objects.  Whoever drives it — the simulated
:class:`~pmalab.rig.base.Rig` of :mod:`pmalab.rig.sim.rig`, or the Modbus/serial device
emulators — calls :meth:`RigPhysics.advance_to` with its own notion of time.

Units: time s, position mm (contraction, positive = shorter), force N (tension),
pressures MPa gauge.  See :mod:`pmalab.rig.sim.kernel` for the equations.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from pmalab.errors import RigError
from pmalab.rig.sim import kernel as K
from pmalab.rig.sim.truth import Truth, default_truth, load_truth

_NOISE_BLOCK = 4096
#: path (mm) the seal must slide after a break-away before it can stick and break away again
_BRK_SLIDE_MM = 0.5


def build_params(truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """Kernel parameter arrays (physics, measurement) from a validated truth."""
    p = np.zeros(K.N_PARAM)
    m = truth.section("muscle")
    p[K.P_FMAX] = m["max_force_N"]
    p[K.P_PREF] = m["reference_pressure_MPa"]
    p[K.P_PTH] = m["threshold_pressure_MPa"]
    p[K.P_BETA] = m["force_pressure_curvature"]
    p[K.P_XMAX] = m["max_contraction_mm"]
    p[K.P_XSCALE] = m["contraction_pressure_scale"]
    p[K.P_KSTRETCH] = m["stretch_stiffness_N_per_mm"]
    fr = truth.section("friction")
    p[K.P_FSLIP] = fr["slip_force_N"]
    p[K.P_FGAMMA] = fr["pressure_curvature"]
    p[K.P_DEXP] = fr["presliding_pressure_exponent"]
    w = np.asarray(fr["weights"], dtype=float)
    w = w / w.sum()
    p[K.P_NE] = len(w)
    p[K.P_DELTA0 : K.P_DELTA0 + len(w)] = fr["presliding_mm"]
    p[K.P_W0 : K.P_W0 + len(w)] = w
    c = truth.section("cylinder")
    p[K.P_AREA] = math.pi * c["bore_mm"] ** 2 / 4.0
    inertia = truth.effect("inertia")
    mb = inertia["mass_kg"] if inertia else 0.0
    p[K.P_MB] = mb
    p[K.P_MASS] = c["moving_mass_kg"] + mb
    p[K.P_FC] = c["coulomb_N"]
    p[K.P_FS] = c["stiction_N"]
    p[K.P_VS] = c["stribeck_velocity_mm_s"]
    p[K.P_BSEAL] = c["viscous_N_s_per_mm"]
    p[K.P_EPS] = c["smoothing_velocity_mm_s"]
    p[K.P_XLO] = c["stroke_min_mm"]
    p[K.P_XHI] = c["stroke_max_mm"]
    p[K.P_KSTOP] = c["stop_stiffness_N_per_mm"]
    p[K.P_CSTOP] = c["stop_damping_N_s_per_mm"]
    reg = truth.section("regulator")
    p[K.P_TAU_ITV] = reg["time_constant_ms"] * 1e-3
    pv = truth.effect("pressure_variation")
    if pv:
        p[K.P_TAU_SUP] = pv["regulator_time_constant_s"]
        p[K.P_V0] = pv["volume_cm3"]
        p[K.P_DVDX] = pv["dvolume_cm3_per_mm"]
    else:
        p[K.P_TAU_SUP] = truth.section("supply")["time_constant_s"]
        p[K.P_V0] = 1.0
        p[K.P_DVDX] = 0.0
    vf = truth.effect("viscous_friction")
    p[K.P_CVISC] = vf["c"] if vf else 0.0
    ah = truth.effect("asymmetric_hysteresis")
    p[K.P_RF] = ah["stretch_friction_factor"] if ah else 1.0
    p[K.P_RD] = ah["stretch_presliding_factor"] if ah else 1.0
    p[K.P_FPOS] = ah["friction_position_gain"] if ah else 0.0
    ns = truth.effect("nonlinear_stiffness")
    p[K.P_KAPPA] = ns["curvature"] if ns else 0.0
    s = truth.section("sensors")
    p[K.P_TAU_YX] = s["position_time_constant_ms"] * 1e-3
    p[K.P_TAU_YF] = s["force_time_constant_ms"] * 1e-3
    p[K.P_TAU_YPM] = s["pressure_time_constant_ms"] * 1e-3
    p[K.P_TAU_YPC] = s["pressure_time_constant_ms"] * 1e-3
    p[K.P_HMAX] = truth.section("integrator")["max_step_ms"] * 1e-3

    mp = np.zeros(K.N_MPARAM)
    sd = truth.effect("sensor_delay")
    if sd:
        mp[K.M_DELAY0 : K.M_DELAY0 + 4] = [
            sd["position_ms"] * 1e-3,
            sd["force_ms"] * 1e-3,
            sd["muscle_pressure_ms"] * 1e-3,
            sd["cylinder_pressure_ms"] * 1e-3,
        ]
    mp[K.M_NOISE0 : K.M_NOISE0 + 4] = [
        s["position_noise_mm"],
        s["force_noise_N"],
        s["pressure_noise_MPa"],
        s["pressure_noise_MPa"],
    ]
    mp[K.M_RES0 : K.M_RES0 + 4] = [
        s["position_resolution_mm"],
        s["force_resolution_N"],
        s["pressure_resolution_MPa"],
        s["pressure_resolution_MPa"],
    ]
    dr = truth.effect("sensor_drift")
    if dr:
        mp[K.M_DRIFT_F] = dr["force_N_per_min"] / 60.0
        mp[K.M_DRIFT_X] = dr["position_mm_per_min"] / 60.0
    return p, mp


class RigPhysics:
    """State of the whole simulated rig, integrated on demand.

    Parameters
    ----------
    truth:
        a :class:`Truth`, a path to a truth TOML, or ``None`` for the defaults (all effects
        off).
    seed:
        seeds the sensor-noise generator; the same seed and the same sequence of calls give
        bit-for-bit identical samples.
    """

    def __init__(self, truth: Truth | str | Path | None = None, seed: int = 0) -> None:
        if truth is None:
            truth = default_truth()
        elif not isinstance(truth, Truth):
            truth = load_truth(truth)
        self.truth = truth
        self.seed = int(seed)
        self._w, self._pend, self._ptr, self._hist = K.new_buffers()
        # views into the packed workspace
        self._st = self._w[K.O_ST : K.O_PAR]
        self._par = self._w[K.O_PAR : K.O_MPAR]
        self._mpar = self._w[K.O_MPAR : K.O_OUT]
        self._out = self._w[K.O_OUT : K.N_W]
        self._par[:], self._mpar[:] = build_params(truth)
        reg = truth.section("regulator")
        self.cylinder_max_MPa = float(reg["max_pressure_MPa"])
        levels = 2 ** int(reg["bits"]) - 1
        self._q_per_mpa = levels / self.cylinder_max_MPa
        self._mpa_per_q = self.cylinder_max_MPa / levels
        self._tail = 0
        self._dead = reg["dead_time_ms"] * 1e-3
        self.muscle_max_MPa = float(truth.section("muscle")["max_pressure_MPa"])
        self._rng = np.random.default_rng(self.seed)
        self._noise = self._rng.standard_normal((_NOISE_BLOCK, 4))
        self._cylinder_command = 0.0
        drift = truth.effect("sensor_drift")
        self._tare_each_run = bool(drift and drift["tare_each_run"])
        # fatigue/creep: the stiffness k = F0/x_max drifts as k0·(1 + r·t) (t: rig time, s),
        # applied through the free contraction x_max (so the tension at x = 0 is unchanged)
        self._xmax0 = float(self._par[K.P_XMAX])
        self._k_drift = (
            float(truth.section("muscle")["stiffness_drift_percent_per_hour"]) / 100.0 / 3600.0
        )
        # off-catalogue effects, applied between kernel steps (each step is one sample
        # period; all of them are slow or sensor-side)
        self._fmax0 = float(self._par[K.P_FMAX])
        cond = truth.effect("conditioning")
        self._cond = (cond["stiffening_percent"] / 100.0, float(cond["path_mm"])) if cond else None
        warm = truth.effect("warming")
        self._warm = (
            (warm["stiffness_change_percent"] / 100.0, float(warm["time_constant_s"]))
            if warm
            else None
        )
        brk = truth.effect("breakaway")
        self._brk = (float(brk["spike_N"]), float(brk["decay_ms"]) * 1e-3) if brk else None
        hum = truth.effect("mains_pickup")
        self._hum = (float(hum["amplitude_N"]), float(hum["frequency_Hz"])) if hum else None
        self._path = 0.0  # path the muscle has moved since switch-on (mm)
        self._x_last = 0.0
        self._v_sign = 0.0  # sign of the motion since the last reversal
        self._t_rev = -math.inf  # time of the last break-away (s)
        self._brk_sign = 0.0  # the motion's sign when the seal last broke away
        self._x_rev = 0.0  # position at the last break-away (mm)
        self._slow = bool(self._k_drift or self._cond or self._warm)
        self._sensor = bool(self._brk or self._hum)
        # the sled starts at rest at nominal length, every pressure at zero
        self._st[K.S_YX] = 0.0

    # ------------------------------------------------------------------ time
    @property
    def time(self) -> float:
        """Current simulated time (s)."""
        return float(self._st[K.S_T])

    def advance_to(self, t: float) -> None:
        """Integrate the physics up to time ``t`` (s); a ``t`` in the past is ignored."""
        if not t > self._st[K.S_T]:
            return
        if not math.isfinite(t):
            raise RigError(f"simulated rig: cannot advance to t = {t}")
        if self._slow:
            self._drift_stiffness(t)
        rc = K.advance(self._w, self._pend, self._ptr, self._hist, float(t))
        if rc:
            self._diverged()
        if self._sensor:
            self._track_motion()

    def _drift_stiffness(self, t: float) -> None:
        """Set the muscle's stiffness for rig time ``t`` (s): k0·(1 + r·t) (fatigue) times
        the warming factor 1 + b·(1 − exp(−t/τ)), and its conditioning F0·(1 + a·exp(−S/S0))
        (S the path moved so far), held over the step to ``t`` (a sample period: all slow)."""
        k = max(0.05, 1.0 + self._k_drift * t)
        if self._warm:
            b, tau = self._warm
            k *= max(0.05, 1.0 + b * (1.0 - math.exp(-t / tau)))
        self._par[K.P_XMAX] = self._xmax0 / k
        if self._cond:
            x = float(self._st[K.S_X])
            self._path += abs(x - self._x_last)
            self._x_last = x
            a, s0 = self._cond
            self._par[K.P_FMAX] = self._fmax0 * (1.0 + a * math.exp(-self._path / s0))

    def _track_motion(self) -> None:
        """Note a reversal of the true motion (for the break-away spikes)."""
        v = float(self._st[K.S_V])
        x = float(self._st[K.S_X])
        # a reversal: the motion (beyond 0.5 mm/s, not noise or rest) changes sign.  The
        # seal breaks away once per reversal: a stick-slip chatter at the turning point
        # (several sign changes within a fraction of a millimetre) is one break-away, so a
        # new one needs the seal to have slid _BRK_SLIDE_MM since the last (a spike that
        # flips sign from one sample to the next is no force a seal makes)
        if abs(v) > 0.5:
            sg = 1.0 if v > 0 else -1.0
            if sg != self._v_sign:
                slid = abs(x - self._x_rev) >= _BRK_SLIDE_MM or not math.isfinite(self._t_rev)
                if self._v_sign != 0.0 and slid:
                    self._t_rev = float(self._st[K.S_T])
                    self._brk_sign = sg
                    self._x_rev = x
                self._v_sign = sg

    def _sensor_terms(self, t: float) -> float:
        """Off-catalogue force on the load-cell reading at time ``t`` (N): the break-away
        spike since the last reversal (up while stretching: −sign(ẋ)) and the mains hum."""
        f = 0.0
        if self._brk and math.isfinite(self._t_rev):
            a, tau = self._brk
            f -= a * self._brk_sign * math.exp(-(t - self._t_rev) / tau)
        if self._hum:
            a, fr = self._hum
            f += a * math.sin(2.0 * math.pi * fr * t + 0.3)
        return f

    def stiffness_factor(self, t: float | None = None) -> float:
        """k(t)/k0 of the stiffness drift at rig time ``t`` (s; default now)."""
        t = self.time if t is None else t
        return max(0.05, 1.0 + self._k_drift * t)

    def _diverged(self) -> None:
        raise RigError(
            f"simulated rig: the physics left its envelope at t = {self.time:.3f} s "
            "(non-finite state); check the truth file"
        )

    # ------------------------------------------------------------------ commands
    def set_cylinder_command(self, mpa: float) -> None:
        """Command the ITV regulator (MPa, 0..0.9): quantized, then applied after the dead time."""
        mpa = float(mpa)
        cmax = self.cylinder_max_MPa
        if not -1e-9 <= mpa <= cmax + 1e-9:  # also rejects NaN
            raise RigError(
                f"simulated ITV regulator: command {mpa:g} MPa outside its range 0–{cmax:g} MPa"
            )
        mpa = 0.0 if mpa < 0.0 else (cmax if mpa > cmax else mpa)
        self._cylinder_command = mpa
        # 2^bits − 1 levels over 0..max, as the regulator's DAC/serial setpoint resolves it
        q = round(mpa * self._q_per_mpa) * self._mpa_per_q
        ptr = self._ptr
        tail = self._tail
        if tail - ptr[K.R_HEAD] >= K.PEND_SIZE:
            # more commands in flight than the queue holds: drop the oldest
            ptr[K.R_HEAD] += 1
        i = tail % K.PEND_SIZE
        pend = self._pend
        pend[i, 0] = self._st[K.S_T] + self._dead
        pend[i, 1] = q
        self._tail = tail + 1
        ptr[K.R_TAIL] = tail + 1

    def set_muscle_supply(self, mpa: float) -> None:
        """Set the muscle regulator's setpoint (MPa, 0..rated pressure)."""
        mpa = float(mpa)
        if not math.isfinite(mpa) or mpa < -1e-9 or mpa > self.muscle_max_MPa + 1e-9:
            raise RigError(
                f"simulated muscle supply: {mpa:g} MPa outside the DMSP-20 envelope "
                f"0–{self.muscle_max_MPa:g} MPa"
            )
        self._st[K.S_PMSET] = min(max(mpa, 0.0), self.muscle_max_MPa)

    def start_run(self) -> None:
        """A run begins (the simulated rig calls this when a run's muscle pressure is requested).

        With the sensor-drift effect's ``tare_each_run`` the operator tares the drifting
        zeros now, so the drift grows from 0 in this run; otherwise nothing changes (the
        zeros keep drifting from switch-on, carried over from run to run).
        """
        if self._tare_each_run:
            self._mpar[K.M_DRIFT_T0] = self._st[K.S_T]

    @property
    def cylinder_command(self) -> float:
        """The last cylinder command (MPa, before quantization and dead time)."""
        return self._cylinder_command

    @property
    def muscle_supply(self) -> float:
        return float(self._st[K.S_PMSET])

    # ------------------------------------------------------------------ sensing
    def _refill_noise(self) -> None:
        self._noise = self._rng.standard_normal((_NOISE_BLOCK, 4))
        self._ptr[K.R_NI] = 0

    def sample(self) -> dict[str, float]:
        """The five channels as the sensors measure them now (s, mm, N, MPa, MPa)."""
        if K.measure(self._w, self._ptr, self._hist, self._noise):
            self._refill_noise()
        o = self._out
        if self._sensor:
            o[2] += self._sensor_terms(float(o[0]))
        return {
            "time": float(o[0]),
            "position": float(o[1]),
            "force": float(o[2]),
            "muscle_pressure": float(o[3]),
            "cylinder_pressure": float(o[4]),
        }

    def advance_and_sample(self, t: float) -> np.ndarray:
        """Fast path: :meth:`advance_to` then :meth:`sample`, as an array of the five channels.

        The returned array is reused by the next call: copy it to keep it.
        """
        if not math.isfinite(t):
            raise RigError(f"simulated rig: cannot advance to t = {t}")
        if self._slow:
            self._drift_stiffness(t)
        rc = K.advance_measure(self._w, self._pend, self._ptr, self._hist, self._noise, float(t))
        if rc:
            if rc & 1:
                self._diverged()
            self._refill_noise()
        if self._sensor:
            self._track_motion()
            self._out[2] += self._sensor_terms(float(self._out[0]))
        return self._out

    def truth_state(self) -> dict[str, Any]:
        """Noise-free true values now (for tests and benchmarks).

        ``tension`` is the muscle's true tension (N) = ``static + friction + viscous``;
        ``load_cell`` what a perfect load cell reads (tension minus the inertia of the mass
        between muscle and load cell); ``element_displacements`` the Maxwell-slip states (mm).
        """
        st = self._st
        fs, ff, fv, tension = K.forces_w(self._w)
        ne = int(self._par[K.P_NE])
        return {
            "time": float(st[K.S_T]),
            "position": float(st[K.S_X]),
            "velocity": float(st[K.S_V]),
            "acceleration": float(st[K.S_A]),
            "tension": float(tension),
            "static_force": float(fs),
            "friction_force": float(ff),
            "viscous_force": float(fv),
            "load_cell": float(st[K.S_FLC]),
            "muscle_pressure": float(st[K.S_PM]),
            "muscle_supply": float(st[K.S_PMSET]),
            "cylinder_pressure": float(st[K.S_PC]),
            "cylinder_command_applied": float(st[K.S_CMD]),
            "element_displacements": [float(u) for u in st[K.S_U0 : K.S_U0 + ne]],
        }

    # ------------------------------------------------------------------ helpers
    def static_force(self, x: float, p: float) -> float:
        """The truth model's static tension F_s(x, p) (N) — no friction, no dynamics."""
        fs, _, _, _ = K._static_terms(self._par, float(x), float(p))
        return float(fs)

    def settle(self, duration: float = 1.0) -> None:
        """Advance ``duration`` seconds with the commands unchanged."""
        self.advance_to(self.time + duration)
