"""The identified model as a plant: force or pressure in, position out.

Identification runs the model one way: measured position in, force out
(:meth:`pmalab.identify.model.ForceModel.predict`).  This module integrates the same force
law the other way, as an equation of motion of the moving end of the muscle::

    (m + M)·ẍ·10⁻³ = F_muscle(x, ẋ, h, p) − u(t) − K·x
    F_muscle      = k·x + c0 + h·(1 + hx·x) + k2·x² + k3·x³ + (p0 + p1·x)·(p − p_nom) − c·ẋ

x contraction (mm, positive = shorter), ẋ in mm/s, ẍ in mm/s² (×10⁻³ for N with masses in
kg), forces in N, p muscle pressure in MPa.  k, c0 and h are the base law; the other terms
are the effects' (each effect declares its term, ``Effect.plant``): m the moving mass of the
inertia effect (the load cell reads F_muscle − m·ẍ), c the viscous coefficient, k2/k3
nonlinear stiffness, p0/p1 pressure variation, hx the asymmetric loop width.  Effects
without a forward form (a sensor delay, a drifting zero) are refused by name.

Two ways to drive it:

* **force input** (``u`` = the measured load-cell tension, the Bouc-Wen benchmark's u): the
  muscle is pulled by a force actuator; ``M`` = ``K`` = 0.
* **pressure input with a load** (the manipulator): ``u`` = the preload F0 (N), ``M`` the
  load mass (kg), ``K`` a load spring (N/mm); the pressure trace p(t) sets θ(p) at every
  sub-step through the identification's pressure laws.

Integrator (one source: ``pmalab simulate``, ``identify --output position`` and the
model-in-the-loop plant of ``pmalab control --plant`` all call :func:`simulate`):
velocity Verlet (Störmer–Verlet, second order) with the damping term implicit (trapezoidal,
so a large c cannot destabilise it) and the hysteresis state advanced *exactly* along each
sub-step's position segment by the law's own segment integrator (the one ``identify``
uses).  The inputs are interpolated linearly between samples.  Stiffness: the explicit
position update is stable for ω·Δt < 2 with ω² = (|k| + K + the law's largest slope)/(m + M);
the sample interval is split into ``n_sub`` sub-steps so that ω·Δt ≤ 0.05 (a phase error
below 0.01 % per cycle of the fastest mode), at most 400.  The Bouc-Wen benchmark at 750 Hz
(ω ≈ 224 rad/s) takes 6 sub-steps per sample.

Without a moving mass (no inertia effect, or a fitted m ≤ 0, and no load mass) force in →
position out is the quasi-static balance F_muscle(x, h(x), ẋ) = u + K·x solved at every
sample (bracketed Illinois regula falsi to 1e-10 mm; ẋ backward Euler), laws with a
compiled segment only.

Laws with a compiled segment (``HysteresisLaw.kernel``, in the law's own file) run in one
numba loop (a 60 s, 500 Hz record in ~20 ms): Bouc-Wen's and Duhem's cached on disk, any
other law's compiled on first use in a process (:func:`compiled_loops`); laws without one
(element laws, whose state is a vector) step in Python (~1 s for the same record).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from pmalab.errors import PmalabError
from pmalab.identify.laws.bouc_wen import bw_kernel
from pmalab.identify.laws.duhem import duhem_kernel
from pmalab.identify.model import ForceModel

#: force-law terms of the forward model, in the order the compiled loop reads them
SLOTS = ("k", "c0", "mass", "damping", "k2", "k3", "p0", "p1", "hx")
#: sub-steps are sized so that ω·Δt stays below this
OMEGA_DT = 0.05
#: ... and never more than this many per sample
MAX_SUBSTEPS = 400
#: the built-in segments the on-disk-cached loops are compiled with (a numba function
#: argument would defeat that cache); every other law's ``kernel()`` gets loops of its own,
#: compiled once per process (:func:`compiled_loops`)
_CACHED = {bw_kernel: 0, duhem_kernel: 1}
#: a position beyond this (mm) is a runaway simulation
RUNAWAY_MM = 1e6


class ForwardError(PmalabError):
    """A model that cannot be run forward (no mass, an effect without a forward form)."""


@dataclass(frozen=True)
class Load:
    """What the muscle moves: a mass (kg), a spring (N/mm, resisting contraction) and a
    preload (N, a constant tension the muscle must hold)."""

    mass_kg: float = 0.0
    stiffness_N_per_mm: float = 0.0
    preload_N: float = 0.0


@dataclass
class Simulation:
    """A forward run: position (mm), velocity (mm/s), hysteretic force h (N) and the
    muscle's tension F_muscle (N) at every input sample; ``status`` is ``"ok"`` or
    ``"diverged"`` (the arrays are NaN from the sample where it ran away)."""

    position: np.ndarray
    velocity: np.ndarray
    h: np.ndarray
    tension: np.ndarray
    n_sub: int
    status: str = "ok"


def plant_slots(model: ForceModel) -> dict[str, str]:
    """slot → parameter name of every effect term (refuses effects with no forward form)."""
    out: dict[str, str] = {"k": "k", "c0": "c0"}
    for e in model.effects:
        if e.plant is None:
            raise ForwardError(
                f"effect '{e.id}' has no forward (plant) form: a forward simulation supports "
                f"{', '.join(sorted(forward_effects()))}"
            )
        out.update(e.plant)
    return out


def forward_effects() -> list[str]:
    """Ids of the catalogue effects a forward simulation can carry."""
    from pmalab.identify.effects import EFFECTS

    return [i for i in EFFECTS if EFFECTS[i].plant is not None]


class Coefficients:
    """Every parameter the forward loop needs as θ(p) = q0 + q1·p + q2·p² rows, clipped
    into bounds — one row per :data:`SLOTS` entry and one per law parameter.

    ``theta``: either one parameter set (constant in p: identify's convention, parameters
    at the run's nominal pressure) or pressure laws {name: (q0, q1, q2)} (a plant whose
    pressure moves, as under a controller)."""

    def __init__(
        self,
        model: ForceModel,
        theta: Mapping[str, float | Sequence[float]],
        bounds: Mapping[str, tuple[float, float]] | None = None,
    ) -> None:
        self.model = model
        law = model.law
        slots = plant_slots(model)
        b = dict(bounds or {})
        law_names = [lp.name for lp in law.params]

        def row(name: str | None) -> tuple[list[float], float, float]:
            if name is None:
                return [0.0, 0.0, 0.0], -np.inf, np.inf
            if name not in theta:
                raise ForwardError(f"parameter '{name}' missing from the model's parameters")
            q = theta[name]
            qs = [float(q), 0.0, 0.0] if np.ndim(q) == 0 else [float(v) for v in q]  # type: ignore[arg-type]
            qs = [*qs, 0.0, 0.0, 0.0][:3]
            lo, hi = b.get(name, (-np.inf, np.inf))
            return qs, float(lo), float(hi)

        rows = [row(slots.get(s)) for s in SLOTS] + [row(n) for n in law_names]
        self.Q = np.array([r[0] for r in rows], dtype=np.float64)
        self.lo = np.array([r[1] for r in rows], dtype=np.float64)
        self.hi = np.array([r[2] for r in rows], dtype=np.float64)
        self.n_slots = len(SLOTS)
        self.law_names = law_names
        # law extras of the effects (asymmetric shape terms): constant, at θ(p_nom)
        th0 = self.named(0.0)
        extras: dict[str, float] = {}
        for e in model.effects:
            extras.update(e.law_extras(law.name, None, th0))  # type: ignore[arg-type]
        self.extras_map = extras
        self.extras = np.array([float(extras.get(n, 0.0)) for n in law.extras], dtype=np.float64)

    def at(self, p: float) -> np.ndarray:
        """Every row's value at pressure ``p`` (MPa), clipped: :data:`SLOTS`, then the law's."""
        return np.clip(self.Q[:, 0] + self.Q[:, 1] * p + self.Q[:, 2] * p * p, self.lo, self.hi)

    def law_theta(self, v: np.ndarray) -> dict[str, float]:
        """The law's parameters by name from a row vector of :meth:`at`."""
        return {n: float(x) for n, x in zip(self.law_names, v[self.n_slots :], strict=True)}

    def named(self, p: float) -> dict[str, float]:
        """Every parameter by name at pressure ``p`` (MPa)."""
        v = self.at(p)
        slots = plant_slots(self.model)
        out = {slots[s]: float(v[i]) for i, s in enumerate(SLOTS) if s in slots}
        out.update({n: float(v[self.n_slots + j]) for j, n in enumerate(self.law_names)})
        return out


