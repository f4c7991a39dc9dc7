"""Joint refinement of the pressure laws θ(p) on the free-run error of every run at once.

Why.  Per-run fits of a model with many shape parameters (an asymmetric Bouc-Wen has nine)
land in different, nearly equivalent optima on different runs: collinear parameters
wander from run to run while each run's force is fitted to 99 %.  Independent quadratics
through such values combine, at an intermediate pressure, into a parameter set that no run
ever had — and the hysteretic state can run away on held-out data.  The rule: fix or
re-parametrize rather than fit noise into the quadratics.

What.  After the per-run fits and their stderr-weighted quadratics (the start), the
coefficients of every θ_j(p) are refined *jointly*: one ``scipy.optimize.least_squares``
on the free-run prediction error of all identification runs together.  Each run keeps its
own initial hysteretic state h0 (a nuisance parameter: the start state of one record, not
a property of the muscle), and so does every record nuisance parameter of the model's
effects (``Effect.nuisance_params``, e.g. a load cell's drift rate: a property of the
sensor during that record, so it gets one value per run, never a pressure law).  Each
run's residual is divided by std(F_run)·√N_run, so the
cost is ½·Σ nrmse² and every run counts equally whatever its force level or length.

Parametrisation: the Legendre pressure basis of :mod:`~pmalab.identify.estimation.basis`;
θ is clipped into the law's bounds when evaluated; results are reported as
q0 + q1·p + q2·p² (p in MPa).  A campaign-wide parameter (``Effect.campaign_shared``, e.g. a
channel skew: a property of the rig) is held at order 0.

The problem is :class:`~pmalab.identify.estimation.problem.Problem` (shared parameters
through the pressure basis, per-run h0 and record nuisances), solved and assessed by
:mod:`~pmalab.identify.estimation.solver` — the same engine as a single-run fit.

Order (0, 1 or 2 in p) of every parameter: first from the per-run fits
(:func:`start_laws`: a parameter that is collinear with another — |ρ| > 0.95 — or at a
bound on at least half the runs is held constant in p; otherwise BIC on its per-run values),
then pruned on the joint fit: a top coefficient whose Wald statistic (c/se)² is below
ln N_eff (the BIC penalty of one parameter) is dropped, and the pruned model is kept only if
its joint BIC is not worse.

Speed.  Runs are subsampled to ≤ ``SAMPLES_PER_CYCLE`` samples per excitation cycle (and
≤ ``MAX_SAMPLES`` per run, but never < ``MIN_SAMPLES_PER_CYCLE`` per cycle: a long run is
not aliased to fit a budget) after the zero-phase filter; the laws are rate independent and
the effects use the full-rate derivatives, so the loss is small.  The Jacobian is computed
per *parameter* (one perturbation of θ_j on every run at once, chained to its Legendre
coefficients) and all h0 are perturbed together (each affects one run only): (P + 1)·R
model evaluations per Jacobian (one more R per nuisance parameter).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pmalab.identify.estimation.basis import PressureBasis, fit_polynomial, weights
from pmalab.identify.estimation.problem import Problem, Record
from pmalab.identify.estimation.records import fit_record_params
from pmalab.identify.estimation.solver import one_blas_thread, solve, uncertainty
from pmalab.identify.messages import detail
from pmalab.identify.metrics import information_criteria
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals
from pmalab.runfile import Run

#: samples per excitation cycle kept for the joint fit (loops need ~100; margin ×2)
SAMPLES_PER_CYCLE = 200
#: at most this many samples of one run enter the joint fit, unless that leaves fewer
#: than ``MIN_SAMPLES_PER_CYCLE`` per excitation cycle
MAX_SAMPLES = 2500
#: the joint fit never keeps fewer samples per excitation cycle (``signals.every``)
MIN_SAMPLES_PER_CYCLE = 100
#: limit on function evaluations of one joint least-squares
MAX_NFEV = 120
#: cap of one weighted residual (≈ 1e3 × the run's own rmse·√N: a runaway prediction)
RESID_CAP = 1e3
#: a run's |ρ| above this with another parameter (or a bound hit) counts as "not determined"


# --------------------------------------------------------------------------- data
def joint_stride(n: int, sample_rate_Hz: float, frequency_Hz: float | None) -> int:
    """Subsampling stride of one run in the joint fit.

    ``SAMPLES_PER_CYCLE`` samples per excitation cycle, and at most ``MAX_SAMPLES`` of the
    run — but never fewer than ``MIN_SAMPLES_PER_CYCLE`` per cycle: striding a run of many
    cycles down to a fixed count would alias its path (a 10-hour 0.5 Hz run in 2,500
    samples is one sample every 7 cycles), so a long run costs time in proportion to its
    length instead.  Unknown frequency: at most ``MAX_SAMPLES``."""
    f = frequency_Hz if frequency_Hz and frequency_Hz > 0 else None
    if f is None:
        return max(1, int(math.ceil(n / MAX_SAMPLES)))
    stride = max(1, int(sample_rate_Hz // (SAMPLES_PER_CYCLE * f)), int(math.ceil(n / MAX_SAMPLES)))
    return max(1, min(stride, int(sample_rate_Hz // (MIN_SAMPLES_PER_CYCLE * f))))


def prepare(run: Run, error_scale: float | None = None) -> Record:
    """Filter (as every fit does) and subsample one run into an estimator record.

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
    stride = joint_stride(n, fs, sig.frequency_Hz)  # an unknown one: from the motion band
    s = sig.every(stride)
    force = np.asarray(run.force, dtype=np.float64)[::stride]
    sd = max(float(np.std(force)), 1e-9)
    sigma = sd if error_scale is None or not np.isfinite(error_scale) else error_scale
    sigma = max(float(sigma), 1e-3 * sd)
    return Record(
        label=run.label,
        p_nom=float(run.nominal_pressure),
        sig=s,
        force=force,
        weight=1.0 / (sigma * math.sqrt(force.shape[0])),
    )


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
    #: leave-one-pressure-out nrmse of every run at an interior level (record label →
    #: nrmse), by :func:`approx_lopo`; empty unless asked for (``refine(lopo=True)``)
    lopo: dict[str, float] = field(default_factory=dict)
    #: the solved problem, its solution vector and Jacobian there (set with ``lopo``): what
    #: a caller needs to score variants of the fit by the same influence approximation
    #: (:func:`approx_lopo` with a ``prior``) without refitting
    problem: Problem | None = field(default=None, repr=False)
    z: np.ndarray | None = field(default=None, repr=False)
    jac: np.ndarray | None = field(default=None, repr=False)

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
def _problem(
    model: ForceModel,
    runs: Sequence[Record],
    basis: PressureBasis,
    free: Sequence[str],
    degree: dict[str, int],
    constants: dict[str, float],
    bounds: dict[str, tuple[float, float]],
    run_params: Sequence[str],
) -> Problem:
    return Problem(
        model,
        runs,
        free=free,
        degree=degree,
        constants=constants,
        bounds=bounds,
        run_params=run_params,
        cap=RESID_CAP,
        basis=basis,
    )


