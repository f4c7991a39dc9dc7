"""The simulated antagonistic joint: two muscles around a pulley, each on its own regulator.

Two DMSP-class muscles (a *flexor* and an *extensor*, each from its own truth file) pull a
cable wrapped round a pulley of radius r on a joint of inertia J::

    J·θ̈ = r·(T_f − T_e) − b·θ̇ − k_s·θ − τ_c·tanh(θ̇/ε) + τ_stop(θ)      (N·m, θ rad)

θ > 0 turns the joint towards the flexor.  Each muscle is mounted ``mount_contraction_mm``
short of its nominal length at θ = 0 (the cable is taut once both are pressurised), so
along the arc y = r·θ (mm) the contractions are ``x_f = x_mount + y`` and
``x_e = x_mount − y``: what one muscle gains, the other gives.  Written along the arc with
m = J/r² (kg) it is the manipulator's equation with a second muscle in the spring's place.

* each tension ``T`` is the **simulated muscle truth** of :mod:`pmalab.rig.sim.kernel`
  (static force law, Maxwell-slip braid friction, the truth file's hidden effects), with
  its own slip elements — nothing comes from the identified models (no inverse crime);
* each muscle's pressure goes through its own **regulator model** (the truth file's
  ``[regulator]``: quantised command, dead time, first-order lag) and fills the muscle's
  volume V(x) = V0 + dV/dx·x through the line, isothermal: a contracting muscle whose
  volume grows loses pressure while its regulator refills it;
* **sensors**: each muscle's contraction (the truth's position sensor on its cable end),
  tension (a load cell in series) and pressure gauge, with the truth's noise, lag,
  quantisation; the joint angle from an encoder (deg, ``encoder_resolution_deg``).

Co-contraction sets the joint's stiffness: holding both muscles at p, a small rotation
changes the torque by r²·(k_f(p) + k_e(p)) per radian, k the muscles' stiffness (N/mm).
Units: s, mm, N, MPa gauge, kg, deg (the angle channel), rad inside.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from pmalab.errors import RigError
from pmalab.rig.base import Block, Clock, Limits, Sampler, VirtualClock
from pmalab.rig.pair import PairGeometry, PairRig
from pmalab.rig.sim import kernel as K
from pmalab.rig.sim.physics import build_params
from pmalab.rig.sim.truth import Truth, default_truth, load_truth

_NOISE_BLOCK = 4096
#: the pair's muscles, in the order of every per-muscle array here
MUSCLES: tuple[str, str] = ("flexor", "extensor")


@dataclass(frozen=True)
class PairSpec:
    """Mechanics and pneumatics of the simulated joint (the muscles are the truth files').

    Defaults: a 20 mm pulley, a light link, the muscles mounted 10 mm short of nominal
    length, so a joint swing of ±30° moves each muscle ±10.5 mm around its mount —
    the contraction range of the seeds' isobaric tests.
    """

    radius_mm: float = 20.0  #: pulley radius r (mm)
    inertia_kg_m2: float = 0.004  #: joint inertia J about its axis (kg·m²)
    damping_N_m_s_per_rad: float = 0.05  #: bearing viscous damping b (N·m·s/rad)
    coulomb_N_m: float = 0.02  #: bearing Coulomb friction τ_c (N·m)
    spring_N_m_per_rad: float = 0.0  #: optional return spring k_s about θ = 0 (N·m/rad)
    smoothing_rad_s: float = 0.002  #: tanh smoothing of sign(θ̇) (rad/s)
    mount_contraction_mm: float = 10.0  #: each muscle's contraction at θ = 0 (mm)
    stop_deg: float = 40.0  #: the joint's end stops at ±stop_deg (deg)
    stop_stiffness_N_m_per_rad: float = 2000.0
    stop_damping_N_m_s_per_rad: float = 5.0
    volume_cm3: float = 50.0  #: each muscle + tubing volume at nominal length (cm³)
    dvolume_cm3_per_mm: float = 1.0  #: volume growth per mm of contraction (cm³/mm)
    fill_time_constant_s: float = (
        0.03  #: regulator → muscle filling at volume_cm3 (s): a well-sized line
    )
    encoder_resolution_deg: float = 0.01  #: angle encoder quantum (deg)
    encoder_noise_deg: float = 0.005  #: angle encoder rms noise (deg)

    def checked(self) -> PairSpec:
        """Self, or a :class:`~pmalab.errors.RigError` naming the implausible field."""
        for k, v in asdict(self).items():
            if not math.isfinite(v):
                raise RigError(f"pair: {k}: must be a finite number")
        for k in (
            "radius_mm",
            "inertia_kg_m2",
            "volume_cm3",
            "fill_time_constant_s",
            "smoothing_rad_s",
            "stop_deg",
            "stop_stiffness_N_m_per_rad",
        ):
            if getattr(self, k) <= 0:
                raise RigError(f"pair: {k}: must be > 0")
        for k in (
            "damping_N_m_s_per_rad",
            "coulomb_N_m",
            "spring_N_m_per_rad",
            "stop_damping_N_m_s_per_rad",
            "dvolume_cm3_per_mm",
            "encoder_resolution_deg",
            "encoder_noise_deg",
            "mount_contraction_mm",
        ):
            if getattr(self, k) < 0:
                raise RigError(f"pair: {k}: must be ≥ 0")
        return self

    @property
    def moving_mass_kg(self) -> float:
        """J/r²: the joint's inertia seen along the arc (kg)."""
        return self.inertia_kg_m2 / (self.radius_mm * 1e-3) ** 2

    @property
    def stop_mm(self) -> float:
        """The end stops along the arc (mm)."""
        return self.radius_mm * math.radians(self.stop_deg)


# ----------------------------------------------------------------- joint parameters (arc)
J_MASS = 0
J_K = 1  # spring along the arc (N/mm)
J_B = 2  # damping along the arc (N·s/mm)
J_FC = 3  # Coulomb along the arc (N)
J_EPS = 4  # smoothing along the arc (mm/s)
J_X0 = 5  # mount contraction (mm)
J_YSTOP = 6  # stops along the arc (mm)
J_KSTOP = 7
J_CSTOP = 8
J_V0 = 9
J_DVDX = 10
J_TFILL = 11
J_TREG_F = 12
J_TREG_E = 13
N_J = 14
# joint state: time, arc y (mm), arc velocity (mm/s), acceleration (mm/s²)
G_T = 0
G_Y = 1
G_V = 2
G_A = 3
N_G = 4


def _joint_params(spec: PairSpec, tf: Truth, te: Truth) -> np.ndarray:
    r = spec.radius_mm
    q = np.zeros(N_J)
    q[J_MASS] = spec.moving_mass_kg
    # torque per rad → force along the arc per mm: τ/r per θ = y/r → k_s/r² (r in mm → m)
    q[J_K] = spec.spring_N_m_per_rad / (r * r) * 1e3
    q[J_B] = spec.damping_N_m_s_per_rad / (r * r) * 1e3
    q[J_FC] = spec.coulomb_N_m / (r * 1e-3)
    q[J_EPS] = spec.smoothing_rad_s * r
    q[J_X0] = spec.mount_contraction_mm
    q[J_YSTOP] = spec.stop_mm
    q[J_KSTOP] = spec.stop_stiffness_N_m_per_rad / (r * r) * 1e3
    q[J_CSTOP] = spec.stop_damping_N_m_s_per_rad / (r * r) * 1e3
    q[J_V0] = spec.volume_cm3
    q[J_DVDX] = spec.dvolume_cm3_per_mm
    q[J_TFILL] = spec.fill_time_constant_s
    q[J_TREG_F] = tf.section("regulator")["time_constant_ms"] * 1e-3
    q[J_TREG_E] = te.section("regulator")["time_constant_ms"] * 1e-3
    return q


@njit(cache=True)
def _pneumatics(st, x, v, dt, a_reg, v0, dvdx, tfill):
    """One sub-step of a muscle's regulator lag and volume filling (isothermal)."""
    st[K.S_PC] += a_reg * (st[K.S_CMD] - st[K.S_PC])
    vol = v0 + dvdx * x
    if vol < 0.1 * v0:
        vol = 0.1 * v0
    pm = st[K.S_PM]
    a_fill = 1.0 - math.exp(-dt * v0 / (tfill * vol))
    pm += a_fill * (st[K.S_PC] - pm)
    pm -= (pm + K.P_ATM) * dvdx * v * dt / vol
    if pm < 0.0:
        pm = 0.0
    st[K.S_PM] = pm
    return pm


@njit(cache=True)
def _tension(par, st, x, v, pm):
    """A muscle's tension (N) and its ∂/∂x (N/mm) from the truth model; a muscle only pulls."""
    fs, dfs, q, xm = K._static_terms(par, x, pm)
    ff, dff = K._friction_terms(par, st, q, v, x / xm)
    t = fs + ff - par[K.P_CVISC] * v
    if t < 0.0:
        return 0.0, 0.0
    return t, dfs + dff


@njit(cache=True)
def _slip(par, st, dx):
    """Move a muscle's Maxwell-slip elements by ``dx`` (mm), clipped at their slip limits."""
    rd = par[K.P_RD]
    for i in range(int(par[K.P_NE])):
        d = par[K.P_DELTA0 + i]
        u = st[K.S_U0 + i] + dx
        if u > d:
            u = d
        elif u < -d * rd:
            u = -d * rd
        st[K.S_U0 + i] = u


@njit(cache=True)
def _sense(par, st, ptr, hist, x, tension, acc, pm, t, dt):
    """Advance a muscle's sensor filters and write its history row (for delayed sensors)."""
    a_yx = 1.0 - math.exp(-dt / par[K.P_TAU_YX]) if par[K.P_TAU_YX] > 0.0 else 1.0
    a_yf = 1.0 - math.exp(-dt / par[K.P_TAU_YF]) if par[K.P_TAU_YF] > 0.0 else 1.0
    a_ypm = 1.0 - math.exp(-dt / par[K.P_TAU_YPM]) if par[K.P_TAU_YPM] > 0.0 else 1.0
    flc = tension - par[K.P_MB] * acc * 1e-3
    st[K.S_FLC] = flc
    st[K.S_YX] += a_yx * (x - st[K.S_YX])
    st[K.S_YF] += a_yf * (flc - st[K.S_YF])
    st[K.S_YPM] += a_ypm * (pm - st[K.S_YPM])
    st[K.S_YPC] = 0.0
    st[K.S_T] = t
    h = ptr[K.R_HIDX]
    hist[h, 0] = t
    hist[h, 1] = st[K.S_YX]
    hist[h, 2] = st[K.S_YF]
    hist[h, 3] = st[K.S_YPM]
    hist[h, 4] = 0.0
    ptr[K.R_HIDX] = (h + 1) % K.HIST_SIZE
    if ptr[K.R_HCNT] < K.HIST_SIZE:
        ptr[K.R_HCNT] += 1


@njit(cache=True)
def _commands(st, pend, ptr, t):
    """Apply a muscle's commands whose dead time has passed."""
    while ptr[K.R_HEAD] < ptr[K.R_TAIL] and pend[ptr[K.R_HEAD] % K.PEND_SIZE, 0] <= t + 1e-12:
        st[K.S_CMD] = pend[ptr[K.R_HEAD] % K.PEND_SIZE, 1]
        ptr[K.R_HEAD] += 1


@njit(cache=True)
def advance_pair(g, jq, wf, wr, pf, pr, qf, qr, hf, hr, t_target):
    """Integrate the joint and both muscles from ``g[G_T]`` to ``t_target``.

    ``g``: joint state; ``jq``: joint parameters; ``wf``/``wr``: the flexor's/extensor's
    kernel workspaces; ``pf``/``pr`` pending commands, ``qf``/``qr`` pointers, ``hf``/``hr``
    sensor histories.  Linearly implicit Euler on the arc (y, v) with both muscles'
    stiffness in the Jacobian.  Returns 0, or 1 when the state became non-finite.
    """
    t0 = g[G_T]
    span = t_target - t0
    if span <= 0.0:
        return 0
    sf = wf[K.O_ST : K.O_PAR]
    se = wr[K.O_ST : K.O_PAR]
    af = wf[K.O_PAR : K.O_MPAR]
    ae = wr[K.O_PAR : K.O_MPAR]
    hmax = min(af[K.P_HMAX], ae[K.P_HMAX])
    n = int(math.ceil(span / hmax - 1e-9))
    if n < 1:
        n = 1
    dt = span / n
    a_rf = 1.0 - math.exp(-dt / jq[J_TREG_F]) if jq[J_TREG_F] > 0.0 else 1.0
    a_re = 1.0 - math.exp(-dt / jq[J_TREG_E]) if jq[J_TREG_E] > 0.0 else 1.0
    kv = 1000.0 / jq[J_MASS]
    x0 = jq[J_X0]
    ystop = jq[J_YSTOP]
    for j in range(n):
        t = t0 + j * dt
        _commands(sf, pf, qf, t)
        _commands(se, pr, qr, t)
        y = g[G_Y]
        v = g[G_V]
        xf = x0 + y
        xe = x0 - y
        pmf = _pneumatics(sf, xf, v, dt, a_rf, jq[J_V0], jq[J_DVDX], jq[J_TFILL])
        pme = _pneumatics(se, xe, -v, dt, a_re, jq[J_V0], jq[J_DVDX], jq[J_TFILL])
        tf, kf = _tension(af, sf, xf, v, pmf)
        te, ke = _tension(ae, se, xe, -v, pme)
        th = math.tanh(v / jq[J_EPS])
        fbear = jq[J_FC] * th + jq[J_B] * v
        dbear = jq[J_FC] * (1.0 - th * th) / jq[J_EPS] + jq[J_B]
        fstop, sjx, sjv = K._end_stop(y, v, -ystop, ystop, jq[J_KSTOP], jq[J_CSTOP])
        # ∂net/∂y: the flexor's tension falls as y grows (kf < 0), the extensor's rises
        # (−ke > 0 through x_e = x0 − y, entering net with a minus sign): both stiffen
        jx = kf + ke - jq[J_K] + sjx
        jv = -af[K.P_CVISC] - ae[K.P_CVISC] - dbear + sjv
        if jx > 0.0:
            jx = 0.0
        net = tf - te - jq[J_K] * y - fbear + fstop
        vn = (v + dt * kv * (net - jv * v)) / (1.0 - dt * kv * jv - dt * dt * kv * jx)
        yn = y + dt * vn
        acc = (vn - v) / dt
        dy = yn - y
        _slip(af, sf, dy)
        _slip(ae, se, -dy)
        g[G_Y] = yn
        g[G_V] = vn
        g[G_A] = acc
        tn = t0 + (j + 1) * dt
        g[G_T] = tn
        sf[K.S_X] = x0 + yn
        sf[K.S_V] = vn
        se[K.S_X] = x0 - yn
        se[K.S_V] = -vn
        _sense(af, sf, qf, hf, x0 + yn, tf, acc, pmf, tn, dt)
        _sense(ae, se, qr, hr, x0 - yn, te, -acc, pme, tn, dt)
    g[G_T] = t_target
    sf[K.S_T] = t_target
    se[K.S_T] = t_target
    for k in range(N_G):
        if not math.isfinite(g[k]):
            return 1
    for k in range(K.N_STATE):
        if not (math.isfinite(sf[k]) and math.isfinite(se[k])):
            return 1
    return 0


class PairPhysics:
    """State of the simulated antagonistic joint, integrated on demand.

    ``flexor``/``extensor``: each muscle's truth (a :class:`Truth`, a truth TOML path or
    ``None`` for the default); ``spec``: the joint; ``seed``: the sensor-noise seed (same
    seed and calls → the same samples).  The joint starts vented, at rest, at θ = 0.
    """

    def __init__(
        self,
        flexor: Truth | str | Path | None = None,
        extensor: Truth | str | Path | None = None,
        spec: PairSpec | None = None,
        seed: int = 0,
    ) -> None:
        truths = [
            default_truth() if t is None else t if isinstance(t, Truth) else load_truth(t)
            for t in (flexor, extensor)
        ]
        self.truths: dict[str, Truth] = dict(zip(MUSCLES, truths, strict=True))
        self.spec = (spec or PairSpec()).checked()
        self.seed = int(seed)
        self._g = np.zeros(N_G)
        self._jq = _joint_params(self.spec, truths[0], truths[1])
        self._buf = []
        self.max_MPa = math.inf
        self._reg: list[tuple[float, float, float]] = []
        for truth in truths:
            w, pend, ptr, hist = K.new_buffers()
            w[K.O_PAR : K.O_MPAR], w[K.O_MPAR : K.O_OUT] = build_params(truth)
            st = w[K.O_ST : K.O_PAR]
            st[K.S_X] = st[K.S_YX] = self.spec.mount_contraction_mm
            self._buf.append((w, pend, ptr, hist, [0]))
            reg = truth.section("regulator")
            top = min(
                float(reg["max_pressure_MPa"]), float(truth.section("muscle")["max_pressure_MPa"])
            )
            self.max_MPa = min(self.max_MPa, top)
            levels = 2 ** int(reg["bits"]) - 1
            self._reg.append(
                (
                    levels / float(reg["max_pressure_MPa"]),
                    float(reg["max_pressure_MPa"]) / levels,
                    float(reg["dead_time_ms"]) * 1e-3,
                )
            )
        self._commanded = [0.0, 0.0]
        self._rng = np.random.default_rng(self.seed)
        self._noise = [self._rng.standard_normal((_NOISE_BLOCK, 4)) for _ in MUSCLES]
        self._enc = self._rng.standard_normal(_NOISE_BLOCK)
        self._ienc = 0
        #: one sample: time, angle (deg), then per muscle position, force, pressure
        self.out = np.zeros(8)

    @property
    def time(self) -> float:
        return float(self._g[G_T])

    def advance_to(self, t: float) -> None:
        """Integrate up to ``t`` (s); a ``t`` in the past is ignored."""
        if not t > self._g[G_T]:
            return
        if not math.isfinite(t):
            raise RigError(f"simulated joint: cannot advance to t = {t}")
        (wf, pf, qf, hf, _), (wr, pr, qr, hr, _) = self._buf
        if advance_pair(self._g, self._jq, wf, wr, pf, pr, qf, qr, hf, hr, float(t)):
            raise RigError(
                f"simulated joint: the physics left its envelope at t = {self.time:.3f} s "
                "(non-finite state)"
            )

    def sample(self, t: float) -> np.ndarray:
        """Advance to ``t`` and measure: (time, angle deg, then per muscle — flexor first —
        contraction mm, tension N, pressure MPa).  The array is reused: copy to keep it."""
        self.advance_to(t)
        o = self.out
        o[0] = self._g[G_T]
        for i, (w, _, ptr, hist, _) in enumerate(self._buf):
            if K.measure(w, ptr, hist, self._noise[i]):
                self._noise[i] = self._rng.standard_normal((_NOISE_BLOCK, 4))
                ptr[K.R_NI] = 0
            o[2 + 3 * i : 5 + 3 * i] = w[K.O_OUT + 1 : K.O_OUT + 4]
        s = self.spec
        ang = math.degrees(self._g[G_Y] / s.radius_mm) + s.encoder_noise_deg * self._enc[self._ienc]
        self._ienc += 1
        if self._ienc >= _NOISE_BLOCK:
            self._enc = self._rng.standard_normal(_NOISE_BLOCK)
            self._ienc = 0
        res = s.encoder_resolution_deg
        o[1] = round(ang / res) * res if res > 0 else ang
        return o

    def set_command(self, muscle: int, mpa: float) -> None:
        """Command muscle ``muscle``'s regulator (0 flexor, 1 extensor), MPa: quantised,
        applied after the dead time."""
        mpa = float(mpa)
        if not -1e-9 <= mpa <= self.max_MPa + 1e-9:  # also rejects NaN
            raise RigError(
                f"simulated {MUSCLES[muscle]} regulator: command {mpa:g} MPa outside "
                f"0–{self.max_MPa:g} MPa"
            )
        mpa = min(max(mpa, 0.0), self.max_MPa)
        self._commanded[muscle] = mpa
        per_q, q_mpa, dead = self._reg[muscle]
        _, pend, ptr, _, tail_box = self._buf[muscle]
        q = round(mpa * per_q) * q_mpa
        tail = tail_box[0]
        if tail - ptr[K.R_HEAD] >= K.PEND_SIZE:
            ptr[K.R_HEAD] += 1
        i = tail % K.PEND_SIZE
        pend[i, 0] = self._g[G_T] + dead
        pend[i, 1] = q
        tail_box[0] = tail + 1
        ptr[K.R_TAIL] = tail + 1

    def command(self, muscle: int) -> float:
        return self._commanded[muscle]

    def stiffness(self, muscle: int, p: float, x: float | None = None) -> float:
        """The truth's static stiffness of ``muscle`` at pressure ``p`` (MPa) and
        contraction ``x`` (mm, default the mount): −∂F_s/∂x in N/mm (tests, benches)."""
        w = self._buf[muscle][0]
        x = self.spec.mount_contraction_mm if x is None else float(x)
        _, dfs, _, _ = K._static_terms(w[K.O_PAR : K.O_MPAR], x, float(p))
        return -float(dfs)

    def static_force(self, muscle: int, x: float, p: float) -> float:
        """The truth's static tension F_s(x, p) (N) of ``muscle``."""
        w = self._buf[muscle][0]
        fs, _, _, _ = K._static_terms(w[K.O_PAR : K.O_MPAR], float(x), float(p))
        return float(fs)

    def truth_state(self) -> dict[str, Any]:
        """Noise-free values now (tests): angle, arc velocity, each muscle's pressure."""
        out: dict[str, Any] = {
            "time": self.time,
            "angle_deg": math.degrees(self._g[G_Y] / self.spec.radius_mm),
            "arc_velocity_mm_s": float(self._g[G_V]),
        }
        for name, (w, *_rest) in zip(MUSCLES, self._buf, strict=True):
            st = w[K.O_ST : K.O_PAR]
            out[f"muscle_pressure_{name}"] = float(st[K.S_PM])
            out[f"contraction_{name}"] = float(st[K.S_X])
        return out


# ----------------------------------------------------------------- the rig devices
class PairSampler(Sampler):
    """Software-polled: each :meth:`read_block` takes one sample at ``clock.now()``."""

    hardware_timed = False

    def __init__(self, physics: PairPhysics, clock: Clock, rate_Hz: float = 500.0) -> None:
        self.physics = physics
        self.clock = clock
        self.sample_rate_Hz = float(rate_Hz)
        self._names = ["angle"] + [
            f"{q}_{m}" for m in MUSCLES for q in ("position", "force", "muscle_pressure")
        ]

    def read_block(self) -> Block:
        o = self.physics.sample(self.clock.now()).copy()
        return Block.of(o[0:1], {n: o[i + 1 : i + 2] for i, n in enumerate(self._names)})


def make_sim_pair(
    flexor: Truth | str | Path | None = None,
    extensor: Truth | str | Path | None = None,
    *,
    spec: PairSpec | None = None,
    seed: int = 0,
    clock: Clock | None = None,
    limits: Limits | None = None,
) -> PairRig:
    """A simulated :class:`~pmalab.rig.pair.PairRig` on a virtual clock (by default).

    Limits default to the muscles' rating (both regulators), a 2 kN load cell on each
    muscle and a contraction travel of −15 … 40 mm; the angle is held within the stops.
    """
    from pmalab.rig.sim.regulator import SimulatedRegulator

    physics = PairPhysics(flexor, extensor, spec, seed)
    clock = clock if clock is not None else VirtualClock()
    if clock.now() > physics.time:
        physics.advance_to(clock.now())
    s = physics.spec
    lim = limits or Limits(
        max_muscle_pressure_MPa=physics.max_MPa,
        max_cylinder_pressure_MPa=physics.max_MPa,
        max_force_N=2000.0,
        min_position_mm=-15.0,
        max_position_mm=40.0,
    )
    regs = {
        m: SimulatedRegulator(
            physics, clock, physics.max_MPa, lambda mpa, i=i: physics.set_command(i, mpa)
        )
        for i, m in enumerate(MUSCLES)
    }
    info = {
        "kind": "sim-pair",
        "truth": {m: physics.truths[m].source for m in MUSCLES},
        "enabled_effects": {m: physics.truths[m].enabled_effects() for m in MUSCLES},
        "seed": physics.seed,
        "pair": asdict(s),
        "clock": "virtual" if clock.virtual else "real",
        "physics": physics,
    }
    rig = PairRig(
        clock=clock,
        sampler=PairSampler(physics, clock),
        cylinder_regulator=regs["extensor"],
        muscle_supply=_supply(regs["flexor"]),
        limits=lim,
        info=info,
        regulators=dict(regs),
        geometry=PairGeometry(s.radius_mm, s.mount_contraction_mm, s.inertia_kg_m2, s.stop_deg),
    )
    return rig


def _supply(reg: Any) -> Any:
    from pmalab.rig.base import RegulatedMuscleSupply

    return RegulatedMuscleSupply(reg)


__all__ = ["MUSCLES", "PairPhysics", "PairSpec", "make_sim_pair"]