def law_slope(model: ForceModel, theta: Mapping[str, float], extras: Mapping[str, float]) -> float:
    """The law's largest |dh/dx| (N/mm) from the virgin state: its stiffest contribution."""
    d = 1e-3
    best = 0.0
    for sgn in (1.0, -1.0):
        x = np.array([0.0, sgn * d])
        h = model.law.h(x, {**theta, "h0": 0.0}, extras)
        best = max(best, abs(float(h[1] - h[0])) / d)
    return best


def substeps(model: ForceModel, coef: Coefficients, p: np.ndarray, dt: float, load: Load) -> int:
    """Sub-steps per sample so that ω·Δt ≤ :data:`OMEGA_DT` at every pressure visited."""
    n = 1
    for pv in np.unique(np.round(np.quantile(p, [0.0, 0.5, 1.0]), 6)):
        v = coef.at(float(pv))
        m = (v[2] + load.mass_kg) * 1e-3
        if m <= 0:
            continue
        th = coef.law_theta(v)
        stiff = abs(v[0]) + abs(load.stiffness_N_per_mm) + law_slope(model, th, coef.extras_map)
        omega = math.sqrt(stiff / m)
        n = max(n, int(math.ceil(omega * dt / OMEGA_DT)))
    return min(n, MAX_SUBSTEPS)


