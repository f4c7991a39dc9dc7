"""Fitting one run: two-stage start, refinement through the one estimation problem.

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
3. **Joint refinement** of every free parameter: the run is a one-record instance of
   :class:`~pmalab.identify.estimation.problem.Problem` (every parameter order 0 in
   pressure, h0 the per-run block) solved by :func:`~pmalab.identify.estimation.solver.solve`.
   Effects start from their own data-sized defaults on top of the fitted base law; an
   effect's multi-modal parameter (``Effect.multistart``) is also started from each of its
   grid values and the best optimum kept.

Uncertainty: :func:`~pmalab.identify.estimation.solver.uncertainty` (s²·(JᵀJ)⁻¹ inflated by
N/N_eff, the AR(1) effective sample size); ``stderr_method`` says so in every result.

Identifiability: pairs with |ρ| > 0.95 and a condition number of the column-scaled JᵀJ
above 1e8 are reported in ``warnings``.  Defaults that remove known degeneracies:

the law's ``default_fixed`` (Bouc-Wen n = 1, Duhem a = 0; each law's file says why) and its
``collinear_fixes``: if a listed parameter is collinear (|ρ| > 0.95) with another on the run
(Bouc-Wen β–γ: Brunot et al. 2017 report 0.998) we refit with it fixed and keep that fix
when the nrmse rises by less than 1 % relative — the warning records both numbers.

h0 (the hysteretic force at the first sample) is fitted: the run's own start state.  For
predicting *another* run see :mod:`pmalab.identify.estimation.records`.
Nothing is excluded: every sample of the run enters the fit.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeVar

import numpy as np

if TYPE_CHECKING:
    from scipy.optimize import OptimizeResult

from pmalab.errors import PmalabError
from pmalab.identify.estimation.problem import Problem, Record
from pmalab.identify.estimation.records import predict_record
from pmalab.identify.estimation.solver import STDERR_METHOD, one_blas_thread, solve, uncertainty
from pmalab.identify.messages import Message, detail, note, warn
from pmalab.identify.metrics import (
    information_criteria,
    loop_direction,
    measured_parts,
    metrics,
)
from pmalab.identify.model import ForceModel
from pmalab.identify.params import Param, Params
from pmalab.identify.signals import Signals, kept_derived
from pmalab.runfile import Run

RHO_LIMIT = 0.95
COND_LIMIT = 1e8
FIX_TOLERANCE = 0.01  # accept an identifiability fix if nrmse rises by < 1 % (relative)


class FitError(PmalabError):
    """A fit cannot be done on this input (too short, constant position...)."""


def check_fix(model: ForceModel, p: Param, value: float | None) -> None:
    """Refuse a fixed value (``--fix NAME=VALUE``) that is not finite or lies outside the
    parameter's bounds (the range the fitter itself may explore): one line naming it."""
    if value is None:
        return
    v = float(value)
    if not math.isfinite(v):
        raise FitError(f"--fix {p.name}={value}: the value must be a finite number")
    if not (p.lo <= v <= p.hi):
        unit = f" {p.unit}" if p.unit not in ("", "-") else ""
        raise FitError(
            f"--fix {p.name}={v:g}: outside the range of {model.name}'s '{p.name}' "
            f"[{p.lo:g}, {p.hi:g}]{unit}"
        )


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

    def predict(
        self, sig: Signals | Run, *, initial: str | None = None, force: np.ndarray | None = None
    ) -> np.ndarray:
        """Force (N) along ``sig``.  ``initial=None``: the fitted h0 (the fitted run itself);
        otherwise the record parameters are set as
        :func:`~pmalab.identify.estimation.records.predict_record` describes (another run)."""
        if isinstance(sig, Run):
            force = sig.force if force is None else force
            sig = Signals.from_run(sig)
        if initial is None:
            return self.model.predict(sig, self.values)
        return predict_record(self.model, sig, self.values, force=force, initial=initial)

    def summary(self) -> str:
        lines = [
            f"{self.model.name}: fit {self.fit_percent:.2f} %  rmse {self.rmse:.3g} N  "
            f"nrmse {self.nrmse:.4f}"
        ]
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


