"""Fitting one run: two-stage start, joint free-run refinement, honest uncertainty.

Procedure (``fit_run``), all on the *free-run* prediction error (the model is driven by the
measured, zero-phase filtered position only, never by the measured force):

1. **Linear stage** (the seeds' first stage): least squares of F ≈ k·x + c0, the centreline.
2. **Hysteretic stage**, automatic start without hand tuning.  Both laws are linear in one
   scale parameter once the shape is fixed: for Bouc-Wen with n = 1, h(A·s) = s·h(A)
   (h0 ∝ A), and for Duhem h is linear in b (with a = 0, h0 ∝ b).  So we search the shape on a
   small log-spaced grid sized from the stroke (Bouc-Wen: decay rates β ± γ per mm;
   Duhem: α per mm) and at every grid point solve (k, c0, scale) exactly by linear least
   squares (variable projection).  The grid is the multi-start: the two best points are
   refined in stage 3.
3. **Joint refinement** of every free parameter with ``scipy.optimize.least_squares``
   (``trf``, bounds, ``x_scale='jac'``).  Effects start from their own data-sized defaults
   on top of the fitted base law.

Uncertainty: the covariance is s²·(JᵀJ)⁻¹ at the optimum (J the Jacobian of the residual).
Residuals of a hysteresis fit are strongly autocorrelated (a model error persists over a
loop), so the naive standard errors are optimistic; we inflate the covariance by N/N_eff
with N_eff = N·(1 − ρ₁)/(1 + ρ₁) from the lag-1 autocorrelation ρ₁ of the residual (the
AR(1) effective sample size).  ``stderr_method`` says so in every result.

Identifiability: pairs with |ρ| > 0.95 and a condition number of the column-scaled JᵀJ
above 1e8 are reported in ``warnings``.  Defaults that remove known degeneracies:

* Bouc-Wen: n fixed at 1 (n trades off against β, γ and makes the exact kernel possible);
  if |ρ(β, γ)| > 0.95 (Brunot et al. 2017 report 0.998) we refit with γ = 0 and keep that
  fix when the nrmse rises by less than 1 % relative — the warning records both numbers;
* Duhem: a fixed at 0 — with F = k·x + c0 + h the force depends on k + a only (write
  h = a·x + u: u obeys du = −α|dx|·u + (b − a)·dx), so k and a are structurally
  non-identifiable.

h0 (the hysteretic force at the first sample) is fitted: the run's own start state.  For
predicting *another* run (validation) it is estimated from that run's first 50 ms of
force, or set by a burn-in / to zero (:func:`predict_free`).
Nothing is excluded: every sample of the run enters the fit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from pmalab.errors import PmalabError
from pmalab.identify.model import ForceModel
from pmalab.identify.params import Params
from pmalab.identify.signals import Signals
from pmalab.identify.validate import loop_direction, metrics
from pmalab.runfile import Run

#: parameters that describe the run's start state, not the muscle (no pressure quadratic use)
STATE_PARAMS = ("h0",)

RHO_LIMIT = 0.95
COND_LIMIT = 1e8
FIX_TOLERANCE = 0.01  # accept an identifiability fix if nrmse rises by < 1 % (relative)

STDERR_METHOD = (
    "Jacobian covariance s^2 (J^T J)^-1 inflated by N/N_eff, N_eff = N(1-r1)/(1+r1) "
    "from the lag-1 residual autocorrelation r1 (AR(1) effective sample size)"
)


class FitError(PmalabError):
    """A fit cannot be done on this input (too short, constant position...)."""


# --------------------------------------------------------------------------- results
@dataclass
class FitResult:
    """The outcome of :func:`fit_run` (units: N, mm, MPa; see the model's parameter docs)."""

    model: ForceModel
    params: Params
    #: free parameter names, the order of ``correlation``
    names: list[str]
    correlation: np.ndarray
    warnings: list[str]
    fixed: list[str]
    rmse: float
    nrmse: float
    fit_percent: float
    cost: float  # ½·Σ residual² (N²)
    n_free: int
    n_samples: int
    n_eff: float
    aic: float
    bic: float
    condition_number: float
    metrics: dict = field(default_factory=dict)
    stderr_method: str = STDERR_METHOD
    label: str = ""
    #: remarks that are not problems (e.g. a benign correlation explained)
    notes: list[str] = field(default_factory=list)

    @property
    def values(self) -> dict[str, float]:
        return self.params.values()

    @property
    def stderr(self) -> dict[str, float | None]:
        return {p.name: p.stderr for p in self.params}

    def predict(self, sig: Signals | Run, *, initial: str | None = None,
                force: np.ndarray | None = None) -> np.ndarray:
        """Force (N) along ``sig``.  ``initial=None``: the fitted h0 (the fitted run itself);
        otherwise h0 is set as :func:`predict_free` describes (another run)."""
        if isinstance(sig, Run):
            force = sig.force if force is None else force
            sig = Signals.from_run(sig)
        if initial is None:
            return self.model.predict(sig, self.values)
        return predict_free(self.model, sig, self.values, force=force, initial=initial)

    def summary(self) -> str:
        lines = [f"{self.model.name}: fit {self.fit_percent:.2f} %  rmse {self.rmse:.3g} N  "
                 f"nrmse {self.nrmse:.4f}"]
        for p in self.params:
            se = "fixed" if not p.vary else (f"± {p.stderr:.3g}" if p.stderr is not None else "± ?")
            lines.append(f"  {p.name:>10} = {p.value:12.6g} {se} {p.unit}")
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"<FitResult {self.model.name} {self.label} fit={self.fit_percent:.2f}%>"


# --------------------------------------------------------------------------- helpers
def as_signals_and_force(data: Run | tuple[Signals, np.ndarray]) -> tuple[Signals, np.ndarray, str]:
    """Accept a :class:`Run` or a ``(Signals, force)`` pair; check it is fit-able."""
    if isinstance(data, Run):
        if len(data) < 50:
            raise FitError(f"{data.label}: too few samples to fit ({len(data)})")
        sig, force, label = Signals.from_run(data), np.asarray(data.force, float), data.label
    else:
        try:
            sig, force = data
        except (TypeError, ValueError):
            raise FitError("fit input must be a Run or a (Signals, force) pair") from None
        force = np.asarray(force, dtype=np.float64)
        label = ""
        if force.shape != sig.t.shape:
            raise FitError(f"force has {force.shape[0]} samples, position {sig.t.shape[0]}")
    if not np.all(np.isfinite(force)) or not np.all(np.isfinite(sig.x)):
        raise FitError(f"{label or 'input'}: NaN or infinite samples")
    if np.ptp(sig.x) <= 1e-9:
        raise FitError(f"{label or 'input'}: channel 'position' is constant (no stroke to fit)")
    return sig, force, label


def burn_in_signals(sig: Signals) -> tuple[Signals, int]:
    """Signals with one excitation period (or the whole run) prepended; returns (sig, P).

    Rate-independent laws depend on the path only, so replaying the first cycle before the
    run puts the hysteretic state on its periodic orbit at the first sample.
    """
    n = sig.t.shape[0]
    dt = float(np.median(np.diff(sig.t)))
    if sig.frequency_Hz and sig.frequency_Hz > 0:
        P = int(round(1.0 / (sig.frequency_Hz * dt)))
        P = min(max(P, 2), n)
    else:
        P = n
    shift = sig.t[P - 1] - sig.t[0] + dt

    def cat(a: np.ndarray) -> np.ndarray:
        return np.concatenate([a[:P], a])

    aug = replace(sig, t=np.concatenate([sig.t[:P] - shift, sig.t]), x=cat(sig.x), v=cat(sig.v),
                  a=cat(sig.a), p=cat(sig.p), x_raw=cat(sig.x_raw))
    return aug, P


#: how a prediction of another run sets the start state h0 (see :func:`predict_free`)
INITIAL_STATES = ("estimate", "burn-in", "zero")
#: samples used to estimate the initial state (50 ms at 500 Hz)
INITIAL_WINDOW_S = 0.05


def record_params(model: ForceModel) -> tuple[str, ...]:
    """Parameters that belong to one record, not to the muscle: the start state h0 and the
    effects' ``nuisance_params`` (e.g. a sensor's drift rate).  A prediction of another run
    sets them to 0 (h0 then by ``initial``, see :func:`predict_free`)."""
    out = list(STATE_PARAMS)
    for e in model.effects:
        out += [n for n in getattr(e, "nuisance_params", ()) if n not in out]
    return tuple(out)


def tares(model: ForceModel) -> bool:
    """True when an effect of ``model`` says the record's force zero is unknown (``tare``)."""
    return any(bool(getattr(e, "tare", False)) for e in model.effects)


#: the note every prediction that tares the force carries (JSON warnings)
TARE_NOTE = ("force tared on each predicted run: the model has a drifting-zero effect "
             "(sensor-drift), so the record's force offset is unknown; a prediction of another "
             "run (initial='estimate') takes it from the run's first ~50 ms of MEASURED force "
             "(median error after a one-period burn-in of the hysteretic state), as the h0 "
             "estimate does; the drift rate is a per-run nuisance set to 0, and c0 is fitted per "
             "run in the joint fit (its per-run quadratic only sets the level before the tare)")


def predict_free(model: ForceModel, sig: Signals, theta: dict[str, float],
                 force: np.ndarray | None = None, initial: str = "estimate") -> np.ndarray:
    """Free-run force (N) of ``model`` on ``sig``; the start state h0 is set by ``initial``:

    * ``"estimate"`` (default when ``force`` is given): h0 from the first 50 ms of the
      measured force, h0 = median(F − F_model(h0 = 0)) over that window — the initial
      condition estimate of MATLAB ``compare``.  Only the state is taken from the data;
      every sample (the window included) is then predicted in free run from the position.
    * ``"burn-in"``: the first excitation period is replayed before the run, putting h on
      its periodic orbit (for records that start mid-cycle on a cycled muscle);
    * ``"zero"``: h0 = 0, a virgin state (a record that starts from rest).

    Record nuisance parameters of the effects (:func:`record_params`, e.g. a drift rate)
    are used as given in ``theta``: the campaign's pressure laws set them to 0
    (:meth:`pmalab.identify.campaign.CampaignFit.theta`).

    Tare: when the model has an effect with ``tare = True`` (sensor drift: the record's
    force zero is unknown) and ``initial="estimate"``, the run's force offset is estimated
    instead of h0 — it uses the first ~50 ms of *measured force* (``INITIAL_WINDOW_S``):
    the hysteretic state is put on its periodic orbit by the burn-in, and the offset is
    median(F − F_model) over that window, added to the whole prediction.  An offset and
    h0 cannot be told apart on so short a window; the offset persists, h0 fades.
    """
    th = dict(theta)
    for s in STATE_PARAMS:
        if s in th:
            th[s] = 0.0
    if initial == "estimate" and force is None:
        initial = "burn-in"
    if initial == "zero":
        return model.predict(sig, th)
    if initial == "burn-in":
        aug, P = burn_in_signals(sig)
        return model.predict(aug, th)[P:]
    if initial != "estimate":
        raise ValueError(f"initial must be one of {INITIAL_STATES}, not {initial!r}")
    dt = float(np.median(np.diff(sig.t)))
    m = max(1, min(sig.t.shape[0], int(round(INITIAL_WINDOW_S / dt))))
    if tares(model):
        # a drifting zero: the record's offset is unknown.  h goes on its periodic orbit
        # (burn-in) and the offset is the median error over the first window; the window
        # cannot tell an offset from a start state, but an offset persists while h0 fades.
        aug, P = burn_in_signals(sig)
        pred = model.predict(aug, th)[P:]
        return pred + float(np.median(np.asarray(force)[:m] - pred[:m]))
    pred0 = model.predict(sig, th)
    if "h0" not in th:
        return pred0
    th["h0"] = float(np.median(np.asarray(force)[:m] - pred0[:m]))
    return model.predict(sig, th)


def _lstsq(cols: Sequence[np.ndarray], y: np.ndarray) -> tuple[np.ndarray, float]:
    M = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(M, y, rcond=None)
    r = M @ coef - y
    return coef, float(r @ r)


def _grid_starts(model: ForceModel, sig: Signals, force: np.ndarray, ps: Params,
                 fixed: dict[str, float]) -> list[dict[str, float]]:
    """Stage 1 + 2: the best grid points with (k, c0, scale) solved linearly, best first."""
    law = model.law
    base = {p.name: p.value for p in ps}
    base.update({k: v for k, v in law.guess(sig.x, force, sig.v).items() if k in base})
    (k, c0), _ = _lstsq([sig.x, np.ones_like(sig.x)], force)  # stage 1: centreline
    base.update(k=float(k), c0=float(c0))
    scale = law.scale_param
    if scale is None or scale in fixed:
        return [base]
    scored = []
    for shape in law.shape_grid(float(np.ptp(sig.x))):
        th = dict(base)
        th.update({kk: v for kk, v in shape.items() if kk not in fixed})
        th.update({kk: v for kk, v in fixed.items()})
        for s in law.state_params:
            th[s] = 0.0
        if not law.scale_valid(th):
            continue
        # with the state at zero, h is positively homogeneous in the scale parameter:
        # h(c·s0) = h(0) + c·(h(s0) − h(0)) for c ≥ 0 (a negative factor would flip sgn(h)
        # against the direction terms), so each sign s0 = ±1 is solved separately
        h_off = law.h(sig.x, {**th, scale: 0.0})
        best = None
        for s0 in (1.0, -1.0):
            h_unit = law.h(sig.x, {**th, scale: s0}) - h_off
            if not np.all(np.isfinite(h_unit)) or np.ptp(h_unit) == 0:
                continue
            coef, sse = _lstsq([sig.x, np.ones_like(sig.x), h_unit], force - h_off)
            if coef[2] >= 0 and (best is None or sse < best[0]):
                best = (sse, coef, s0)
        if best is None:
            continue
        sse, coef, s0 = best
        th.update(k=float(coef[0]), c0=float(coef[1]), **{scale: float(coef[2] * s0)})
        scored.append((sse, th))
    scored.sort(key=lambda s: s[0])
    return [th for _, th in scored[:2]] or [base]


def _autocorr1(r: np.ndarray) -> float:
    r = r - r.mean()
    d = float(r @ r)
    return float(r[1:] @ r[:-1]) / d if d > 0 else 0.0


@dataclass
class _Problem:
    model: ForceModel
    sig: Signals
    force: np.ndarray
    ps: Params
    free: list[str]

    def __post_init__(self) -> None:
        self._cache: tuple[bytes, np.ndarray] | None = None

    def theta(self, vec: np.ndarray) -> dict[str, float]:
        th = self.ps.values()
        th.update(zip(self.free, (float(v) for v in vec)))
        return th

    def residual(self, vec: np.ndarray) -> np.ndarray:
        key = np.asarray(vec, dtype=float).tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        with np.errstate(all="ignore"):
            pred = self.model.predict(self.sig, self.theta(vec))
        r = pred - self.force
        if not np.all(np.isfinite(r)):
            r = np.nan_to_num(r, nan=1e9, posinf=1e9, neginf=-1e9)
        self._cache = (key, r)
        return r

    def jac(self, vec: np.ndarray) -> np.ndarray:
        """Forward-difference Jacobian; the linear parameters k, c0 analytically.

        ∂F/∂k is the (effect-transformed) drive position and ∂F/∂c0 = 1, which saves two
        model evaluations per Jacobian.
        """
        vec = np.asarray(vec, dtype=float)
        r0 = self.residual(vec)
        J = np.empty((r0.shape[0], vec.shape[0]))
        th = self.theta(vec)
        s = self.sig
        for e in self.model.effects:
            s = e.transform(s, th)
        eps = np.sqrt(np.finfo(float).eps)
        for j, name in enumerate(self.free):
            if name == "k":
                J[:, j] = s.x
            elif name == "c0":
                J[:, j] = 1.0
            else:
                h = eps * max(1.0, abs(vec[j]))
                lo, hi = self.ps[name].lo, self.ps[name].hi
                if vec[j] + h > hi:
                    h = -h
                if not (lo <= vec[j] + h <= hi):
                    h = -h
                v2 = vec.copy()
                v2[j] += h
                with np.errstate(all="ignore"):
                    pred = self.model.predict(self.sig, self.theta(v2))
                J[:, j] = (np.nan_to_num(pred - self.force, nan=1e9, posinf=1e9, neginf=-1e9) - r0) / h
        return J


#: least_squares tolerances (relative); 1e-8 changes parameters by < 0.1 σ vs 1e-10
TOL = 1e-8
#: refine the second-best grid start too when the best one ends with nrmse above this
SECOND_START_NRMSE = 0.05


def _refine(prob: _Problem, start: dict[str, float]) -> tuple[np.ndarray, object]:
    lo = np.array([prob.ps[n].lo for n in prob.free])
    hi = np.array([prob.ps[n].hi for n in prob.free])
    x0 = np.array([start[n] for n in prob.free], dtype=float)
    # strictly inside the bounds (trf requirement)
    span = np.where(np.isfinite(hi - lo), hi - lo, np.abs(x0) + 1.0)
    x0 = np.clip(x0, lo + 1e-9 * span, hi - 1e-9 * span)
    res = least_squares(prob.residual, x0, jac=prob.jac, bounds=(lo, hi), method="trf",
                        x_scale="jac", ftol=TOL, xtol=TOL, gtol=TOL,
                        max_nfev=100 * (len(x0) + 1))
    return res.x, res


def _refine_starts(prob: _Problem, starts: list[dict[str, float]]) -> tuple[np.ndarray, object]:
    """Refine the best start; try the next ones only if the fit stays poor."""
    best = None
    sd = float(np.std(prob.force)) or 1.0
    for st in starts:
        if best is not None:
            nrmse = float(np.sqrt(2.0 * best[1].cost / prob.force.shape[0])) / sd
            if nrmse <= SECOND_START_NRMSE:
                break
        xv, res = _refine(prob, st)
        if best is None or res.cost < best[1].cost:
            best = (xv, res)
    assert best is not None
    return best


def _uncertainty(prob: _Problem, res, warnings: list[str]) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(stderr, correlation, condition number, N_eff) from the Jacobian at the optimum."""
    J = np.asarray(res.jac, dtype=float)
    r = np.asarray(res.fun, dtype=float)
    N, p = J.shape
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms
    sv = np.linalg.svd(Js, compute_uv=False)
    cond = float((sv[0] / sv[-1]) ** 2) if sv[-1] > 0 else float("inf")
    JtJ_s = Js.T @ Js
    cov_s = np.linalg.pinv(JtJ_s, rcond=1e-15)
    s2 = float(r @ r) / max(N - p, 1)
    rho1 = min(max(_autocorr1(r), 0.0), 0.999)
    n_eff = max(N * (1.0 - rho1) / (1.0 + rho1), p + 1.0)
    cov = s2 * (N / n_eff) * cov_s / np.outer(norms, norms)
    var = np.diag(cov).copy()
    se = np.sqrt(np.where(var > 0, var, np.nan))
    d = np.sqrt(np.abs(np.diag(cov_s)))
    d[d == 0] = 1.0
    corr = cov_s / np.outer(d, d)
    corr = np.clip(corr, -1.0, 1.0)
    return se, corr, cond, n_eff


def _flag_pairs(names: list[str], corr: np.ndarray) -> list[tuple[str, str, float]]:
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if abs(corr[i, j]) > RHO_LIMIT:
                out.append((names[i], names[j], float(corr[i, j])))
    return out


# --------------------------------------------------------------------------- fit_run
def _fit_once(model: ForceModel, sig: Signals, force: np.ndarray, fixed: dict[str, float],
              init: dict[str, float]) -> tuple[Params, _Problem, object]:
    ps = model.params(sig, force)
    for name in list(fixed) + list(init):
        if name not in ps:
            raise FitError(f"unknown parameter '{name}' for model {model.name} "
                           f"(has: {', '.join(ps.names())})")
    for name, v in fixed.items():
        ps[name].value = float(v)
        ps[name].vary = False
    law_names = ["k", "c0"] + [lp.name for lp in model.law.params]
    if all(n in init or n in fixed for n in law_names):
        starts = [{**ps.values(), **init, **fixed}]
    else:
        base_model = ForceModel(model.law) if model.effects else model
        base_ps = base_model.params(sig, force)
        grid = _grid_starts(base_model, sig, force, base_ps,
                            {k: v for k, v in fixed.items() if k in base_ps})
        starts = [{**ps.values(), **g, **init, **fixed} for g in grid]
        if model.effects:
            # refine the base law alone first; effects then start on top of it
            bprob = _Problem(base_model, sig, force, base_ps, [])
            for name, v in fixed.items():
                if name in base_ps:
                    base_ps[name].value, base_ps[name].vary = float(v), False
            bprob.free = [p.name for p in base_ps if p.vary]
            xb, _ = _refine_starts(bprob, [{**base_ps.values(), **st} for st in grid])
            base_th = bprob.theta(xb)
            starts = [{**ps.values(), **base_th, **init, **fixed}]
    for name, v in starts[0].items():
        if name in ps:
            ps[name].value = float(v)
    prob = _Problem(model, sig, force, ps, [p.name for p in ps if p.vary])
    if not prob.free:
        raise FitError(f"every parameter of {model.name} is fixed: nothing to fit")
    xv, res = _refine_starts(prob, starts)
    for name, v in prob.theta(xv).items():
        ps[name].value = v
    return ps, prob, res


def fit_run(
    data: Run | tuple[Signals, np.ndarray],
    model: ForceModel | str,
    *,
    fixed: dict[str, float | None] | None = None,
    init: dict[str, float] | None = None,
    free: Sequence[str] = (),
    auto_fix: bool = True,
) -> FitResult:
    """Fit ``model`` to one run by free-run prediction error (see the module docstring).

    ``data`` is a :class:`~pmalab.runfile.Run` (canonical units) or ``(Signals, force_N)``.
    ``fixed`` maps parameter names to values held constant (``None``: hold at the start
    value); the law's ``default_fixed`` apply unless named in ``free``.
    ``init`` gives start values (skips the start grid when every base-law parameter is
    given).  ``auto_fix`` lets the fit fix a collinear parameter (the law's ``collinear_fixes``)
    when that costs < 1 % of nrmse; the warning records it.

    BLAS runs single-threaded inside (tall-skinny 20 000 × 6 products are slower threaded,
    and batches parallelise across runs instead).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _fit_run(data, model, fixed=fixed, init=init, free=free, auto_fix=auto_fix)


def _fit_run(
    data: Run | tuple[Signals, np.ndarray],
    model: ForceModel | str,
    *,
    fixed: dict[str, float | None] | None,
    init: dict[str, float] | None,
    free: Sequence[str],
    auto_fix: bool,
) -> FitResult:
    model = ForceModel(model) if isinstance(model, str) else model
    sig, force, label = as_signals_and_force(data)
    init = dict(init or {})
    defaults = {k: v for k, v in model.law.default_fixed.items() if k not in free}
    fix: dict[str, float] = dict(defaults)
    warnings: list[str] = []
    ps0 = model.params(sig, force)
    for k, v in (fixed or {}).items():
        if k not in ps0:
            raise FitError(f"unknown parameter '{k}' for model {model.name} "
                           f"(has: {', '.join(ps0.names())})")
        fix[k] = float(init.get(k, ps0[k].value)) if v is None else float(v)

    ps, prob, res = _fit_once(model, sig, force, fix, init)
    se, corr, cond, n_eff = _uncertainty(prob, res, warnings)
    pred = prob.residual(res.x) + force
    met = metrics(force, pred, sig.x)

    if auto_fix:
        pairs = _flag_pairs(prob.free, _centred_corr(corr, prob.free, se, float(np.mean(sig.x))))
        flagged = {a for a, b, _ in pairs} | {b for a, b, _ in pairs}
        for name, value in model.law.collinear_fixes:
            if name not in flagged or name in fix:
                continue
            partners = ", ".join(f"rho({a},{b})={r:+.3f}" for a, b, r in pairs if name in (a, b))
            fix2 = {**fix, name: value}
            ps2, prob2, res2 = _fit_once(model, sig, force, fix2, init)
            pred2 = prob2.residual(res2.x) + force
            met2 = metrics(force, pred2, sig.x)
            if met2["nrmse"] <= met["nrmse"] * (1.0 + FIX_TOLERANCE) + 1e-12:
                warnings.append(
                    f"{partners}: not identifiable on this run; fixed {name} = {value:g} "
                    f"(nrmse {met['nrmse']:.4f} -> {met2['nrmse']:.4f})")
                fix, ps, prob, res, pred, met = fix2, ps2, prob2, res2, pred2, met2
                se, corr, cond, n_eff = _uncertainty(prob, res, warnings)
            else:
                warnings.append(
                    f"{partners}: kept {name} free — fixing it at {value:g} raised nrmse "
                    f"{met['nrmse']:.4f} -> {met2['nrmse']:.4f}; their stderrs are large")

    done = {n for w in warnings for n in prob.free if f"fixed {n} =" in w}
    notes: list[str] = []
    xm = float(np.mean(sig.x))
    corr_c = _centred_corr(corr, prob.free, se, xm)
    for a, b, r in _flag_pairs(prob.free, corr):
        rc = corr_c[prob.free.index(a), prob.free.index(b)]
        if "c0" in (a, b) and abs(rc) <= RHO_LIMIT:
            # c0 is the tension extrapolated to x = 0, away from the data; with the offset
            # taken at the data's centre (c0 + k·mean x) the pair is not collinear, so this
            # is a parametrisation artefact, not an identifiability problem
            notes.append(f"rho({a},{b})={r:+.3f} only because c0 is extrapolated to x = 0 "
                         f"(data centred at x = {xm:.3g} mm; centred offset: rho={rc:+.3f})")
            continue
        if a not in done and b not in done:
            warnings.append(f"rho({a},{b})={r:+.3f}: |rho| > {RHO_LIMIT}; these parameters trade off")
    if cond > COND_LIMIT:
        warnings.append(f"condition number of scaled J^T J is {cond:.3g} (> {COND_LIMIT:.0e}): "
                        "some parameter combination is poorly determined")
    for i, name in enumerate(prob.free):
        p = ps[name]
        p.stderr = None if not np.isfinite(se[i]) else float(se[i])
        span = p.hi - p.lo
        if np.isfinite(span) and min(p.value - p.lo, p.hi - p.value) <= 1e-6 * span:
            warnings.append(f"{name} = {p.value:.4g} is at its bound [{p.lo:g}, {p.hi:g}]")
    for p in ps:
        if not p.vary:
            p.stderr = None
    if not res.success:
        warnings.append(f"optimizer did not converge: {res.message}")
    ld = loop_direction(force, sig.x)
    if ld < 0:
        warnings.append(f"measured loop runs anti-physically (tension {abs(ld):.3g} N lower while "
                        "stretching): check the position sign / channel mapping")

    N = force.shape[0]
    p_free = len(prob.free)
    sse = float(np.sum((pred - force) ** 2))
    ll = N * math.log(max(sse / N, 1e-300))
    return FitResult(
        model=model, params=ps, names=list(prob.free), correlation=corr, warnings=warnings,
        fixed=[p.name for p in ps if not p.vary], rmse=met["rmse"], nrmse=met["nrmse"],
        fit_percent=met["fit_percent"], cost=float(res.cost), n_free=p_free, n_samples=N,
        n_eff=float(n_eff), aic=ll + 2 * p_free, bic=ll + p_free * math.log(N),
        condition_number=cond, metrics=met, label=label, notes=notes,
    )


def _centred_corr(corr: np.ndarray, names: list[str], se: np.ndarray, xm: float) -> np.ndarray:
    """Correlation matrix with c0 replaced by the centred offset c0 + k·xm (same order)."""
    if "k" not in names or "c0" not in names:
        return corr
    s = np.where(np.isfinite(se), se, 0.0)
    cov = corr * np.outer(s, s)
    T = np.eye(len(names))
    T[names.index("c0"), names.index("k")] = xm
    cov_c = T @ cov @ T.T
    d = np.sqrt(np.abs(np.diag(cov_c)))
    d[d == 0] = 1.0
    return np.clip(cov_c / np.outer(d, d), -1.0, 1.0)


def default_fixed_notes(model: ForceModel, free: Sequence[str] = ()) -> list[str]:
    """Human-readable notes on the law's default fixes (for campaign-level warnings)."""
    return [why for k, why in model.law.default_fixed_why.items() if k not in free]


def fit_campaign(runs, model, **kwargs):
    """See :func:`pmalab.identify.campaign.fit_campaign` (re-exported here for convenience)."""
    from pmalab.identify.campaign import fit_campaign as _fc

    return _fc(runs, model, **kwargs)


def predict_run(campaign_fit, run):
    """See :func:`pmalab.identify.campaign.predict_run`."""
    from pmalab.identify.campaign import predict_run as _pr

    return _pr(campaign_fit, run)