@njit(cache=True, fastmath=False)
def _theta(Q, lo, hi, p, out):
    for i in range(Q.shape[0]):
        v = Q[i, 0] + Q[i, 1] * p + Q[i, 2] * p * p
        out[i] = min(max(v, lo[i]), hi[i])


@njit(cache=True, fastmath=False)
def _static(c, x, h, p, p_nom, u, KL):
    """F_muscle without the damping term, minus the load (N); c = θ at this pressure."""
    return (
        c[0] * x
        + c[1]
        + h * (1.0 + c[8] * x)
        + (c[4] + c[5] * x) * x * x
        + (c[6] + c[7] * x) * (p - p_nom)
        - u
        - KL * x
    )


@njit(cache=True, fastmath=False)
def _seg(law_id, h, x0, x1, prm):
    """The compiled segment of a built-in law (a numba function argument would defeat the
    on-disk cache and cost ~0.6 s of compilation in every new process)."""
    if law_id == 0:
        return bw_kernel(h, x0, x1, prm)
    return duhem_kernel(h, x0, x1, prm)


@njit(cache=True, fastmath=False)
def _integrate(
    law_id, t, u, p, p_nom, Q, lo, hi, extras, ns, ML, KL, x0, v0, h0, nsub, xo, vo, ho, fo
):
    N = t.shape[0]
    nq = Q.shape[0]
    ca = np.empty(nq)
    cb = np.empty(nq)
    prm = np.empty(nq - ns + extras.shape[0])
    for j in range(extras.shape[0]):
        prm[nq - ns + j] = extras[j]
    x = x0
    v = v0
    h = h0
    _theta(Q, lo, hi, p[0], ca)
    xo[0] = x
    vo[0] = v
    ho[0] = h
    fo[0] = _static(ca, x, h, p[0], p_nom, 0.0, 0.0) - ca[3] * v
    for k in range(N - 1):
        dt = (t[k + 1] - t[k]) / nsub
        for j in range(nsub):
            fa = j / nsub
            fb = (j + 1.0) / nsub
            pa = p[k] + (p[k + 1] - p[k]) * fa
            pb = p[k] + (p[k + 1] - p[k]) * fb
            ua = u[k] + (u[k + 1] - u[k]) * fa
            ub = u[k] + (u[k + 1] - u[k]) * fb
            _theta(Q, lo, hi, pa, ca)
            m = (ca[2] + ML) * 1e-3
            if m <= 0.0:
                return -2, k
            c = ca[3]
            vh = (v + 0.5 * dt * _static(ca, x, h, pa, p_nom, ua, KL) / m) / (
                1.0 + 0.5 * dt * c / m
            )
            xn = x + dt * vh
            # the law's parameters at the segment's mid pressure
            _theta(Q, lo, hi, 0.5 * (pa + pb), cb)
            for i in range(nq - ns):
                prm[i] = cb[ns + i]
            h = _seg(law_id, h, x, xn, prm)
            x = xn
            _theta(Q, lo, hi, pb, cb)
            m = (cb[2] + ML) * 1e-3
            c = cb[3]
            v = (vh + 0.5 * dt * _static(cb, x, h, pb, p_nom, ub, KL) / m) / (
                1.0 + 0.5 * dt * c / m
            )
        if not (abs(x) < 1e6) or not (abs(v) < 1e12) or not (abs(h) < 1e12):
            return -1, k + 1
        xo[k + 1] = x
        vo[k + 1] = v
        ho[k + 1] = h
        fo[k + 1] = _static(cb, x, h, p[k + 1], p_nom, 0.0, 0.0) - cb[3] * v
    return 0, N


