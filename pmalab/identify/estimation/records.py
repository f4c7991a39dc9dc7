"""The one record policy: how a run's own parameters are set when a model predicts it.

A *record parameter* belongs to one recording, not to the muscle: the law's start state h0
and the effects' ``nuisance_params`` (a load cell's drift rate during that run), plus the
record's force zero c0 — in the fit only for a model with a drifting-zero effect
(``Effect.tare``), in every *prediction* of another record (``RECORD_OFFSET``: the same
per-record freedom for every model, so a record's offset is evidence for no effect).  Every fit
gives them one value per run (:mod:`.problem`, per-run blocks).  When a model predicts a run
it was not fitted on (validation, diagnosis, reports), the muscle parameters come from the
pressure laws and the record parameters are set by ``initial``:

* ``"estimate"`` (default; MATLAB ``compare``'s initial-condition estimate, made
  *forward in time*): the record parameters are fitted by least squares on the *early part*
  of the predicted record (:func:`calibration_samples`: its first whole excitation cycles,
  about a third of it) with every muscle parameter held — a start from the first 50 ms
  (h0 = median(F − F_model) there), then a few Gauss–Newton steps — and the model then
  predicts the whole record; its error is scored on the rest (:func:`scored_from`).
  A record parameter must therefore *predict* the rest of its record, not absorb it: a drift
  rate fitted on the first cycle extrapolates a real linear drift, but makes a decaying
  softening or a misfit of the loop's shape worse, and every model — the null as much as a
  candidate with record nuisances — is scored on the same samples.  An elasto-slide law
  (Maxwell-slip, Prandtl-Ishlinskii) whose record's early part leaves the range the rest
  covers (a ramp-in's overshoot) then refits its force zero on the early samples within
  that range, h0 held (:func:`within_range`): its one-number start state cannot say what
  the excursion left in its large elements.  Without the measured force: ``"burn-in"``.
* ``"burn-in"``: the first excitation period is replayed before the run, putting h on its
  periodic orbit (record parameters other than h0 at 0);
* ``"zero"``: every record parameter 0 (a virgin state, no drift).

Identification's validation, diagnosis's scoring and the reports all predict through
:func:`predict_record`, so the number a user reads is the same wherever it is shown.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from pmalab.identify.estimation.problem import Problem, Record
from pmalab.identify.estimation.solver import solve
from pmalab.identify.laws._slide import START_BRANCH
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals

#: how a prediction of another run sets its record parameters
INITIAL_STATES = ("estimate", "burn-in", "zero")
#: window used for the first estimate of the start state (s)
INITIAL_WINDOW_S = 0.05
#: an element law's start state moves to the other branch only when that fits the record's
#: early part better by more than this (relative rms): the choice never hinges on round-off
BRANCH_GAIN = 0.02
#: Gauss–Newton evaluations for the record parameters of one predicted run
RECORD_NFEV = 12
#: share of a predicted record (in whole excitation cycles, at least one) on which its
#: record parameters are estimated under ``initial="estimate"``; the rest is scored
CALIBRATION_FRACTION = 1.0 / 3.0

#: the least share of a predicted record's early part that its force zero is refitted on
#: when an elasto-slide law's record leaves the range it then cycles over
#: (:func:`within_range`); an early part that leaves less keeps its first estimate
WITHIN_RANGE_SHARE = 0.25

#: the note every prediction with a drifting-zero effect carries (JSON warnings)
TARE_NOTE = (
    "record zero estimated on each predicted run: the model has a drifting-zero effect "
    "(sensor-drift), so each record's force offset (c0) and drift rate are record "
    "parameters — fitted per run in identification and estimated on each predicted "
    "run (initial='estimate') with every muscle parameter held"
)


#: every model's prediction of another record estimates that record's force zero c0 on its
#: early part (the same per-record freedom for a null model and for a candidate with a
#: drifting zero: a record's offset is then no evidence for any effect)
RECORD_OFFSET = True


def record_names(model: ForceModel) -> tuple[str, ...]:
    """The record parameters of ``model`` (see the module docstring)."""
    out = list(model.record_params)
    if (model.tares or RECORD_OFFSET) and "c0" not in out:
        out.append("c0")
    return tuple(out)


def calibration_samples(sig: Signals) -> int:
    """Samples of the early part of a record on which ``initial="estimate"`` fits its record
    parameters (:func:`calibration_count` of the record's time stamps and frequency)."""
    return calibration_count(sig.t, sig.frequency_Hz)


def calibration_count(t: np.ndarray, frequency_Hz: float | None) -> int:
    """round(cycles × ``CALIBRATION_FRACTION``) whole excitation cycles, at least one, at
    most half the record (a record of fewer than two cycles, or of unknown frequency: its
    first third), for time stamps ``t`` (s) and the excitation ``frequency_Hz``."""
    n = int(np.shape(t)[0])
    if n < 6:
        return max(1, n // 2)
    m = int(round(n * CALIBRATION_FRACTION))
    f = frequency_Hz
    dt = float(np.median(np.diff(t)))
    if f and f > 0 and dt > 0:
        per = int(round(1.0 / (f * dt)))
        cycles = n // per if per > 0 else 0
        if cycles >= 2:
            m = per * max(1, int(round(cycles * CALIBRATION_FRACTION)))
    return int(min(max(m, 3), n // 2))


def scored_from(sig: Signals, initial: str = "estimate") -> int:
    """First sample of a predicted record that its error is scored on: after the early part
    (:func:`calibration_samples`) under ``initial="estimate"``, else 0 (nothing of the
    record was fitted)."""
    return calibration_samples(sig) if initial == "estimate" else 0


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

    aug = replace(
        sig,
        t=np.concatenate([sig.t[:P] - shift, sig.t]),
        x=cat(sig.x),
        v=cat(sig.v),
        a=cat(sig.a),
        p=cat(sig.p),
        x_raw=cat(sig.x_raw),
        x_slide=None if sig.x_slide is None else cat(sig.x_slide),
        t_ref=sig.reference_time,
    )
    return aug, P


def fit_record_params(
    prob: Problem,
    z: np.ndarray,
    max_nfev: int = RECORD_NFEV,
    prior: Mapping[str, tuple[float, float]] | None = None,
    rows_kept: np.ndarray | None = None,
) -> np.ndarray:
    """z with every run's record parameters fitted, the shared parameters held.

    Start: each run's h0 from the first ``INITIAL_WINDOW_S`` (median of F − F_model with
    h0 = 0; other record parameters keep their values in ``z``); then a few Gauss–Newton
    steps on the record parameters alone (never worse than the start).  The one record
    estimate of the engine: the joint fit's start states and every predicted record use it.
    ``rows_kept``: the residual rows (samples of a one-record problem) the steps fit; None:
    all.
    """
    z = np.array(z, dtype=float)
    if not prob.run_params:
        return z
    k = prob.n_coef
    lo, hi = prob.z_bounds()
    if "h0" in prob.run_params:
        blk = prob.block(prob.run_params.index("h0"))
        z[blk] = 0.0
        for i, th in enumerate(prob.thetas(z)):
            r = prob.records[i]
            with np.errstate(all="ignore"):
                pred = prob.model.predict(r.sig, th)
            dt = float(np.median(np.diff(r.sig.t)))
            m = max(1, min(r.n, int(round(INITIAL_WINDOW_S / dt))))
            est = float(np.median(r.force[:m] - pred[:m]))
            z[blk.start + i] = est if np.isfinite(est) else 0.0
    z[k:] = np.clip(z[k:], lo[k:], hi[k:])

    # a Gaussian prior on record nuisances (one record: Problem with R = 1): extra residual
    # rows σ_e·(θ − μ)/s, σ_e the start residual's rms, so the cost is that of the data
    # (Σe²/σ_e²) plus (θ − μ)²/s², in the data's units
    rows: list[tuple[int, float, float]] = []
    if prior and len(prob.records) == 1:
        for j, n in enumerate(prob.run_params):
            if n in prior:
                rows.append((j, *prior[n]))
    sel = slice(None) if rows_kept is None else rows_kept
    e0 = prob.residual(z)[sel]
    scale = float(np.sqrt(np.mean(e0**2))) if e0.size else 1.0
    scale = scale if np.isfinite(scale) and scale > 0 else 1.0

    def f(h: np.ndarray) -> np.ndarray:
        e = prob.residual(np.concatenate([z[:k], h]))[sel]
        if not rows:
            return e
        return np.concatenate([e, [scale * (h[j] - mu) / sd for j, mu, sd in rows]])

    def jf(h: np.ndarray) -> np.ndarray:
        J = prob.jac(np.concatenate([z[:k], h]), run_only=True)[sel, k:]
        if not rows:
            return J
        P = np.zeros((len(rows), J.shape[1]))
        for i, (j, _, sd) in enumerate(rows):
            P[i, j] = scale / sd
        return np.vstack([J, P])

    r0 = f(z[k:])
    sol = solve(f, jf, z[k:], lo[k:], hi[k:], max_nfev=max_nfev, tol=1e-6)
    if sol.cost <= 0.5 * float(r0 @ r0):
        z[k:] = sol.x
    return z


def estimate_record(
    model: ForceModel,
    sig: Signals,
    force: np.ndarray,
    theta: Mapping[str, float],
    bounds: Mapping[str, tuple[float, float]] | None = None,
    prior: Mapping[str, tuple[float, float]] | None = None,
    rows_kept: np.ndarray | None = None,
) -> dict[str, float]:
    """``theta`` with the record parameters fitted on this record (muscle parameters held).

    ``prior``: per record nuisance (a drift rate), the campaign's (mean, sd) of it
    (:meth:`~pmalab.identify.campaign.fit.CampaignFit.record_prior`): the estimate starts at
    the mean and is pulled toward it by a Gaussian prior, so a rate that the record's early
    part cannot tell from the start state's transient (one short cycle) keeps the campaign's
    value instead of extrapolating a confusion.

    ``rows_kept``: indices of the samples the record parameters other than h0 (the force
    zero, a drift rate) are refitted on once h0 and its branch are set
    (:func:`within_range`); None: the whole early part sets them all."""
    th = dict(theta)
    names = [n for n in record_names(model) if n in th]
    if not names:
        return th
    b = dict(bounds or {})
    for n in names:
        b.setdefault(n, (-np.inf, np.inf))
    prob = _record_problem(model, sig, force, th, b, names)
    # start: the pressure law's c0 (a drifting zero), every other record parameter at 0
    pr = dict(prior or {})
    start = {n: [th[n] if n == "c0" else pr[n][0] if n in pr else 0.0] for n in names}
    z = fit_record_params(prob, prob.z_from({}, start), prior=pr)
    th.update({n: v[0] for n, v in prob.run_values(z).items()})
    if model.law.state_size > 1 and "h0" in names:
        # an element law's start state is h0 on one of two branches: that of the record's
        # first motion, or — a record that starts at a turning point it reached moving the
        # other way — that of a move against it (:mod:`pmalab.identify.laws._slide`).  The
        # early part says which: the other branch is kept only when it fits it better by
        # more than BRANCH_GAIN
        alt = dict(th)
        alt[START_BRANCH] = 1.0 - float(th.get(START_BRANCH, 0.0))
        prob2 = replace_constants(prob, {k: v for k, v in alt.items() if k not in names})
        z2 = fit_record_params(prob2, prob2.z_from({}, start), prior=pr)
        c1, c2 = _cost(prob, z), _cost(prob2, z2)
        if c2 < (1.0 - BRANCH_GAIN) ** 2 * c1:
            alt.update({n: v[0] for n, v in prob2.run_values(z2).items()})
            th = alt
    rest = [n for n in names if n != "h0"]
    if rest and rows_kept is not None:
        # the force zero (and any drift rate) refitted where the record revisits, h0 and its
        # branch held: the excursion's misfit is carried into none of them
        prob3 = _record_problem(model, sig, force, th, b, rest)
        z3 = fit_record_params(
            prob3, prob3.z_from({}, {n: [th[n]] for n in rest}), prior=pr, rows_kept=rows_kept
        )
        th.update({n: v[0] for n, v in prob3.run_values(z3).items()})
    return th


def _record_problem(
    model: ForceModel,
    sig: Signals,
    force: np.ndarray,
    theta: Mapping[str, float],
    bounds: dict[str, tuple[float, float]],
    names: list[str],
) -> Problem:
    """The one-record problem whose free parameters are the record parameters ``names``,
    every other parameter of ``theta`` held."""
    return Problem(
        model,
        [Record("", sig.p_nom, sig, np.asarray(force, dtype=np.float64))],
        free=[],
        degree={},
        constants={k: v for k, v in theta.items() if k not in names},
        bounds=bounds,
        run_params=names,
    )


def _cost(prob: Problem, z: np.ndarray) -> float:
    """Sum of squared residuals (N²) of ``prob`` at ``z`` (inf when not finite)."""
    with np.errstate(all="ignore"):
        e = prob.residual(z)
    c = float(e @ e)
    return c if np.isfinite(c) else float("inf")


def replace_constants(prob: Problem, constants: Mapping[str, float]) -> Problem:
    """``prob`` with other held parameters (same records, free and record parameters)."""
    return Problem(
        prob.model,
        prob.records,
        free=list(prob.free),
        degree=dict(prob.degree),
        constants=dict(constants),
        bounds=dict(prob.bounds),
        run_params=list(prob.run_params),
        cap=prob.cap,
        basis=prob.basis,
    )


def predict_record(
    model: ForceModel,
    sig: Signals,
    theta: Mapping[str, float],
    force: np.ndarray | None = None,
    initial: str = "estimate",
    bounds: Mapping[str, tuple[float, float]] | None = None,
    prior: Mapping[str, tuple[float, float]] | None = None,
) -> np.ndarray:
    """Free-run force (N) of ``model`` on a record, its record parameters set by ``initial``
    (``prior``: the campaign's (mean, sd) of each record nuisance, see :func:`estimate_record`).

    ``theta``: the muscle parameters (record parameters in it are replaced).  Under
    ``"estimate"`` they are fitted on the record's early part only (module docstring); score
    the prediction from :func:`scored_from` on.
    """
    if initial not in INITIAL_STATES:
        raise ValueError(f"initial must be one of {INITIAL_STATES}, not {initial!r}")
    th = dict(theta)
    for n in model.record_params:
        if n in th:
            th[n] = 0.0
    if initial == "estimate" and force is None:
        initial = "burn-in"
    if initial == "zero":
        return model.predict(sig, th)
    if initial == "burn-in":
        aug, P = burn_in_signals(sig)
        return model.predict(aug, th)[P:]
    assert force is not None  # "estimate" without a force became "burn-in" above
    m = calibration_samples(sig)
    f = np.asarray(force, dtype=np.float64)
    keep = within_range(sig.x, m) if model.law.state_size > 1 else None
    return model.predict(sig, estimate_record(model, sig.head(m), f[:m], th, bounds, prior, keep))


def within_range(x: np.ndarray, m: int, least: float = WITHIN_RANGE_SHARE) -> np.ndarray | None:
    """Samples of a record's early part (its first ``m``) whose contraction lies within the
    range the rest of the record covers, or None when that is all of them or fewer than
    ``least`` of them.

    A recorded run starts after its ramp-in, which may carry the path beyond the range it
    then cycles over (an overshoot before the first reversal).  There an elasto-slide law's
    start state — one number on a branch — says least about the elements' real forces: the
    large elements still hold what the ramp-in left, and the loop beyond the range is one
    the identification runs never repeated.  The record's force zero is fitted on the
    samples the record revisits.

    Parameters
    ----------
    x : numpy.ndarray
        Contraction (mm) of the whole record.
    m : int
        Samples of the early part (:func:`calibration_samples`).
    least : float
        The least share of the early part kept; below it, the early part as a whole.

    Returns
    -------
    numpy.ndarray or None
        Indices into the early part, ascending.
    """
    x = np.asarray(x, dtype=np.float64)
    if m >= x.shape[0] or m < 1:
        return None
    lo, hi = float(np.min(x[m:])), float(np.max(x[m:]))
    head = x[:m]
    keep = np.flatnonzero((head >= lo) & (head <= hi))
    if keep.size == m or keep.size < least * m:
        return None
    return keep