def _lstsq(cols: Sequence[np.ndarray], y: np.ndarray) -> tuple[np.ndarray, float]:
    M = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(M, y, rcond=None)
    r = M @ coef - y
    return coef, float(r @ r)


def _grid_starts(
    model: ForceModel, sig: Signals, force: np.ndarray, ps: Params, fixed: dict[str, float]
) -> list[dict[str, float]]:
    """Stage 1 + 2: the best grid points with (k, c0, scale) solved linearly, best first."""
    law = model.law
    sig = law.drive_signals(sig)  # the path the law is driven by (and k·x with it)
    base = {p.name: p.value for p in ps}
    g = law.guess(sig.x, force, sig.v, fixed=fixed)
    base.update({k: v for k, v in g.items() if k in base})
    if "k" not in g or "c0" not in g:  # stage 1: centreline (a law's guess may fit k, c0 too)
        (k, c0), _ = _lstsq([sig.x, np.ones_like(sig.x)], force)
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


def _problem(
    model: ForceModel, sig: Signals, force: np.ndarray, ps: Params, label: str = ""
) -> Problem:
    """The run as a one-record estimation problem: every free parameter order 0 in
    pressure, the law's start state as the per-run block."""
    free = [p.name for p in ps if p.vary]
    shared = [n for n in free if n not in model.state_params]
    return Problem(
        model,
        [Record(label, sig.p_nom, sig, force)],
        free=shared,
        degree=dict.fromkeys(shared, 0),
        constants={p.name: p.value for p in ps if not p.vary},
        bounds={p.name: (p.lo, p.hi) for p in ps},
        run_params=[n for n in free if n in model.state_params],
    )


def _names(prob: Problem) -> list[str]:
    """Free parameter names in solution-vector order."""
    return [*prob.free, *prob.run_params]


def _theta(prob: Problem, z: np.ndarray) -> dict[str, float]:
    return prob.thetas(z)[0]


#: samples per excitation cycle a single-run fit keeps (loops need ~100; margin ×2)
SAMPLES_PER_CYCLE = 200
#: ... and at least this many samples of a run (short runs are fitted whole)
MIN_FIT_SAMPLES = 2000