@njit(cache=True, fastmath=False)
def _qs_resid(law_id, c, prm, x, xk, hk, p, p_nom, u, KL, dt):
    """Force balance at x for the segment xk → x: F_muscle(x) − u − K·x (N) and h(x)."""
    h = _seg(law_id, hk, xk, x, prm)
    return _static(c, x, h, p, p_nom, u, KL) - c[3] * (x - xk) / dt, h


@njit(cache=True, fastmath=False)
def _quasi_static(law_id, t, u, p, p_nom, Q, lo, hi, extras, ns, KL, x0, h0, xo, vo, ho, fo):
    """Massless forward model: at every sample x solves F_muscle(x, h(x), ẋ) = u + K·x,
    h advanced along x_k → x and ẋ = (x − x_k)/Δt (backward Euler in the damping).  The
    balance falls monotonically with x for a physical muscle (k < 0, h's slope ≤ |k|'s
    side), so the root is bracketed by stepping out from x_k and found by the Illinois
    variant of regula falsi to 1e-10 mm."""
    N = t.shape[0]
    nq = Q.shape[0]
    c = np.empty(nq)
    prm = np.empty(nq - ns + extras.shape[0])
    for j in range(extras.shape[0]):
        prm[nq - ns + j] = extras[j]
    x = x0
    h = h0
    _theta(Q, lo, hi, p[0], c)
    xo[0] = x
    vo[0] = 0.0
    ho[0] = h
    fo[0] = _static(c, x, h, p[0], p_nom, 0.0, 0.0)
    for k in range(N - 1):
        dt = t[k + 1] - t[k]
        _theta(Q, lo, hi, 0.5 * (p[k] + p[k + 1]), c)
        for i in range(nq - ns):
            prm[i] = c[ns + i]
        _theta(Q, lo, hi, p[k + 1], c)
        a = x
        fa, _ = _qs_resid(law_id, c, prm, a, x, h, p[k + 1], p_nom, u[k + 1], KL, dt)
        if fa == 0.0:
            b = a
            fb = fa
        else:
            # the balance falls with x: a positive residual means the muscle pulls harder
            # than the load, so the root lies at larger contraction
            step = 1e-3 if fa > 0 else -1e-3
            b = a + step
            fb, _ = _qs_resid(law_id, c, prm, b, x, h, p[k + 1], p_nom, u[k + 1], KL, dt)
            n = 0
            while fa * fb > 0.0 and n < 60:
                a, fa = b, fb
                step *= 2.0
                b = a + step
                fb, _ = _qs_resid(law_id, c, prm, b, x, h, p[k + 1], p_nom, u[k + 1], KL, dt)
                n += 1
            if fa * fb > 0.0:
                return -1, k + 1
            for _ in range(100):
                m = b - fb * (b - a) / (fb - fa)
                fm, _ = _qs_resid(law_id, c, prm, m, x, h, p[k + 1], p_nom, u[k + 1], KL, dt)
                if fm * fb < 0.0:  # the root lies between b and m
                    a, fa = b, fb
                else:  # between a and m: keep a, halve its residual (Illinois)
                    fa *= 0.5
                b, fb = m, fm
                if abs(b - a) < 1e-10 or fm == 0.0:
                    break
        xn = b
        _, hn = _qs_resid(law_id, c, prm, xn, x, h, p[k + 1], p_nom, u[k + 1], KL, dt)
        vo[k + 1] = (xn - x) / dt
        x = xn
        h = hn
        if not (abs(x) < 1e6) or not (abs(h) < 1e12):
            return -1, k + 1
        xo[k + 1] = x
        ho[k + 1] = h
        fo[k + 1] = _static(c, x, h, p[k + 1], p_nom, 0.0, 0.0) - c[3] * vo[k + 1]
    return 0, N