def _solve(prob: Problem, z0: np.ndarray, max_nfev: int):
    lo, hi = prob.z_bounds()
    return solve(prob.residual, prob.jac, z0, lo, hi, max_nfev=max_nfev)


def _stats(prob: Problem, sol) -> tuple[np.ndarray, float, float]:
    """(stderr in z order, N_eff, BIC with N_eff)."""
    e = prob.residual(sol.x)
    J = sol.jac if sol.jac is not None else prob.jac(sol.x)
    u = uncertainty(J, e, prob.rows)
    _, bic = u.ic(float(e @ e), prob.n_rows, prob.n_var)
    return u.stderr, u.n_eff, bic


def refine(
    model: ForceModel,
    runs: Sequence[Record],
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
    nuisance_start: Mapping[str, Sequence[float]] | None = None,
    fixed_order: Sequence[str] = (),
    lopo: bool = False,
) -> tuple[JointFit, list[str]]:
    """Jointly refine the pressure laws (see the module docstring); returns (fit, notes).

    ``start``: monomial q per free parameter (the per-run quadratics); ``degree``: the
    order of each; ``constants``: parameters held fixed; ``bounds``: (lo, hi) per parameter
    (θ is clipped into them); ``h0_start``: per-run start states (None: the law has no h0).
    ``alternatives``: further (start, degree) pairs; the fit starts from the one with the
    lowest cost (h0 fitted for each) and tries the next while it has not beaten it.
    ``nuisance_start``: per-run start values of the record nuisance parameters (one value
    per run each, fitted like h0).  ``fixed_order``: parameters whose order is never pruned
    or raised (campaign-wide constants).  ``lopo``: also estimate every interior-level
    run's leave-one-pressure-out error (:func:`approx_lopo`, ``JointFit.lopo``).
    """
    basis = PressureBasis.over([r.p_nom for r in runs])
    nuis = dict(nuisance_start or {})
    free = [n for n in start if n not in constants and n != "h0" and n not in nuis]
    run_params = (["h0"] if h0_start is not None else []) + list(nuis)
    run_start = {**({"h0": list(h0_start)} if h0_start is not None else {}), **nuis}
    notes: list[str] = []

    def build(deg: dict[str, int]) -> Problem:
        return _problem(model, runs, basis, free, deg, constants, bounds, run_params)

    # the starts: the chosen orders and start laws, then any alternatives (e.g. the plain
    # per-run quadratics); each with its own fitted h0, best (lowest cost) first
    cands = []
    for st, dg in [(start, degree), *(alternatives or [])]:
        deg_c = {n: (0 if n in fixed_order else int(dg.get(n, 2))) for n in free}
        pr = build(deg_c)
        z = pr.z_from({n: basis.from_monomial(st[n], deg_c[n]) for n in free}, run_start)
        with one_blas_thread():
            z = fit_record_params(pr, z, max_nfev=10)  # the start laws' own start states
        e = pr.residual(z)
        cands.append((float(e @ e), deg_c, pr, z))
    nr_start = cands[0][2].per_run_nrmse(cands[0][3])
    order = sorted(range(len(cands)), key=lambda i: cands[i][0])
    best = None
    nfev = 0
    for i in order:
        sse0, deg_c, pr, z = cands[i]
        if best is not None and float(best[1].cost) * 2.0 <= sse0:
            break  # already below this start's cost: no need to try it
        sol_c = _solve(pr, z, max_nfev)
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
        prob2 = build(deg2)
        coefs = {n: sol.x[prob.slices[n]][: deg2[n] + 1] for n in free}
        sol2 = _solve(prob2, prob2.z_from(coefs, prob.run_values(sol.x)), max_nfev)
        se2, n_eff2, bic2 = _stats(prob2, sol2)
        nfev += int(sol2.nfev)
        dropped = [f"{n} {deg[n]}->{deg2[n]}" for n in free if deg2[n] != deg[n]]
        # compare on a common N_eff (the richer model's) so the penalty is the same
        e1, e2 = prob.residual(sol.x), prob2.residual(sol2.x)
        rows = len(e1)
        b1 = information_criteria(float(e1 @ e1), rows, prob.n_var, n_eff)[1]
        b2 = information_criteria(float(e2 @ e2), rows, prob2.n_var, n_eff)[1]
        if b2 > b1:
            notes.append(
                detail(
                    "joint-order",
                    f"joint fit: kept pressure orders (lowering {', '.join(dropped)} "
                    "raised the joint BIC)",
                )
            )
            break
        notes.append(
            detail(
                "joint-order",
                "joint fit: pressure order lowered where the joint data do not support "
                f"it (Wald/BIC): {', '.join(dropped)}",
            )
        )
        prob, sol, se, n_eff, bic, deg = prob2, sol2, se2, n_eff2, bic2, deg2

    coef = {n: basis.to_monomial(sol.x[prob.slices[n]]) for n in free}
    leg = {n: np.array(sol.x[prob.slices[n]]) for n in free}
    leg_se = {n: np.array(se[prob.slices[n]]) for n in free}
    rv = prob.run_values(sol.x)
    fit = JointFit(
        coef=coef,
        degree=deg,
        constants=dict(constants),
        h0=rv.get("h0", []),
        nrmse=prob.per_run_nrmse(sol.x),
        nrmse_start=nr_start,
        bounds=dict(bounds),
        basis=basis,
        n_eff=n_eff,
        bic=bic,
        nfev=nfev,
        success=bool(sol.success),
        message=str(sol.message),
        legendre=leg,
        legendre_stderr=leg_se,
        nuisance={n: rv[n] for n in nuis},
    )
    if lopo:
        J = sol.jac if getattr(sol, "jac", None) is not None else prob.jac(sol.x)
        fit.lopo = approx_lopo(prob, sol.x, np.asarray(J))
        fit.problem, fit.z, fit.jac = prob, np.array(sol.x), np.asarray(J)
    return fit, notes