def fit_stride(sig: Signals) -> int:
    """Decimation stride of a single-run fit (1 when the excitation frequency is unknown)."""
    f = sig.frequency_Hz
    n = sig.t.shape[0]
    if not f or f <= 0 or n <= MIN_FIT_SAMPLES:
        return 1
    fs = 1.0 / float(np.median(np.diff(sig.t)))
    return max(1, min(int(fs // (SAMPLES_PER_CYCLE * f)), n // MIN_FIT_SAMPLES))


#: least_squares tolerances (relative); held-out nrmse agrees to 4 digits with 1e-8 at a
#: third of the cost
TOL = 1e-6
#: function evaluations allowed per free parameter (+1) in one refinement: a base law
#: converges in 10–40; a model with many collinear effect parameters (asymmetric Bouc-Wen,
#: 10 free) crawls along a flat valley for hundreds without changing its prediction (the
#: held-out nrmse moved by < 0.5 % between 132 and 330 evaluations), and the campaign's
#: joint fit refines the laws on all runs afterwards anyway
NFEV_PER_PARAM = 12
#: refine the second-best grid start too when the best one ends with nrmse above this
SECOND_START_NRMSE = 0.05


def _refine(prob: Problem, start: dict[str, float], max_nfev: int | None = None):
    z0 = prob.z_from({n: [start[n]] for n in prob.free}, {n: [start[n]] for n in prob.run_params})
    lo, hi = prob.z_bounds()
    res = solve(
        prob.residual,
        prob.jac,
        z0,
        lo,
        hi,
        tol=TOL,
        max_nfev=max_nfev or NFEV_PER_PARAM * (prob.n_var + 1),
    )
    return res.x, res


def _refine_starts(
    prob: Problem, starts: list[dict[str, float]]
) -> tuple[np.ndarray, OptimizeResult]:
    """Refine the best start; try the next ones only if the fit stays poor; then the
    multi-start grid of any multi-modal effect parameter (``Effect.multistart``)."""
    best = None
    rec = prob.records[0]
    for st in starts:
        if best is not None:
            nrmse = float(np.sqrt(2.0 * best[1].cost / rec.n)) / rec.sd
            if nrmse <= SECOND_START_NRMSE:
                break
        xv, res = _refine(prob, st)
        if best is None or res.cost < best[1].cost:
            best = (xv, res)
    assert best is not None
    grid = {n: v for n, v in prob.model.multistart.items() if n in prob.free and len(v)}
    if grid:
        th_best = _theta(prob, best[0])
        short = max(10, NFEV_PER_PARAM * (prob.n_var + 1) // 4)
        # every grid value, not only the nearest on each side of the descent's τ: that
        # halved the grid's cost (the tries from one side mostly meet) but lost real lags —
        # on 2 and 4 Hz triangles with lags of ±40–90 ms (48 fits), 13 missed by > 5 ms
        # against 5 from every value, the 8 more at 4 Hz (a farther start reached a minimum
        # the nearer did not); a screen by the cost at each τ with the rest held picks the
        # nearest anyway (on 692 of 692 sides in four simulated campaigns)
        tries = [
            _refine(prob, {**th_best, n: float(v)}, short) for n, vals in grid.items() for v in vals
        ]
        cand = min(tries, key=lambda t: t[1].cost)
        if cand[1].cost < best[1].cost:
            polished = _refine(prob, _theta(prob, cand[0]))
            best = polished if polished[1].cost <= cand[1].cost else cand
    return best


def _uncertainty(prob: Problem, res) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(stderr, correlation, condition number, N_eff) at the optimum."""
    u = uncertainty(res.jac, res.fun, prob.rows)
    return u.stderr, u.correlation, u.condition, u.n_eff


def _flag_pairs(names: list[str], corr: np.ndarray) -> list[tuple[str, str, float]]:
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if abs(corr[i, j]) > RHO_LIMIT:
                out.append((names[i], names[j], float(corr[i, j])))
    return out


# --------------------------------------------------------------------------- fit_run
#: base-law fits by (record, law, fixes): every model with effects starts from the base law
#: refined alone on the same record, so a diagnosis that identifies many candidate models
#: on one campaign (and an identify of the base model before) computes it once per run
_BASE_FITS: dict[tuple, dict[str, float]] = {}
_BASE_FITS_MAX = 512
_R = TypeVar("_R")


def _base_key(model: ForceModel, sig: Signals, force: np.ndarray, fixed: dict[str, float]) -> tuple:
    h = hashlib.blake2b(digest_size=16)
    for a in (sig.t, sig.x, force):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return (h.digest(), model.law.cache_key(), tuple(sorted(fixed.items())))


def _remember(key: tuple, theta: dict[str, float]) -> None:
    if len(_BASE_FITS) >= _BASE_FITS_MAX:
        _BASE_FITS.pop(next(iter(_BASE_FITS)))
    _BASE_FITS[key] = dict(theta)


def remember_base_fits(entries: dict) -> None:
    """Keep base fits another process made (:func:`with_new_base_fits`), in their order;
    those already kept stay."""
    for k, v in entries.items():
        if k not in _BASE_FITS:
            _remember(k, v)


def with_new_base_fits(fn: Callable[[], _R]) -> tuple[_R, dict]:
    """``fn()``, and the base fits it remembered: what a worker or forked child hands back
    so another process need not compute them again (the same numbers whoever made them)."""
    before = set(_BASE_FITS)
    out = fn()
    return out, {k: v for k, v in _BASE_FITS.items() if k not in before}


def _fit_once(
    model: ForceModel,
    sig: Signals,
    force: np.ndarray,
    fixed: dict[str, float],
    init: dict[str, float],
) -> tuple[Params, Problem, OptimizeResult]:
    ps = model.params(sig, force)
    for name in list(fixed) + list(init):
        if name not in ps:
            raise FitError(
                f"unknown parameter '{name}' for model {model.name} (has: {', '.join(ps.names())})"
            )
    for name, v in fixed.items():
        check_fix(model, ps[name], v)
        ps[name].value = float(v)
        ps[name].vary = False
    law_names = ["k", "c0"] + [lp.name for lp in model.law.params]
    if all(n in init or n in fixed for n in law_names):
        starts = [{**ps.values(), **init, **fixed}]
    else:
        base_model = ForceModel(model.law) if model.effects else model
        base_ps = base_model.params(sig, force)

        def grid() -> list[dict[str, float]]:
            return _grid_starts(
                base_model, sig, force, base_ps, {k: v for k, v in fixed.items() if k in base_ps}
            )

        if not model.effects:
            starts = [{**ps.values(), **g, **init, **fixed} for g in grid()]
        else:
            # refine the base law alone first; effects then start on top of it
            fixed_base = {k: v for k, v in fixed.items() if k in base_ps}
            key = _base_key(model, sig, force, fixed_base)
            base_th = _BASE_FITS.get(key)
            if base_th is None:
                for name, v in fixed_base.items():
                    base_ps[name].value, base_ps[name].vary = float(v), False
                bprob = _problem(base_model, sig, force, base_ps)
                xb, _ = _refine_starts(bprob, [{**base_ps.values(), **st} for st in grid()])
                base_th = _theta(bprob, xb)
                _remember(key, base_th)
            starts = [{**ps.values(), **base_th, **init, **fixed}]
    for name, v in starts[0].items():
        if name in ps:
            ps[name].value = float(v)
    if not any(p.vary for p in ps):
        raise FitError(f"every parameter of {model.name} is fixed: nothing to fit")
    prob = _problem(model, sig, force, ps)
    xv, res = _refine_starts(prob, starts)
    for name, v in _theta(prob, xv).items():
        ps[name].value = v
    if not model.effects and not init and model.predicts_by_parts:
        # the same base fit a model with effects on this record would start from (not a
        # subclass's own prediction: keyed by the law, it would be another model's start)
        _remember(_base_key(model, sig, force, fixed), _theta(prob, xv))
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
    with one_blas_thread():
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
    warnings: list[str] = []
    ps0 = model.params(sig, force)
    fix: dict[str, float] = {
        k: (ps0[k].value if v is None else float(v))
        for k, v in model.held_fixed().items()
        if k not in free and k in ps0
    }
    for k, v in (fixed or {}).items():
        if k not in ps0:
            raise FitError(
                f"unknown parameter '{k}' for model {model.name} (has: {', '.join(ps0.names())})"
            )
        check_fix(model, ps0[k], v)
        fix[k] = float(init.get(k, ps0[k].value)) if v is None else float(v)

    # fit on ≤ SAMPLES_PER_CYCLE samples per excitation cycle (the laws are rate independent
    # and the drive is the full-rate filtered position, so a 500 Hz record at 0.1 Hz carries
    # 25× more samples than its loop needs); every metric is computed at the full rate
    stride = fit_stride(sig)
    sig_f, force_f = sig.every(stride), force[::stride]

    def full(prob_: Problem, res_) -> tuple[np.ndarray, dict]:
        with np.errstate(all="ignore"):
            p_ = model.predict(sig, _theta(prob_, res_.x))
        parts = kept_derived(sig, force, "measured", lambda: measured_parts(force, sig.x))
        return p_, metrics(force, p_, sig.x, parts)

    ps, prob, res = _fit_once(model, sig_f, force_f, fix, init)
    se, corr, cond, n_eff = _uncertainty(prob, res)
    names = _names(prob)
    pred, met = full(prob, res)

    auto_fixed: set[str] = set()  # what this fit fixed itself (kept as data, not parsed back)
    if auto_fix:
        pairs = _flag_pairs(names, _centred_corr(corr, names, se, float(np.mean(sig.x))))
        flagged = {a for a, b, _ in pairs} | {b for a, b, _ in pairs}
        for name, value in model.law.collinear_fixes:
            if name not in flagged or name in fix:
                continue
            partners = ", ".join(f"rho({a},{b})={r:+.3f}" for a, b, r in pairs if name in (a, b))
            fix2 = {**fix, name: value}
            ps2, prob2, res2 = _fit_once(model, sig_f, force_f, fix2, init)
            pred2, met2 = full(prob2, res2)
            if met2["nrmse"] <= met["nrmse"] * (1.0 + FIX_TOLERANCE) + 1e-12:
                warnings.append(
                    detail(
                        "auto-fix",
                        f"{partners}: not identifiable on this run; fixed {name} = {value:g} "
                        f"(nrmse {met['nrmse']:.4f} -> {met2['nrmse']:.4f})",
                        name=name,
                        value=value,
                    )
                )
                fix, ps, prob, res, pred, met = fix2, ps2, prob2, res2, pred2, met2
                auto_fixed.add(name)
                se, corr, cond, n_eff = _uncertainty(prob, res)
                names = _names(prob)
            else:
                warnings.append(
                    f"{partners}: kept {name} free — fixing it at {value:g} raised nrmse "
                    f"{met['nrmse']:.4f} -> {met2['nrmse']:.4f}; their stderrs are large"
                )

    done = {n for n in auto_fixed if n in names}
    notes: list[str] = []
    xm = float(np.mean(sig.x))
    corr_c = _centred_corr(corr, names, se, xm)
    for a, b, r in _flag_pairs(names, corr):
        rc = corr_c[names.index(a), names.index(b)]
        if "c0" in (a, b) and abs(rc) <= RHO_LIMIT:
            # c0 is the tension extrapolated to x = 0, away from the data; with the offset
            # taken at the data's centre (c0 + k·mean x) the pair is not collinear, so this
            # is a parametrisation artefact, not an identifiability problem
            notes.append(
                detail(
                    "c0-extrapolated",
                    f"rho({a},{b})={r:+.3f} only because c0 is extrapolated to x = 0 "
                    f"(data centred at x = {xm:.3g} mm; centred offset: "
                    f"rho={rc:+.3f})",
                    a=a,
                    b=b,
                    rho=r,
                )
            )
            continue
        if a not in done and b not in done:
            warnings.append(
                warn(
                    "collinear",
                    f"rho({a},{b})={r:+.3f}: |rho| > {RHO_LIMIT}; these parameters trade off",
                    a=a,
                    b=b,
                    rho=r,
                    limit=RHO_LIMIT,
                )
            )
    if cond > COND_LIMIT:
        warnings.append(
            f"condition number of scaled J^T J is {cond:.3g} (> {COND_LIMIT:.0e}): "
            "some parameter combination is poorly determined"
        )
    for i, name in enumerate(names):
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
    ld = kept_derived(sig, force, "loop direction", lambda: loop_direction(force, sig.x))
    if ld < 0:
        warnings.append(
            f"measured loop runs anti-physically (tension {abs(ld):.3g} N lower while "
            "stretching): check the position sign / channel mapping"
        )

    N = force.shape[0]
    p_free = len(names)
    sse = float(np.sum((pred - force) ** 2))
    aic, bic = information_criteria(sse, N, p_free, n_eff)
    return FitResult(
        model=model,
        params=ps,
        names=list(names),
        correlation=corr,
        warnings=warnings,
        fixed=[p.name for p in ps if not p.vary],
        rmse=met["rmse"],
        nrmse=met["nrmse"],
        fit_percent=met["fit_percent"],
        cost=float(res.cost),
        n_free=p_free,
        n_samples=N,
        n_eff=float(n_eff),
        aic=aic,
        bic=bic,
        condition_number=cond,
        metrics=met,
        label=label,
        notes=notes,
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


def default_fixed_notes(model: ForceModel, free: Sequence[str] = ()) -> list[Message]:
    """Human-readable notes on the law's default fixes (for campaign-level warnings)."""
    return [
        note("default-fix", why, name=k, value=model.law.default_fixed.get(k))
        for k, why in model.law.default_fixed_why.items()
        if k not in free
    ]