@dataclass(frozen=True)
class CompiledLoops:
    """A law's compiled forward loops: ``integrate`` (with a moving mass) and
    ``quasi_static`` (massless), both called as ``loop(law_id, ...)`` with the arguments of
    :func:`_integrate` / :func:`_quasi_static`."""

    law_id: int
    integrate: Callable[..., tuple[int, int]]
    quasi_static: Callable[..., tuple[int, int]]


def _rebind(fn: Any, **names: Any) -> Any:
    """``fn`` (a numba dispatcher) recompiled with some of its global names bound to other
    compiled functions: the same loop with another law's segment."""
    import types

    py = fn.py_func
    glob = dict(py.__globals__)
    glob.update(names)
    f = types.FunctionType(py.__code__, glob, py.__name__, py.__defaults__, py.__closure__)
    return njit(fastmath=False)(f)


_DYNAMIC: dict[Any, CompiledLoops] = {}


def compiled_loops(law: Any) -> CompiledLoops | None:
    """The compiled forward loops of a law with a compiled segment (``law.kernel()``, one
    scalar state), or None (element laws step in Python).

    A law brings its own segment in its own file; nothing here lists the laws.  The
    built-in Bouc-Wen and Duhem segments run in loops cached on disk; any other law's
    segment is bound into the same loops (:func:`_rebind`), compiled on first use in a
    process (about a second) and at full speed after it.
    """
    kern = law.kernel()
    if kern is None or law.state_size != 1:
        return None
    if kern in _CACHED:
        return CompiledLoops(_CACHED[kern], _integrate, _quasi_static)
    loops = _DYNAMIC.get(kern)
    if loops is None:
        seg = njit(fastmath=False)(lambda law_id, h, x0, x1, prm: kern(h, x0, x1, prm))
        qs_resid = _rebind(_qs_resid, _seg=seg)
        loops = _DYNAMIC[kern] = CompiledLoops(
            -1, _rebind(_integrate, _seg=seg), _rebind(_quasi_static, _qs_resid=qs_resid)
        )
    return loops