def approx_lopo(
    prob: Problem,
    z: np.ndarray,
    J: np.ndarray,
    r: np.ndarray | None = None,
    prior: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, float]:
    """Leave-one-pressure-out nrmse of every run at an interior pressure level, estimated
    from the joint solution ``z`` and its Jacobian ``J`` (record label → nrmse).

    For each interior level L (rounded to 1 kPa; the lowest and highest levels are never
    left out — predicting them is extrapolation): one Gauss–Newton step of the joint problem
    *without* the runs at L from ``z`` (the influence approximation of refitting without
    them: at the optimum the step is exactly the pull of those runs removed), then the runs
    at L predicted with the stepped laws, their own per-run parameters (h0, nuisances)
    re-estimated on them (linearised, as a validation run's start state is estimated).  The
    pressure orders are the ones chosen on all runs.  nrmse is RMS error (N) ÷ std of the
    record's force, on the joint fit's subsampled records.

    ``r``: the residual at ``z`` (default: evaluated); ``prior``: (M, p) extra residual rows
    p + M·dz of a linear penalty on the solution (a smoothness prior), kept in every fold —
    the held-out error of the penalised fit.
    """
    r = prob.residual(z) if r is None else np.asarray(r, dtype=np.float64)
    J = np.asarray(J, dtype=np.float64)
    keys = np.array([round(float(rec.p_nom), 3) for rec in prob.records])
    levels = sorted(set(keys.tolist()))
    R = len(prob.records)
    nc = prob.n_coef
    run_cols = [[prob.block(j).start + i for j in range(len(prob.run_params))] for i in range(R)]
    # normal equations once; a fold removes its runs' rows (J_G'J_G, J_G'r_G) and columns
    A = J.T @ J
    g = J.T @ r
    if prior is not None:
        M, pr = prior
        A = A + M.T @ M
        g = g + M.T @ pr
    out: dict[str, float] = {}
    for L in levels[1:-1]:
        G = [i for i in range(R) if keys[i] == L]
        T = [i for i in range(R) if keys[i] != L]
        rows_g = np.concatenate([np.arange(prob.rows[i].start, prob.rows[i].stop) for i in G])
        Jg = J[rows_g]
        cols = np.array(list(range(nc)) + [c for i in T for c in run_cols[i]], dtype=np.intp)
        At = (A - Jg.T @ Jg)[np.ix_(cols, cols)]
        gt = (g - Jg.T @ r[rows_g])[cols]
        # column scaling (the coefficients and start states differ by orders of magnitude)
        d = np.sqrt(np.maximum(np.diag(At), 0.0))
        d = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
        step = -d * np.linalg.lstsq(At * d[:, None] * d[None, :], gt * d, rcond=1e-12)[0]
        dc = step[:nc]
        for i in G:
            rows = np.arange(prob.rows[i].start, prob.rows[i].stop)
            e = r[rows] + J[rows, :nc] @ dc
            if run_cols[i]:
                Jr = J[np.ix_(rows, np.array(run_cols[i], dtype=np.intp))]
                eps, *_ = np.linalg.lstsq(Jr, -e, rcond=None)
                e = e + Jr @ eps
            rec = prob.records[i]
            err_N = e / rec.weight
            out[rec.label] = float(np.sqrt(np.mean(err_N**2)) / rec.sd)
    return out


