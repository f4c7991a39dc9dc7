"""Joint refinement of the pressure laws θ(p) on the free-run error of every run at once.

Why.  Per-run fits of a model with many shape parameters (an asymmetric Bouc-Wen has nine)
land in different, nearly equivalent optima on different runs: collinear parameters
wander from run to run while each run's force is fitted to 99 %.  Independent quadratics
through such values combine, at an intermediate pressure, into a parameter set that no run
ever had — and the hysteretic state can run away on held-out data.  DESIGN.md: "fix or
re-parametrize rather than fit noise into the quadratics".

What.  After the per-run fits and their stderr-weighted quadratics (the start), the
coefficients of every θ_j(p) are refined *jointly*: one ``scipy.optimize.least_squares``
on the free-run prediction error of all identification runs together.  Each run keeps its
own initial hysteretic state h0 (a nuisance parameter: the start state of one record, not
a property of the muscle), and so does every record nuisance parameter of the model's
effects (``Effect.nuisance_params``, e.g. a load cell's drift rate: a property of the
sensor during that record, so it gets one value per run, never a pressure law).  Each
run's residual is divided by std(F_run)·√N_run, so the
cost is ½·Σ nrmse² and every run counts equally whatever its force level or length.

Parametrisation.  θ_j(p) = Σ_d c_jd·P_d(u), P_d the Legendre polynomials of
u = (2p − p_lo − p_hi)/(p_hi − p_lo) ∈ [−1, 1] over the identified pressure range: the
coefficients are nearly orthogonal (well conditioned), and the top one measures the
curvature (or slope) directly, which is what the order test needs.  θ is clipped into the
law's bounds when evaluated.  The results are reported as q0 + q1·p + q2·p² (p in MPa).

Order (0, 1 or 2 in p) of every parameter: first from the per-run fits
(:func:`choose_degrees`: a parameter that is collinear with another — |ρ| > 0.95 — or at a
bound on at least half the runs is held constant in p; otherwise BIC on its per-run values),
then pruned on the joint fit: a top coefficient whose Wald statistic (c/se)² is below
ln N_eff (the BIC penalty of one parameter) is dropped, and the pruned model is kept only if
its joint BIC is not worse.

Speed.  Runs are subsampled to ≤ ``SAMPLES_PER_CYCLE`` samples per excitation cycle (and
≤ ``MAX_SAMPLES`` per run) after the zero-phase filter; the laws are rate independent and
the effects use the full-rate derivatives, so the loss is small.  The Jacobian is computed
per *parameter* (one perturbation of θ_j on every run at once, chained to its Legendre
coefficients) and all h0 are perturbed together (each affects one run only): (P + 1)·R
model evaluations per Jacobian (one more R per nuisance parameter).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals
from pmalab.runfile import Run

#: samples per excitation cycle kept for the joint fit (loops need ~100; margin ×2)
SAMPLES_PER_CYCLE = 200
#: at most this many samples of one run enter the joint fit
MAX_SAMPLES = 2500
#: limit on function evaluations of one joint least-squares
MAX_NFEV = 60
#: cap of one weighted residual (≈ 1e3 × the run's own rmse·√N: a runaway prediction)
RESID_CAP = 1e3
#: a run's |ρ| above this with another parameter (or a bound hit) counts as "not determined"


# --------------------------------------------------------------------------- data
@dataclass
class JointRun:
    """One identification run, subsampled for the joint fit."""

    label: str
    p_nom: float
    sig: Signals
    force: np.ndarray  # N, on the subsampled grid
    sd: float  # std of the measured force, N
    weight: float  # 1 / (σ·√N), σ the run's own error scale (see :func:`prepare`)
    sigma: float = 1.0  # σ (N): the run's own error scale (the weight's denominator)

    @property
    def n(self) -> int:
        return int(self.force.shape[0])


def prepare(run: Run, error_scale: float | None = None) -> JointRun:
    """Filter (as every fit does) and subsample one run.

    ``error_scale`` σ (N): the rmse the model reaches on this run alone (its per-run fit).
    Each run's residual is divided by σ·√N, so every run counts equally whatever its length,
    and a run the model cannot fit well even on its own (a different regime, e.g. a weak
    muscle pushed onto its end stop) does not dictate the laws of the others — weighted
    least squares with each run's own error variance.  Default σ: std of the force (the
    cost is then ½·Σ nrmse²).
    """
    sig = Signals.from_run(run)
    n = sig.t.shape[0]
    fs = 1.0 / float(np.median(np.diff(sig.t)))
    f = run.frequency if run.frequency and run.frequency > 0 else None
    stride = int(fs // (SAMPLES_PER_CYCLE * f)) if f else 1
    stride = max(1, stride, int(math.ceil(n / MAX_SAMPLES)))
    s = sig.every(stride)
    force = np.asarray(run.force, dtype=np.float64)[::stride]
    sd = max(float(np.std(force)), 1e-9)
    sigma = sd if error_scale is None or not np.isfinite(error_scale) else error_scale
    sigma = max(float(sigma), 1e-3 * sd)
    w = 1.0 / (sigma * math.sqrt(force.shape[0]))
    return JointRun(label=run.label, p_nom=float(run.nominal_pressure), sig=s, force=force,
                    sd=sd, weight=w, sigma=sigma)


# --------------------------------------------------------------------------- pressure basis
@dataclass(frozen=True)
class PressureBasis:
    """Legendre basis in u = (2p − p_lo − p_hi)/(p_hi − p_lo) over the identified range."""

    p_lo: float
    p_hi: float

    def u(self, p: float | np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        span = self.p_hi - self.p_lo
        if span <= 0:
            return np.zeros_like(p)
        return (2.0 * p - self.p_lo - self.p_hi) / span

    def matrix(self, p: float | np.ndarray, degree: int) -> np.ndarray:
        """Rows: pressures; columns P_0..P_degree."""
        u = np.atleast_1d(self.u(p))
        cols = [np.ones_like(u), u, 1.5 * u * u - 0.5][: degree + 1]
        return np.column_stack(cols)

    def to_monomial(self, c: Sequence[float]) -> tuple[float, float, float]:
        """(q0, q1, q2) of θ(p) = q0 + q1·p + q2·p² equal to Σ c_d·P_d(u(p))."""
        c = list(c) + [0.0] * (3 - len(c))
        nodes = self._nodes()
        vals = self.matrix(nodes, 2) @ np.asarray(c, dtype=np.float64)
        q = np.linalg.solve(np.vander(nodes, 3, increasing=True), vals)
        return float(q[0]), float(q[1]), float(q[2])

    def from_monomial(self, q: Sequence[float], degree: int) -> np.ndarray:
        """Legendre coefficients (degree + 1 of them) of the least-squares fit to q on the range."""
        nodes = self._nodes(7)
        vals = np.vander(nodes, 3, increasing=True) @ np.asarray(list(q) + [0.0] * (3 - len(q)))
        c, *_ = np.linalg.lstsq(self.matrix(nodes, degree), vals, rcond=None)
        return c

    def _nodes(self, m: int = 3) -> np.ndarray:
        if self.p_hi > self.p_lo:
            return np.linspace(self.p_lo, self.p_hi, m)
        # one level: any three distinct points (the basis is constant there)
        return self.p_lo + np.linspace(-0.1, 0.1, m)


# --------------------------------------------------------------------------- result
@dataclass
class JointFit:
    """The jointly refined pressure laws."""

    coef: dict[str, tuple[float, float, float]]  # monomial q per free parameter
    degree: dict[str, int]
    constants: dict[str, float]  # parameters held fixed on every run
    h0: list[float]
    nrmse: list[float]  # per run, subsampled free-run prediction with the joint law
    nrmse_start: list[float]  # the same with the start (per-run quadratics, chosen orders)
    bounds: dict[str, tuple[float, float]]
    basis: PressureBasis
    n_eff: float
    bic: float
    nfev: int
    success: bool
    message: str
    legendre: dict[str, np.ndarray] = field(default_factory=dict)
    legendre_stderr: dict[str, np.ndarray] = field(default_factory=dict)
    #: record nuisance parameters: one fitted value per run (never a pressure law)
    nuisance: dict[str, list[float]] = field(default_factory=dict)

    @property
    def mean_nrmse(self) -> float:
        return float(np.mean(self.nrmse)) if self.nrmse else float("nan")

    @property
    def mean_nrmse_start(self) -> float:
        return float(np.mean(self.nrmse_start)) if self.nrmse_start else float("nan")

    def theta(self, p: float) -> dict[str, float]:
        """Laws at ``p`` (MPa); the per-run parameters (h0, :attr:`nuisance`) are not
        included: they belong to the fitted records."""
        out = dict(self.constants)
        for name, q in self.coef.items():
            lo, hi = self.bounds[name]
            out[name] = float(np.clip(q[0] + q[1] * p + q[2] * p * p, lo, hi))
        return out


# --------------------------------------------------------------------------- the problem
class _Problem:
    """Residuals and Jacobian of the joint fit (see the module docstring)."""

    def __init__(self, model: ForceModel, runs: Sequence[JointRun], basis: PressureBasis,
                 free: Sequence[str], degree: dict[str, int], constants: dict[str, float],
                 bounds: dict[str, tuple[float, float]], has_h0: bool,
                 nuisance: Sequence[str] = ()) -> None:
        self.model, self.runs, self.basis = model, list(runs), basis
        self.free = list(free)
        self.degree = dict(degree)
        self.constants = dict(constants)
        self.bounds = bounds
        self.has_h0 = has_h0
        #: per-run parameters, one block of len(runs) values each after the coefficients
        self.run_names = (["h0"] if has_h0 else []) + list(nuisance)
        self.B = {n: basis.matrix([r.p_nom for r in runs], degree[n]) for n in self.free}
        self.slices: dict[str, slice] = {}
        i = 0
        for n in self.free:
            self.slices[n] = slice(i, i + degree[n] + 1)
            i += degree[n] + 1
        self.n_coef = i
        self.n_var = i + len(runs) * len(self.run_names)
        offs = np.cumsum([0] + [r.n for r in runs])
        self.rows = [slice(int(a), int(b)) for a, b in itertools.pairwise(offs)]
        self.n_rows = int(offs[-1])
        self._cache: tuple[bytes, np.ndarray] | None = None

    def block(self, j: int) -> slice:
        """z indices of the j-th per-run parameter (``run_names[j]``), one per run."""
        R = len(self.runs)
        return slice(self.n_coef + j * R, self.n_coef + (j + 1) * R)

    # raw (unclipped) θ_j at every run's pressure
    def raw(self, z: np.ndarray) -> dict[str, np.ndarray]:
        return {n: self.B[n] @ z[self.slices[n]] for n in self.free}

    def thetas(self, z: np.ndarray) -> list[dict[str, float]]:
        raw = self.raw(z)
        out = []
        for i in range(len(self.runs)):
            th = dict(self.constants)
            for n in self.free:
                lo, hi = self.bounds[n]
                th[n] = float(min(max(raw[n][i], lo), hi))
            for j, rn in enumerate(self.run_names):
                th[rn] = float(z[self.block(j).start + i])
            out.append(th)
        return out

    def _run_resid(self, i: int, th: dict[str, float]) -> np.ndarray:
        r = self.runs[i]
        with np.errstate(all="ignore"):
            e = (self.model.predict(r.sig, th) - r.force) * r.weight
        if not np.all(np.isfinite(e)) or float(np.max(np.abs(e))) > RESID_CAP:
            # a runaway state: cap it so the optimizer sees a large, finite cost
            e = np.clip(np.nan_to_num(e, nan=RESID_CAP, posinf=RESID_CAP, neginf=-RESID_CAP),
                        -RESID_CAP, RESID_CAP)
        return e

    def residual(self, z: np.ndarray) -> np.ndarray:
        key = np.asarray(z, dtype=float).tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        e = np.concatenate([self._run_resid(i, th) for i, th in enumerate(self.thetas(z))])
        self._cache = (key, e)
        return e

    def jac(self, z: np.ndarray, h0_only: bool = False) -> np.ndarray:
        """Forward differences, per parameter (chained to its coefficients) and h0 batched.

        ``h0_only``: only the per-run columns (h0 and nuisance; the others are left zero).
        """
        z = np.asarray(z, dtype=float)
        r0 = self.residual(z)
        ths = self.thetas(z)
        raw = self.raw(z)
        J = np.zeros((self.n_rows, self.n_var))
        for n in ([] if h0_only else self.free):
            lo, hi = self.bounds[n]
            sl = self.slices[n]
            for i, th in enumerate(ths):
                if not (lo < raw[n][i] < hi) and raw[n][i] != th[n]:
                    continue  # clipped: θ does not move with the coefficients here
                d = self._dresid_dparam(i, th, n, hi, r0)
                J[self.rows[i], sl] = np.outer(d, self.B[n][i])
        for j, rn in enumerate(self.run_names):
            lo, hi = self.bounds.get(rn, (-np.inf, np.inf))
            col0 = self.block(j).start
            for i, th in enumerate(ths):
                J[self.rows[i], col0 + i] = self._dresid_dparam(i, th, rn, hi, r0)
        return J

    def _dresid_dparam(self, i: int, th: dict[str, float], name: str, hi: float,
                       r0: np.ndarray) -> np.ndarray:
        """Forward difference of run ``i``'s residual in one parameter (stepping back at
        the upper bound)."""
        v = th[name]
        h = math.sqrt(np.finfo(float).eps) * max(1.0, abs(v))
        if v + h > hi:
            h = -h
        th2 = dict(th)
        th2[name] = v + h
        return (self._run_resid(i, th2) - r0[self.rows[i]]) / h

    def fit_h0(self, z: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """z with every run's h0 (and nuisance parameters) fitted for the given laws.

        First the initial-condition estimate (median force error over the first 50 ms with
        h0 = 0, as validation does; nuisance parameters keep their values in ``z``), then a
        few least-squares steps on the per-run parameters alone.
        """
        z = np.array(z, dtype=float)
        if not self.run_names:
            return z
        k = self.n_coef
        if self.has_h0:
            z[self.block(0)] = 0.0
            for i, th in enumerate(self.thetas(z)):
                r = self.runs[i]
                with np.errstate(all="ignore"):
                    pred = self.model.predict(r.sig, th)
                dt = float(np.median(np.diff(r.sig.t)))
                m = max(1, min(r.n, int(round(0.05 / dt))))
                est = float(np.median(r.force[:m] - pred[:m]))
                z[k + i] = est if np.isfinite(est) else 0.0
        span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        z[k:] = np.clip(z[k:], (lo + 1e-9 * span)[k:], (hi - 1e-9 * span)[k:])

        def f(h: np.ndarray) -> np.ndarray:
            return self.residual(np.concatenate([z[:k], h]))

        def jf(h: np.ndarray) -> np.ndarray:
            return self.jac(np.concatenate([z[:k], h]), h0_only=True)[:, k:]

        sol = least_squares(f, z[k:], jac=jf, bounds=(lo[k:], hi[k:]), method="trf",
                            x_scale="jac", max_nfev=10)
        z[k:] = sol.x
        return z

    def per_run_nrmse(self, z: np.ndarray) -> list[float]:
        e = self.residual(z)
        # residual = err·weight: the run's rmse is |block|/(weight·√N)
        return [float(np.sqrt(e[s] @ e[s])) / (r.weight * math.sqrt(r.n) * r.sd)
                for r, s in zip(self.runs, self.rows)]


def _n_eff(e: np.ndarray, rows: Sequence[slice]) -> float:
    """AR(1) effective sample size summed over runs (as in :mod:`pmalab.identify.fit`)."""
    tot = 0.0
    for s in rows:
        r = e[s] - float(np.mean(e[s]))
        d = float(r @ r)
        rho = float(r[1:] @ r[:-1]) / d if d > 0 else 0.0
        rho = min(max(rho, 0.0), 0.999)
        tot += r.shape[0] * (1.0 - rho) / (1.0 + rho)
    return max(tot, 1.0)


def _solve(prob: _Problem, z0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_nfev: int):
    z0 = np.clip(z0, lo + 1e-9 * np.where(np.isfinite(hi - lo), hi - lo, 1.0),
                 hi - 1e-9 * np.where(np.isfinite(hi - lo), hi - lo, 1.0))
    with threadpool_limits(limits=1, user_api="blas"):
        return least_squares(prob.residual, z0, jac=prob.jac, bounds=(lo, hi), method="trf",
                             x_scale="jac", max_nfev=max_nfev, ftol=1e-8, xtol=1e-8)


def _stats(prob: _Problem, sol) -> tuple[np.ndarray, float, float]:
    """(coefficient stderr in z order (NaN for h0), N_eff, BIC with N_eff)."""
    e = prob.residual(sol.x)
    n_eff = _n_eff(e, prob.rows)
    N = prob.n_rows
    P = prob.n_var
    rss = float(e @ e)
    bic = n_eff * math.log(max(rss / N, 1e-300)) + P * math.log(n_eff)
    J = sol.jac if sol.jac is not None else prob.jac(sol.x)
    try:
        JtJ = J.T @ J
        d = np.sqrt(np.diag(JtJ))
        d[d == 0] = 1.0
        cov = np.linalg.pinv(JtJ / np.outer(d, d), rcond=1e-12) / np.outer(d, d)
        s2 = rss / max(N - P, 1) * (N / n_eff)
        se = np.sqrt(np.abs(np.diag(cov)) * s2)
    except np.linalg.LinAlgError:
        se = np.full(P, np.nan)
    return se, n_eff, bic


def refine(
    model: ForceModel,
    runs: Sequence[JointRun],
    start: dict[str, tuple[float, float, float]],
    degree: dict[str, int],
    constants: dict[str, float],
    bounds: dict[str, tuple[float, float]],
    h0_start: Sequence[float] | None,
    *,
    prune: bool = True,
    max_prune_rounds: int = 2,
    max_nfev: int = MAX_NFEV,
    alternatives: Sequence[tuple[dict[str, tuple[float, float, float]], dict[str, int]]] = (),
    nuisance_start: dict[str, Sequence[float]] | None = None,
) -> tuple[JointFit, list[str]]:
    """Jointly refine the pressure laws (see the module docstring); returns (fit, notes).

    ``start``: monomial q per free parameter (the per-run quadratics); ``degree``: the
    order of each; ``constants``: parameters held fixed; ``bounds``: (lo, hi) per parameter
    (θ is clipped into them); ``h0_start``: per-run start states (None: the law has no h0).
    ``alternatives``: further (start, degree) pairs; the fit starts from the one with the
    lowest cost (h0 fitted for each) and tries the next while it has not beaten it.
    ``nuisance_start``: per-run start values of the record nuisance parameters (one value
    per run each, fitted like h0; see the module docstring).
    """
    levels = [r.p_nom for r in runs]
    basis = PressureBasis(min(levels), max(levels))
    nuis = dict(nuisance_start or {})
    free = [n for n in start if n not in constants and n != "h0" and n not in nuis]
    has_h0 = h0_start is not None
    notes: list[str] = []
    # the per-run tail of z: h0 block, then one block per nuisance parameter
    tail0 = list(h0_start or []) + [float(v) for n in nuis for v in nuis[n]]

    def build(deg: dict[str, int]) -> tuple[_Problem, np.ndarray, np.ndarray]:
        prob = _Problem(model, runs, basis, free, deg, constants, bounds, has_h0, list(nuis))
        lo = np.full(prob.n_var, -np.inf)
        hi = np.full(prob.n_var, np.inf)
        for j, rn in enumerate(prob.run_names):
            lo[prob.block(j)], hi[prob.block(j)] = bounds.get(rn, (-np.inf, np.inf))
        return prob, lo, hi

    def z_from(prob: _Problem, coefs: dict[str, np.ndarray], tail: Sequence[float]) -> np.ndarray:
        z = np.zeros(prob.n_var)
        for n in free:
            c = np.asarray(coefs[n], dtype=float)
            k = prob.degree[n] + 1
            z[prob.slices[n]] = np.concatenate([c, np.zeros(max(0, k - c.size))])[:k]
        z[prob.n_coef:] = list(tail)
        return z

    # the starts: the chosen orders and start laws, then any alternatives (e.g. the plain
    # per-run quadratics); each with its own fitted h0, best (lowest cost) first
    cands = []
    for st, dg in [(start, degree), *(alternatives or [])]:
        deg_c = {n: int(dg.get(n, 2)) for n in free}
        pr, lo_c, hi_c = build(deg_c)
        z = z_from(pr, {n: basis.from_monomial(st[n], deg_c[n]) for n in free}, tail0)
        with threadpool_limits(limits=1, user_api="blas"):
            z = pr.fit_h0(z, lo_c, hi_c)  # the start laws' own start states
        e = pr.residual(z)
        cands.append((float(e @ e), deg_c, pr, lo_c, hi_c, z))
    nr_start = cands[0][2].per_run_nrmse(cands[0][5])
    order = sorted(range(len(cands)), key=lambda i: cands[i][0])
    best = None
    nfev = 0
    for i in order:
        sse0, deg_c, pr, lo_c, hi_c, z = cands[i]
        if best is not None and float(best[1].cost) * 2.0 <= sse0:
            break  # already below this start's cost: no need to try it
        sol_c = _solve(pr, z, lo_c, hi_c, max_nfev)
        nfev += int(sol_c.nfev)
        if best is None or sol_c.cost < best[1].cost:
            best = (pr, sol_c, deg_c)
    assert best is not None
    prob, sol, deg = best

    se, n_eff, bic = _stats(prob, sol)

    for _ in range(max_prune_rounds if prune else 0):
        # drop top coefficients that the joint data do not support (Wald ≈ BIC test: the
        # squared t-value of one coefficient against the BIC penalty ln N_eff)
        pen = math.log(n_eff)
        deg2 = dict(deg)
        for n in free:
            if deg[n] == 0:
                continue
            j = prob.slices[n].stop - 1
            c, s_ = float(sol.x[j]), float(se[j])
            if not np.isfinite(s_) or s_ == 0 or (c / s_) ** 2 < pen:
                deg2[n] = deg[n] - 1
        if deg2 == deg:
            break
        prob2, lo2, hi2 = build(deg2)
        coefs = {n: sol.x[prob.slices[n]][: deg2[n] + 1] for n in free}
        sol2 = _solve(prob2, z_from(prob2, coefs, sol.x[prob.n_coef:]), lo2, hi2, max_nfev)
        se2, n_eff2, bic2 = _stats(prob2, sol2)
        nfev += int(sol2.nfev)
        dropped = [f"{n} {deg[n]}->{deg2[n]}" for n in free if deg2[n] != deg[n]]
        # compare on a common N_eff (the richer model's) so the penalty is the same
        e1, e2 = prob.residual(sol.x), prob2.residual(sol2.x)
        b1 = n_eff * math.log(max(float(e1 @ e1), 1e-300)) + prob.n_var * pen
        b2 = n_eff * math.log(max(float(e2 @ e2), 1e-300)) + prob2.n_var * pen
        if b2 > b1:
            notes.append(f"joint fit: kept pressure orders (lowering {', '.join(dropped)} "
                         "raised the joint BIC)")
            break
        notes.append("joint fit: pressure order lowered where the joint data do not support "
                     f"it (Wald/BIC): {', '.join(dropped)}")
        prob, sol, se, n_eff, bic, deg = prob2, sol2, se2, n_eff2, bic2, deg2

    coef = {n: basis.to_monomial(sol.x[prob.slices[n]]) for n in free}
    leg = {n: np.array(sol.x[prob.slices[n]]) for n in free}
    leg_se = {n: np.array(se[prob.slices[n]]) for n in free}
    h0 = [float(v) for v in sol.x[prob.block(0)]] if has_h0 else []
    jn = 1 if has_h0 else 0
    nuis_fit = {n: [float(v) for v in sol.x[prob.block(jn + j)]] for j, n in enumerate(nuis)}
    fit = JointFit(coef=coef, degree=deg, constants=dict(constants), h0=h0,
                   nrmse=prob.per_run_nrmse(sol.x), nrmse_start=nr_start, bounds=dict(bounds),
                   basis=basis, n_eff=n_eff, bic=bic, nfev=nfev, success=bool(sol.success),
                   message=str(sol.message), legendre=leg, legendre_stderr=leg_se,
                   nuisance=nuis_fit)
    return fit, notes


def evaluate(model: ForceModel, runs: Sequence[JointRun], coef: dict[str, Sequence[float]],
             constants: dict[str, float], bounds: dict[str, tuple[float, float]],
             h0: Sequence[float] | None,
             nuisance: dict[str, Sequence[float]] | None = None) -> list[float]:
    """Per-run nrmse (subsampled free run) of the monomial pressure laws ``coef``.

    Each run's h0 (and record nuisance parameters, starting from ``nuisance``) is fitted
    for these laws (as in the joint fit), so the comparison with the joint fit is fair.
    ``h0`` only says whether the law has a state (None: no h0).
    """
    levels = [r.p_nom for r in runs]
    basis = PressureBasis(min(levels), max(levels))
    nuis = dict(nuisance or {})
    free = [n for n in coef if n not in constants and n != "h0" and n not in nuis]
    prob = _Problem(model, runs, basis, free, dict.fromkeys(free, 2), constants, bounds,
                    h0 is not None, list(nuis))
    z = np.zeros(prob.n_var)
    for n in free:
        z[prob.slices[n]] = basis.from_monomial(coef[n], 2)
    jn = 1 if h0 is not None else 0
    for j, n in enumerate(nuis):
        z[prob.block(jn + j)] = [float(v) for v in nuis[n]]
    if prob.run_names:
        lo_a = np.full(prob.n_var, -np.inf)
        hi_a = np.full(prob.n_var, np.inf)
        for j, rn in enumerate(prob.run_names):
            lo_a[prob.block(j)], hi_a[prob.block(j)] = bounds.get(rn, (-np.inf, np.inf))
        with threadpool_limits(limits=1, user_api="blas"):
            z = prob.fit_h0(z, lo_a, hi_a)  # each run's best start state for these laws
    return prob.per_run_nrmse(z)


# --------------------------------------------------------------------------- orders
def _bic_degree(p: np.ndarray, y: np.ndarray, w: np.ndarray, max_deg: int) -> int:
    """Order (≤ max_deg) of a weighted polynomial in p by BIC with unknown noise scale."""
    n = p.shape[0]
    best, best_d = float("inf"), 0
    for d in range(0, max_deg + 1):
        if d + 1 >= n:
            break
        V = np.vander(p, d + 1, increasing=True)
        c, *_ = np.linalg.lstsq(V * w[:, None], y * w, rcond=None)
        rss = float(np.sum((w * (y - V @ c)) ** 2))
        b = n * math.log(max(rss / n, 1e-300)) + (d + 1) * math.log(n)
        if b < best - 1e-9:
            best, best_d = b, d
    return best_d


#: per-run values of a collinear parameter still trace a pressure law when an unweighted
#: quadratic explains this much of their variance (e.g. c0, k, A: large, smooth trends)
SMOOTH_R2 = 0.9


def _smooth_r2(p: np.ndarray, y: np.ndarray, max_deg: int) -> float:
    """Unweighted R² of a polynomial (≤ max_deg) through the per-run values."""
    d = min(max_deg, max(np.unique(np.round(p, 4)).shape[0] - 1, 0))
    if d == 0 or np.ptp(y) == 0:
        return 1.0 if np.ptp(y) == 0 else 0.0
    c = np.polyfit(p, y, d)
    res = y - np.polyval(c, p)
    return float(1.0 - (res @ res) / float(np.sum((y - y.mean()) ** 2)))


def start_laws(
    names: Sequence[str],
    pressures: Sequence[float],
    values: dict[str, Sequence[float]],
    stderr: dict[str, Sequence[float | None]],
    undetermined: dict[str, Sequence[bool]],
    max_degree: int,
) -> tuple[dict[str, tuple[float, float, float]], dict[str, int], list[str]]:
    """Start laws (monomial q) and orders from the per-run fits; returns (q, orders, notes).

    ``undetermined[name][i]``: the parameter was collinear (|ρ| > 0.95 with another) or at
    a bound on run i.  A parameter undetermined on at least half the runs whose values do
    not follow a smooth law anyway (unweighted quadratic R² < :data:`SMOOTH_R2`; a collinear
    c0 that still rises steadily with pressure keeps its trend) *wanders* between nearly
    equivalent optima: it starts from the median of its values (a 1/stderr weighted mean
    would follow whichever run was most over-confident) and the joint fit decides its order
    (the Wald/BIC pruning makes it a constant unless all runs together support a trend).
    Every other parameter gets the order chosen by BIC over its determined runs' values and
    starts from the weighted polynomial of that order (stderrs floored at their median, so no
    single run dominates).
    """
    p_all = np.asarray(pressures, dtype=np.float64)
    start: dict[str, tuple[float, float, float]] = {}
    out: dict[str, int] = {}
    notes: list[str] = []
    for n in names:
        y_all = np.asarray(values[n], dtype=np.float64)
        bad = np.asarray(undetermined[n], dtype=bool)
        smooth = _smooth_r2(p_all, y_all, max_degree)
        if 2 * int(bad.sum()) >= bad.shape[0] and max_degree > 0 and smooth < SMOOTH_R2:
            out[n] = max_degree
            start[n] = (float(np.median(y_all)), 0.0, 0.0)
            notes.append(f"{n}: poorly determined per run (collinear with another parameter or "
                         f"at a bound on {int(bad.sum())} of {bad.shape[0]} runs; per-run values "
                         f"wander, unweighted R² {smooth:.2f}): no per-run quadratic — the joint "
                         "fit starts from their median and keeps only the pressure terms all "
                         "runs together support")
            continue
        good = ~bad if int((~bad).sum()) > max_degree + 1 else np.ones_like(bad)
        p = p_all[good]
        y = y_all[good]
        se = np.array([np.nan if s is None else float(s) for s in stderr[n]])[good]
        ok = np.isfinite(se) & (se > 0)
        med = float(np.median(se[ok])) if ok.any() else 1.0
        w = 1.0 / np.maximum(np.where(ok, se, med), med)
        levels = np.unique(np.round(p, 4)).shape[0]
        md = min(max_degree, max(levels - 1, 0))
        d = _bic_degree(p, y, w, md) if md > 0 else 0
        out[n] = d
        c, *_ = np.linalg.lstsq(np.vander(p, d + 1, increasing=True) * w[:, None], y * w,
                                rcond=None)
        q = [0.0, 0.0, 0.0]
        q[: d + 1] = [float(v) for v in c]
        start[n] = (q[0], q[1], q[2])
        if d < md:
            notes.append(f"{n}: pressure order {d} (BIC over its per-run values; "
                         f"order {md} not supported)")
    return start, out, notes