def simulate(
    model: ForceModel,
    theta: Mapping[str, float | Sequence[float]],
    t: np.ndarray,
    u: np.ndarray | float,
    p: np.ndarray | float,
    *,
    p_nom: float | None = None,
    load: Load = Load(),
    x0: float = 0.0,
    v0: float = 0.0,
    h0: float = 0.0,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    n_sub: int | None = None,
) -> Simulation:
    """Integrate the model forward from (x0 mm, v0 mm/s, h0 N) — see the module docstring.

    ``t`` time stamps (s), ``u`` the input force (N: measured tension, or the load's preload),
    ``p`` muscle pressure (MPa), ``p_nom`` the pressure the pressure-variation term is taken
    from (default: the mean of ``p``), ``theta`` one parameter set or pressure laws,
    ``n_sub`` sub-steps per sample (default: sized for stability and accuracy).
    """
    t = np.ascontiguousarray(t, dtype=np.float64)
    N = t.shape[0]
    if N < 2:
        raise ForwardError("a forward simulation needs at least two samples")
    u_a = np.ascontiguousarray(np.broadcast_to(np.asarray(u, dtype=np.float64), (N,)))
    p_a = np.ascontiguousarray(np.broadcast_to(np.asarray(p, dtype=np.float64), (N,)))
    pn = float(np.mean(p_a)) if p_nom is None else float(p_nom)
    coef = Coefficients(model, theta, bounds)
    if not np.all(np.diff(t) > 0):
        raise ForwardError("time stamps must increase")
    mass = coef.at(pn)[2] + load.mass_kg
    loops = compiled_loops(model.law)
    u_eff = u_a + load.preload_N
    xo, vo, ho, fo = (np.full(N, np.nan) for _ in range(4))
    if not mass > 0:
        # no moving mass (none identified, or the fit's m ≤ 0): the quasi-static balance
        if loops is None:
            raise ForwardError(
                f"force in -> position out without a moving mass needs a law with a compiled "
                f"segment (HysteresisLaw.kernel), which {model.law.name} has not: add the "
                "inertia effect or give the load a mass"
            )
        Qs = coef.Q.copy()
        Qs[2, :] = 0.0  # a fitted m ≤ 0 is no mass: treated as 0
        code, k = loops.quasi_static(
            loops.law_id,
            t,
            u_eff,
            p_a,
            pn,
            Qs,
            coef.lo,
            coef.hi,
            coef.extras,
            coef.n_slots,
            float(load.stiffness_N_per_mm),
            float(x0),
            float(h0),
            xo,
            vo,
            ho,
            fo,
        )
        return Simulation(
            position=xo,
            velocity=vo,
            h=ho,
            tension=fo,
            n_sub=0,
            status="ok" if code == 0 else "diverged",
        )
    dt = float(np.median(np.diff(t)))
    ns = n_sub or substeps(model, coef, p_a, dt, load)
    if loops is not None:
        code, k = loops.integrate(
            loops.law_id,
            t,
            u_eff,
            p_a,
            pn,
            coef.Q,
            coef.lo,
            coef.hi,
            coef.extras,
            coef.n_slots,
            float(load.mass_kg),
            float(load.stiffness_N_per_mm),
            float(x0),
            float(v0),
            float(h0),
            int(ns),
            xo,
            vo,
            ho,
            fo,
        )
    else:
        code, k, _ = _integrate_py(
            model, coef, t, u_eff, p_a, pn, load, x0, v0, h0, ns, xo, vo, ho, fo
        )
    if code == -2:
        raise ForwardError(
            f"the moving mass is not positive at sample {k} (pressure "
            f"{p_a[k]:.4g} MPa): the inertia law left its range"
        )
    return Simulation(
        position=xo,
        velocity=vo,
        h=ho,
        tension=fo,
        n_sub=int(ns),
        status="ok" if code == 0 else "diverged",
    )


def _integrate_py(
    model: ForceModel,
    coef: Coefficients,
    t,
    u,
    p,
    p_nom,
    load: Load,
    x0,
    v0,
    h0,
    nsub,
    xo,
    vo,
    ho,
    fo,
    state: Any = None,
) -> tuple[int, int, Any]:
    """The same scheme as :func:`_integrate` for laws without a compiled segment (element
    laws): the state is the law's own (``initial_state`` from ``h0``, or ``state`` carried
    over from a previous call), steppers cached per 1 kPa.  Returns (code, samples, the
    law's state at the end)."""
    law = model.law

    steppers: dict[int, Callable[..., Any]] = {}

    def stepper(pv: float):
        key = int(round(pv * 1000.0))
        st = steppers.get(key)
        if st is None:
            th = coef.law_theta(coef.at(key / 1000.0))
            st = steppers[key] = law.stepper(th, coef.extras_map)
        return st

    KL = float(load.stiffness_N_per_mm)

    def static(c, x, h, pv, uv):  # the compiled loop's force balance, called from Python
        return _static(c, x, h, pv, p_nom, uv, KL)

    c0 = coef.at(float(p[0]))
    th0 = coef.law_theta(c0)
    if state is None:
        state = law.initial_state(th0, h0, 1.0)
    x, v = float(x0), float(v0)
    h = law.output(state)
    xo[0], vo[0], ho[0] = x, v, h
    fo[0] = _static(c0, x, h, p[0], p_nom, 0.0, 0.0) - c0[3] * v
    cb = c0
    for k in range(t.shape[0] - 1):
        dt = (t[k + 1] - t[k]) / nsub
        for j in range(nsub):
            fa, fb = j / nsub, (j + 1.0) / nsub
            pa = p[k] + (p[k + 1] - p[k]) * fa
            pb = p[k] + (p[k + 1] - p[k]) * fb
            ua = u[k] + (u[k + 1] - u[k]) * fa
            ub = u[k] + (u[k + 1] - u[k]) * fb
            ca = coef.at(pa)
            m = (ca[2] + load.mass_kg) * 1e-3
            if m <= 0:
                return -2, k, state
            vh = (v + 0.5 * dt * static(ca, x, h, pa, ua) / m) / (1.0 + 0.5 * dt * ca[3] / m)
            xn = x + dt * vh
            state = stepper(0.5 * (pa + pb))(state, x, xn)
            h = law.output(state)
            x = xn
            cb = coef.at(pb)
            m = (cb[2] + load.mass_kg) * 1e-3
            v = (vh + 0.5 * dt * static(cb, x, h, pb, ub) / m) / (1.0 + 0.5 * dt * cb[3] / m)
        if not (abs(x) < RUNAWAY_MM and abs(v) < 1e12 and abs(h) < 1e12):
            return -1, k + 1, state
        xo[k + 1], vo[k + 1], ho[k + 1] = x, v, h
        fo[k + 1] = _static(cb, x, h, p[k + 1], p_nom, 0.0, 0.0) - cb[3] * v
    return 0, t.shape[0], state


