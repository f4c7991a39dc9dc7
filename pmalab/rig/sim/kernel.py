"""The compiled core of the simulated rig: sub-stepped mechanics, regulators and sensors.

Everything here works on flat float arrays so that one call integrates many sub-steps
(numba); :mod:`pmalab.rig.sim.physics` wraps it in a friendly class.

Units inside the kernel: time s, position mm, velocity mm/s, acceleration mm/s², force N,
pressure MPa (gauge), mass kg (so ``a [mm/s²] = 1000 · F [N] / m [kg]``).

Geometry and signs.  x is the muscle's contraction (mm, positive = shorter).  The muscle
pulls the sled towards +x with its tension T; the cylinder (piston area A) pushes it
towards −x, stretching the muscle, with P_cyl·A; the cylinder seals' friction opposes the
sled's velocity; end stops bound the stroke.  The load cell sits between the muscle and
the sled: it reads T minus the inertial force of any mass between the two
(``effects.inertia``).  Equation of motion of the sled (total moving mass m)::

    m·ẍ = T(x, ẋ, p, u) − P_cyl·A − F_seal(ẋ) + F_stop(x, ẋ)

Muscle tension ``T = F_static(x, p) + F_friction(u, p) + F_viscous(ẋ)``:

* ``F_static = F0(p)·(1 − s)·(1 − κ·s)`` with ``s = x / x_max(p)``; κ = 0 unless the
  nonlinear-stiffness effect is on (then it is Tondu–Lopez-like, quadratic in contraction).
  ``F0(p) = Fmax·((1−β)q + βq²)`` and ``x_max(p) ∝ 1 − exp(−q/σ)`` with
  ``q = (p − p_th)/(p_ref − p_th)`` clipped at 0: no force below the threshold pressure.
  Beyond nominal length (x < 0) the braid adds a stiff stretch term; shorter than its
  free contraction (s > 1) the muscle is slack.  A muscle only pulls: T ≥ 0.
* ``F_friction = −Σ z_i``: braid friction as a Maxwell-slip model — elastic elements of
  pre-sliding displacement δ_i that slip at force f_i(p) ∝ pressure.  While the muscle is
  stretched (x decreasing) the elements sit at −f_i and add tension: the loop runs in the
  physical direction.  This is deliberately *not* a Bouc-Wen or Duhem law.
* ``F_viscous = −c·ẋ`` (viscous-friction effect).

Integration: linearly implicit Euler on (x, v) — the stiff terms (seal friction
smoothing, pre-sliding stiffness, end stops) enter through their Jacobian — with equal
sub-steps ≤ ``max_step``.  It is unconditionally stable for the dissipative stiff terms,
which is what keeps every state finite across the envelope.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

P_ATM = 0.101325  # MPa, for the isothermal volume–pressure coupling

# ----------------------------------------------------------------- state indices
S_T = 0  # time (s)
S_X = 1  # contraction (mm)
S_V = 2  # velocity (mm/s)
S_A = 3  # acceleration of the last sub-step (mm/s²)
S_PM = 4  # muscle pressure, true (MPa)
S_PMSET = 5  # muscle supply setpoint (MPa)
S_PC = 6  # cylinder pressure, true (MPa)
S_CMD = 7  # ITV command in effect (after dead time, quantized) (MPa)
S_YX = 8  # sensor filter states: position, load cell, muscle p, cylinder p
S_YF = 9
S_YPM = 10
S_YPC = 11
S_FLC = 12  # true load-cell reading (no noise/drift) (N)
S_U0 = 16  # Maxwell-slip element displacements u_i (mm), up to 8
N_STATE = 24
MAX_ELEMENTS = 8

# ----------------------------------------------------------------- parameter indices
P_FMAX = 0
P_PREF = 1
P_PTH = 2
P_BETA = 3
P_XMAX = 4
P_XSCALE = 5
P_KSTRETCH = 6
P_FSLIP = 7
P_FGAMMA = 8
P_NE = 9
P_AREA = 10
P_MASS = 11
P_MB = 12
P_FC = 13
P_FS = 14
P_VS = 15
P_BSEAL = 16
P_EPS = 17
P_XLO = 18
P_XHI = 19
P_KSTOP = 20
P_CSTOP = 21
P_TAU_ITV = 22
P_TAU_SUP = 23
P_V0 = 24
P_DVDX = 25
P_CVISC = 26
P_RF = 27
P_RD = 28
P_KAPPA = 29
P_TAU_YX = 30
P_TAU_YF = 31
P_TAU_YPM = 32
P_TAU_YPC = 33
P_HMAX = 34
P_FPOS = 35
P_DEXP = 36  # slip displacements ∝ q**P_DEXP (0: the same at every pressure)
P_DELTA0 = 40  # 8 slots
P_W0 = 48  # 8 slots
N_PARAM = 56

# measurement parameters
M_DELAY0 = 0  # 4 delays (s): position, force, muscle p, cylinder p
M_NOISE0 = 4  # 4 rms noises
M_RES0 = 8  # 4 quantization steps
M_DRIFT_F = 12  # N/s
M_DRIFT_X = 13  # mm/s
M_DRIFT_T0 = 14  # time the drifting zeros were last tared (s): drift = rate·(t − t0)
N_MPARAM = 15

# pointer array: pending-command ring head/tail, history ring write index and count
R_HEAD = 0
R_TAIL = 1
R_HIDX = 2
R_HCNT = 3
R_NI = 4  # next row of the pre-drawn sensor-noise block
N_PTR = 5
PEND_SIZE = 1024
HIST_SIZE = 8192


@njit(cache=True)
def _static_terms(par, x, p):
    """Static tension (N), its x-derivative (N/mm), q = normalised pressure, x_max (mm)."""
    pth = par[P_PTH]
    q = (p - pth) / (par[P_PREF] - pth)
    if q < 0.0:
        q = 0.0
    beta = par[P_BETA]
    f0 = par[P_FMAX] * ((1.0 - beta) * q + beta * q * q)
    sc = par[P_XSCALE]
    xm = par[P_XMAX] * (1.0 - math.exp(-q / sc)) / (1.0 - math.exp(-1.0 / sc))
    if xm < 0.5:
        xm = 0.5
    kap = par[P_KAPPA]
    s = x / xm
    if s <= 1.0:
        fs = f0 * (1.0 - s) * (1.0 - kap * s)
        dfdx = f0 * (-1.0 - kap + 2.0 * kap * s) / xm
    else:
        # shorter than its free contraction the muscle is slack: it cannot push
        fs = 0.0
        dfdx = 0.0
    if x < 0.0:
        fs += -par[P_KSTRETCH] * x
        dfdx += -par[P_KSTRETCH]
    return fs, dfdx, q, xm


@njit(cache=True)
def _slip_scale(par, q):
    """Factor on every element's slip displacement at normalised pressure ``q``: q**a with
    a = ``presliding_pressure_exponent`` (a > 0: the elements slip later at higher pressure,
    so their slip forces rise faster than their stiffnesses).  q is floored at 0.05 (below
    the threshold pressure the muscle carries no force anyway)."""
    a = par[P_DEXP]
    if a == 0.0:
        return 1.0
    return max(q, 0.05) ** a


@njit(cache=True)
def _friction_terms(par, st, q, v, s):
    """Braid friction tension (N) from the Maxwell-slip elements, and its x-stiffness.

    ``s = x / x_max(p)``: with the asymmetric-hysteresis effect the slip forces also scale
    with ``1 + g·(1 − 2s)`` (s clipped to 0..1) — more friction where the muscle is
    stretched and the braid presses harder — so the loop is wide at one end and narrow at
    the other instead of point-symmetric.
    """
    gam = par[P_FGAMMA]
    ftot = par[P_FSLIP] * ((1.0 - gam) * q + gam * q * q)
    g = par[P_FPOS]
    if g != 0.0:
        sc = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
        ftot *= 1.0 + g * (1.0 - 2.0 * sc)
    rf = par[P_RF]
    rd = par[P_RD]
    ne = int(par[P_NE])
    ds = _slip_scale(par, q)
    f = 0.0
    k = 0.0
    for i in range(ne):
        u = st[S_U0 + i]
        d = par[P_DELTA0 + i] * ds
        fi = par[P_W0 + i] * ftot
        if u >= 0.0:
            ki = fi / d
            inside = u < d or v < 0.0
        else:
            ki = fi * rf / (d * rd)
            inside = u > -d * rd or v > 0.0
        f -= ki * u
        if inside:
            k -= ki
    return f, k


@njit(cache=True)
def _end_stop(x, v, xlo, xhi, kstop, cstop):
    """Travel end stops as stiff damped springs outside [xlo, xhi] (mm): (force N, ∂F/∂x,
    ∂F/∂v) for the semi-implicit step; zeros inside the travel."""
    if x > xhi:
        return -kstop * (x - xhi) - cstop * v, -kstop, -cstop
    if x < xlo:
        return kstop * (xlo - x) - cstop * v, -kstop, -cstop
    return 0.0, 0.0, 0.0


@njit(cache=True)
def forces(st, par):
    """(static, friction, viscous, tension) at the current state, N."""
    fs, _, q, xm = _static_terms(par, st[S_X], st[S_PM])
    ff, _ = _friction_terms(par, st, q, st[S_V], st[S_X] / xm)
    fv = -par[P_CVISC] * st[S_V]
    return fs, ff, fv, max(fs + ff + fv, 0.0)


@njit(cache=True)
def _advance(st, par, pend, ptr, hist, t_target):
    """Integrate from ``st[S_T]`` to ``t_target`` in equal sub-steps ≤ ``P_HMAX``.

    Returns 0 on success, 1 if the state became non-finite (never expected).
    """
    t0 = st[S_T]
    span = t_target - t0
    if span <= 0.0:
        return 0
    n = int(math.ceil(span / par[P_HMAX] - 1e-9))
    if n < 1:
        n = 1
    dt = span / n
    # exact first-order-lag factors for this step size
    a_itv = 1.0 - math.exp(-dt / par[P_TAU_ITV]) if par[P_TAU_ITV] > 0.0 else 1.0
    a_sup = 1.0 - math.exp(-dt / par[P_TAU_SUP])
    a_yx = 1.0 - math.exp(-dt / par[P_TAU_YX]) if par[P_TAU_YX] > 0.0 else 1.0
    a_yf = 1.0 - math.exp(-dt / par[P_TAU_YF]) if par[P_TAU_YF] > 0.0 else 1.0
    a_ypm = 1.0 - math.exp(-dt / par[P_TAU_YPM]) if par[P_TAU_YPM] > 0.0 else 1.0
    a_ypc = 1.0 - math.exp(-dt / par[P_TAU_YPC]) if par[P_TAU_YPC] > 0.0 else 1.0
    kv = 1000.0 / par[P_MASS]
    area = par[P_AREA]
    fc = par[P_FC]
    fsx = par[P_FS] - fc
    vs = par[P_VS]
    eps = par[P_EPS]
    bseal = par[P_BSEAL]
    xlo = par[P_XLO]
    xhi = par[P_XHI]
    kstop = par[P_KSTOP]
    cstop = par[P_CSTOP]
    cv = par[P_CVISC]
    dvdx = par[P_DVDX]
    v0 = par[P_V0]
    mb = par[P_MB]
    ne = int(par[P_NE])
    rd = par[P_RD]

    for j in range(n):
        t = t0 + j * dt
        # ITV command whose dead time has elapsed
        while ptr[R_HEAD] < ptr[R_TAIL] and pend[ptr[R_HEAD] % PEND_SIZE, 0] <= t + 1e-12:
            st[S_CMD] = pend[ptr[R_HEAD] % PEND_SIZE, 1]
            ptr[R_HEAD] += 1
        x = st[S_X]
        v = st[S_V]
        # --- pneumatics: ITV lag; muscle supply lag + isothermal volume coupling
        st[S_PC] += a_itv * (st[S_CMD] - st[S_PC])
        pm = st[S_PM]
        pm += a_sup * (st[S_PMSET] - pm)
        if dvdx > 0.0:
            vol = v0 + dvdx * x
            if vol < 0.1 * v0:
                vol = 0.1 * v0
            pm -= (pm + P_ATM) * dvdx * v * dt / vol
        if pm < 0.0:
            pm = 0.0
        st[S_PM] = pm
        # --- forces and their Jacobian
        fs, dfs, q, xm = _static_terms(par, x, pm)
        ff, dff = _friction_terms(par, st, q, v, x / xm)
        tension = fs + ff - cv * v
        if tension < 0.0:
            # a muscle only pulls: friction cannot make the tension negative (slack)
            tension = 0.0
            dfs = 0.0
            dff = 0.0
        th = math.tanh(v / eps)
        rv = v / vs
        fslip = fc + fsx * math.exp(-rv * rv)
        fseal = fslip * th + bseal * v
        dseal = fslip * (1.0 - th * th) / eps + bseal
        fstop, sjx, sjv = _end_stop(x, v, xlo, xhi, kstop, cstop)
        jx = dfs + dff + sjx
        jv = -cv - dseal + sjv
        if jx > 0.0:
            jx = 0.0
        net = tension - st[S_PC] * area - fseal + fstop
        vn = (v + dt * kv * (net - jv * v)) / (1.0 - dt * kv * jv - dt * dt * kv * jx)
        xn = x + dt * vn
        acc = (vn - v) / dt
        # --- Maxwell-slip elements follow the displacement (rate independent)
        dx = xn - x
        ds = _slip_scale(par, q)
        for i in range(ne):
            d = par[P_DELTA0 + i] * ds
            u = st[S_U0 + i] + dx
            if u > d:
                u = d
            elif u < -d * rd:
                u = -d * rd
            st[S_U0 + i] = u
        st[S_X] = xn
        st[S_V] = vn
        st[S_A] = acc
        st[S_T] = t0 + (j + 1) * dt
        # --- load cell: muscle tension minus inertia of the mass between them
        flc = tension - mb * acc * 1e-3
        st[S_FLC] = flc
        # --- sensor first-order lags
        st[S_YX] += a_yx * (xn - st[S_YX])
        st[S_YF] += a_yf * (flc - st[S_YF])
        st[S_YPM] += a_ypm * (pm - st[S_YPM])
        st[S_YPC] += a_ypc * (st[S_PC] - st[S_YPC])
        # --- history for pure channel delays
        h = ptr[R_HIDX]
        hist[h, 0] = st[S_T]
        hist[h, 1] = st[S_YX]
        hist[h, 2] = st[S_YF]
        hist[h, 3] = st[S_YPM]
        hist[h, 4] = st[S_YPC]
        ptr[R_HIDX] = (h + 1) % HIST_SIZE
        if ptr[R_HCNT] < HIST_SIZE:
            ptr[R_HCNT] += 1
    st[S_T] = t_target
    for k in range(N_STATE):
        if not math.isfinite(st[k]):
            return 1
    return 0


@njit(cache=True)
def _delayed(st, hist, ptr, col, tq):
    """Channel ``col`` of the history at time ``tq`` (linear interpolation)."""
    cnt = ptr[R_HCNT]
    if cnt == 0:
        return st[S_YX + col - 1]
    newest = (ptr[R_HIDX] - 1) % HIST_SIZE
    if tq >= hist[newest, 0]:
        return hist[newest, col]
    k = newest
    for _ in range(cnt - 1):
        kp = (k - 1) % HIST_SIZE
        if hist[kp, 0] <= tq:
            t1 = hist[kp, 0]
            t2 = hist[k, 0]
            w = (tq - t1) / (t2 - t1) if t2 > t1 else 1.0
            return hist[kp, col] + w * (hist[k, col] - hist[kp, col])
        k = kp
    return hist[k, col]  # older than the history: the oldest value


@njit(cache=True)
def _measure(st, mpar, hist, ptr, noise, out):
    """Fill ``out`` with (time, position, force, muscle_pressure, cylinder_pressure)."""
    t = st[S_T]
    out[0] = t
    for c in range(4):
        d = mpar[M_DELAY0 + c]
        if d > 0.0:
            y = _delayed(st, hist, ptr, c + 1, t - d)
        else:
            y = st[S_YX + c]
        if c == 0:
            y += mpar[M_DRIFT_X] * (t - mpar[M_DRIFT_T0])
        elif c == 1:
            y += mpar[M_DRIFT_F] * (t - mpar[M_DRIFT_T0])
        y += mpar[M_NOISE0 + c] * noise[c]
        r = mpar[M_RES0 + c]
        if r > 0.0:
            y = round(y / r) * r
        out[c + 1] = y


# ----------------------------------------------------------------- packed entry points
# One float workspace W = [state | physics params | measurement params | out] keeps the
# number of arguments (and numba's per-call dispatch cost) small on the 500 Hz path.
O_ST = 0
O_PAR = N_STATE
O_MPAR = O_PAR + N_PARAM
O_OUT = O_MPAR + N_MPARAM
N_W = O_OUT + 5


@njit(cache=True)
def advance(w, pend, ptr, hist, t_target):
    """Integrate the workspace's state to ``t_target``; 0 = ok, 1 = non-finite state."""
    return _advance(w[O_ST:O_PAR], w[O_PAR:O_MPAR], pend, ptr, hist, t_target)


@njit(cache=True)
def measure(w, ptr, hist, noise):
    """Write the five measured channels into ``w[O_OUT:]`` using the next noise row.

    Returns 2 when the noise block is used up (the caller draws a new one), else 0.
    """
    i = ptr[R_NI]
    _measure(w[O_ST:O_PAR], w[O_MPAR:O_OUT], hist, ptr, noise[i], w[O_OUT:N_W])
    ptr[R_NI] = i + 1
    return 2 if i + 1 >= noise.shape[0] else 0


@njit(cache=True)
def advance_measure(w, pend, ptr, hist, noise, t_target):
    """:func:`advance` then :func:`measure` in one compiled call (the sampler's fast path)."""
    rc = advance(w, pend, ptr, hist, t_target)
    return rc | measure(w, ptr, hist, noise)


@njit(cache=True)
def forces_w(w):
    """:func:`forces` on a workspace."""
    return forces(w[O_ST:O_PAR], w[O_PAR:O_MPAR])


def new_buffers() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fresh (workspace, pending commands, pointers, history) arrays."""
    return (
        np.zeros(N_W),
        np.zeros((PEND_SIZE, 2)),
        np.zeros(N_PTR, dtype=np.int64),
        np.zeros((HIST_SIZE, 5)),
    )