def evaluate(
    model: ForceModel,
    runs: Sequence[Record],
    coef: Mapping[str, Sequence[float]],
    constants: dict[str, float],
    bounds: dict[str, tuple[float, float]],
    h0: Sequence[float] | None,
    nuisance: Mapping[str, Sequence[float]] | None = None,
) -> list[float]:
    """Per-run nrmse (subsampled free run) of the monomial pressure laws ``coef``.

    Each run's h0 (and record nuisance parameters, starting from ``nuisance``) is fitted
    for these laws (as in the joint fit), so the comparison with the joint fit is fair.
    ``h0`` only says whether the law has a state (None: no h0).
    """
    basis = PressureBasis.over([r.p_nom for r in runs])
    nuis = dict(nuisance or {})
    free = [n for n in coef if n not in constants and n != "h0" and n not in nuis]
    run_params = (["h0"] if h0 is not None else []) + list(nuis)
    prob = _problem(model, runs, basis, free, dict.fromkeys(free, 2), constants, bounds, run_params)
    z = prob.z_from({n: basis.from_monomial(coef[n], 2) for n in free}, nuis)
    with one_blas_thread():
        z = fit_record_params(prob, z, max_nfev=10)  # each run's best start state
    return prob.per_run_nrmse(z)


# --------------------------------------------------------------------------- orders
#: per-run values of a collinear parameter still trace a pressure law when an unweighted
#: quadratic explains this much of their variance (e.g. c0, k, A: large, smooth trends)
SMOOTH_R2 = 0.9