# --------------------------------------------------------------------------- identified plant
class IdentifiedPlant:
    """An ``identification.json`` as a plant: the law, its effects, the pressure laws
    θ(p) = q0 + q1·p + q2·p² and their bounds — what ``pmalab simulate`` and the
    model-in-the-loop controller integrate."""

    def __init__(self, doc: Mapping, source: str = "<memory>") -> None:
        from pmalab.identify.effects import get_effect

        law = doc.get("model")
        fits = doc.get("pressure_fits")
        if doc.get("kind") == "static":
            raise ForwardError(
                f"{source}: a static characterization (identify --static "
                f"{doc.get('static_map', {}).get('id', '')}) has no forward model: "
                "identify an isobaric campaign for simulate and control"
            )
        if not isinstance(law, str) or not isinstance(fits, Mapping):
            raise ForwardError(
                f"{source}: not an identification.json (no 'model' and 'pressure_fits')"
            )
        try:
            self.model = ForceModel(law, [get_effect(e) for e in doc.get("effects") or []])
        except (KeyError, ValueError, PmalabError) as exc:
            raise ForwardError(f"{source}: {exc}") from None
        self.laws: dict[str, tuple[float, float, float]] = {}
        for n, q in fits.items():
            if (
                not isinstance(q, list)
                or len(q) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in q)
            ):
                raise ForwardError(f"{source}: pressure_fits.{n}: expected [q0, q1, q2]")
            self.laws[str(n)] = (float(q[0]), float(q[1]), float(q[2]))
        self.bounds = {
            n: (float(b[0]), float(b[1])) for n, b in (doc.get("parameter_bounds") or {}).items()
        }
        self.output = str(doc.get("output") or "force")
        self.initial = str((doc.get("method") or {}).get("initial_state_validation") or "estimate")
        self.pressure_range = tuple(doc.get("pressure_range_MPa") or (float("nan"),) * 2)
        self.source = source

    @classmethod
    def read(cls, path: str | Path) -> IdentifiedPlant:
        """From a directory holding ``identification.json`` or the file itself (read and
        checked by the file's one reader, :func:`pmalab.identify.schema.read_identification`)."""
        from pmalab.identify.schema import read_identification
        from pmalab.paths import DATA_DIR, shipped

        # a result directory, its identification.json, or a shipped identification by name
        # or clone path (data/control/identification-bouc-wen.json) from an installed wheel
        p = shipped(path, DATA_DIR / "control", ".json")
        f = p / "identification.json" if p.is_dir() else p
        if not f.is_file():
            raise ForwardError(f"{path}: no identification.json there (run pmalab identify)")
        return cls(read_identification(f, error=ForwardError), str(f))

    def theta(self, p: float) -> dict[str, float]:
        """Parameters at pressure ``p`` (MPa), clipped into their bounds, record
        parameters at 0 — the same θ ``identify`` predicts held-out runs with."""
        th = {}
        for n, (q0, q1, q2) in self.laws.items():
            v = q0 + q1 * p + q2 * p * p
            lo, hi = self.bounds.get(n, (-np.inf, np.inf))
            th[n] = float(min(max(v, lo), hi)) if np.isfinite(v) else v
        for s in self.model.record_params:
            th[s] = 0.0
        return th

    def free_laws(self) -> dict[str, tuple[float, float, float]]:
        """The pressure laws as θ rows for a run whose pressure moves (record params 0)."""
        out = dict(self.laws)
        for s in self.model.record_params:
            out[s] = (0.0, 0.0, 0.0)
        return out