def start_laws(
    names: Sequence[str],
    pressures: Sequence[float],
    values: Mapping[str, Sequence[float]],
    stderr: Mapping[str, Sequence[float | None]],
    undetermined: Mapping[str, Sequence[bool]],
    max_degree: int,
) -> tuple[dict[str, tuple[float, float, float]], dict[str, int], list[str]]:
    """Start laws (monomial q) and orders from the per-run fits; returns (q, orders, notes).

    ``undetermined[name][i]``: the parameter was collinear (|ρ| > 0.95 with another) or at
    a bound on run i.  A parameter undetermined on at least half the runs whose values do
    not follow a smooth law anyway (unweighted polynomial R² < :data:`SMOOTH_R2`; a collinear
    c0 that still rises steadily with pressure keeps its trend) *wanders* between nearly
    equivalent optima: it starts from the median of its values (a 1/stderr weighted mean
    would follow whichever run was most over-confident) and the joint fit decides its order
    (the Wald/BIC pruning makes it a constant unless all runs together support a trend).
    Every other parameter gets the order chosen by BIC over its determined runs' values and
    starts from the weighted polynomial of that order (stderrs floored at their median, so no
    single run dominates) — both through :func:`~pmalab.identify.estimation.basis.fit_polynomial`.
    """
    p_all = np.asarray(pressures, dtype=np.float64)
    start: dict[str, tuple[float, float, float]] = {}
    out: dict[str, int] = {}
    notes: list[str] = []
    for n in names:
        y_all = np.asarray(values[n], dtype=np.float64)
        bad = np.asarray(undetermined[n], dtype=bool)
        smooth = fit_polynomial(p_all, y_all, max_degree=max_degree).r2
        if 2 * int(bad.sum()) >= bad.shape[0] and max_degree > 0 and smooth < SMOOTH_R2:
            out[n] = max_degree
            start[n] = (float(np.median(y_all)), 0.0, 0.0)
            notes.append(
                detail(
                    "poorly-determined",
                    f"{n}: poorly determined per run (collinear with another parameter or "
                    f"at a bound on {int(bad.sum())} of {bad.shape[0]} runs; per-run values "
                    f"wander, unweighted R² {smooth:.2f}): no per-run quadratic — the joint "
                    "fit starts from their median and keeps only the pressure terms all "
                    "runs together support",
                )
            )
            continue
        good = ~bad if int((~bad).sum()) > max_degree + 1 else np.ones_like(bad)
        p = p_all[good]
        w = weights(
            [s for s, g in zip(stderr[n], good) if g], int(good.sum()), floor_at_median=True
        )
        pf = fit_polynomial(p, y_all[good], w, max_degree=max_degree, select=True)
        levels = np.unique(np.round(p, 4)).shape[0]
        md = min(max_degree, max(levels - 1, 0))
        out[n] = pf.degree
        start[n] = pf.coef
        if pf.degree < md:
            notes.append(
                detail(
                    "pressure-order",
                    f"{n}: pressure order {pf.degree} (BIC over its per-run values; "
                    f"order {md} not supported)",
                    name=n,
                    order=pf.degree,
                )
            )
    return start, out, notes
