"""Scoring candidate effects by what ``pmalab identify --add`` gives on the held-out runs.

A candidate effect is scored by running THE identification
(:func:`~pmalab.identify.campaign.validation.fit_and_validate`: per-run fits, joint pressure
laws, validation with the record policy) with the effect added, on the same identification
and held-out runs as the current model — the way SysIdentPy's term selection scores a term
with the estimator it fits with.  The numbers in the ranking are therefore the numbers the
user gets from ``pmalab identify --add EFFECT --validate ...``.

Nuisance-fair scoring.  Every held-out run is predicted the way ``pmalab identify``
validates it: the record's own parameters (the start state h0, the record's force zero —
for every model alike — and the record nuisances of the effects, e.g. a drift rate pulled
toward the campaign's) are fitted on the run's *early part* and the error is scored on the
*rest* (:mod:`pmalab.identify.estimation.records`), the same samples and the same
per-record freedom for the null model and for every candidate.  An effect with per-record freedom must
therefore predict the rest of the record from its start: a real linear drift extrapolates,
a decaying softening or a misfit of the loop's shape does not.

A candidate whose identification *failed* — a held-out prediction diverged, the held-out
error rose by more than ``FAILED_FALL`` (a converged fit with more freedom cannot lose that
much), the per-run ratios scatter more than the fall they average, or the new parameters
sit on their bounds on most runs while the error rises — is listed as "fit failed: why",
never ranked by its fall and never significant (:meth:`Candidate.failure`).  A held-out run
on which the *current* model's prediction diverged (or ran off to ``DIVERGED_NRMSE``) has no
error to fall from: it is left out of every candidate's evidence (:attr:`Candidate.evidence`)
— fall, gain, every-run and block tests are taken over the other runs — and named in the
diagnosis; a candidate that merely predicts where a failed identification did not would
otherwise be credited with a fall of ~``DIVERGED_NRMSE``.

Significance is decided in the units of the held-out evidence itself (docs/explanation/
significance.md): an effect is *significant* when the held-out error falls on every
held-out run (a run at its noise floor both without and with the effect — below
``AT_FLOOR_RATIO`` = 1.25× its floor — cannot show a fall and does not count), by at
least ``MIN_GAIN_X_FLOOR`` = 0.25 noise floors on average (absolute nrmse over the runs' own noise floor, not a percentage: a real device sits 10–20× above
its floor, and a modest real effect cuts a small share of that), and — where the runs hold
at least ``MIN_BLOCKS`` whole cycles — block by block beyond ``MIN_BLOCK_T`` standard
errors.  The fall must be the effect's own: for an effect whose absence is a parameter value
(``Effect.absent``: a mass, a viscous coefficient, a delay of 0; symmetric branches; no
nonlinear spring or pressure term) the identified model is predicted again without the
effect, every other parameter as identified; per run
the fall credited to the effect is the smaller of its fall and the rise that removal causes,
and the credited falls must also average ``MIN_GAIN_X_FLOOR`` floors
(:attr:`Candidate.gain_carried_x_floor`) — a run where the physics makes the effect's force
negligible (inertia on a slow run) carries no evidence for it.  fall = 1 − mean(nrmse_after) / mean(nrmse_before) is what the user reads; its
standard error comes from the per-run ratios.  Two significant effects are *ambiguous*
when the runner-up achieves ≥ ``AMBIGUITY_RATIO`` = 85 % of the winner's fall and the
winner's held-out errors are not clearly lower, run by run (:func:`clearly_better`), or
when the identification runs share one frequency and both grow with the rate of motion
(:func:`judge`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmalab.identify.campaign import ModelSpec, fit_and_validate
from pmalab.identify.campaign.batch import ContextPool, map_with_context
from pmalab.identify.effects import EFFECTS
from pmalab.runfile import Run

#: an effect must cut the held-out nrmse by at least this many noise floors (absolute)
MIN_GAIN_X_FLOOR = 0.25
#: ... and its paired block-by-block improvement must exceed this many standard errors (a
#: consistency check: a slow effect such as a drifting zero improves late blocks more than
#: early ones, so blocks are not identical replicates and a strict t would miss it)
MIN_BLOCK_T = 1.5
#: whole cycles a held-out run needs for the block test (fewer: the test is not made)
MIN_BLOCKS = 3
#: runner-up / winner fall ratio above which two significant effects are ambiguous
AMBIGUITY_RATIO = 0.85
#: held-out runs a paired "every run" comparison of two effects needs (see clearly_better)
MIN_PAIRED_RUNS = 4
#: a held-out run whose nrmse is below this many times its own noise floor both without and
#: with the candidate is *at the floor*: it cannot show a fall beyond noise either way, so it
#: is neither evidence for nor against the candidate in the every-run rule
AT_FLOOR_RATIO = 1.0 + MIN_GAIN_X_FLOOR
#: a diverged validation counts with this nrmse (it is then never significant)
DIVERGED_NRMSE = 10.0
#: a held-out error rising by more than this fraction marks the candidate's fit failed
FAILED_FALL = 1.0
#: ... and so does a fall below −``SCATTER_MIN_RISE`` whose standard error exceeds it
SCATTER_MIN_RISE = 0.3
#: share of the identification runs on which new parameters sit on a bound (other than a
#: physical sign bound at 0) for a rising error to count as a failed fit
BOUND_SHARE = 0.5


@dataclass
class Scored:
    """One identification scored on the held-out runs."""

    effects: tuple[str, ...]
    nrmse: list[float]  # per held-out run
    diverged: list[str] = field(default_factory=list)
    n_params: int = 0
    #: the free-run force predictions (N, full rate) of the held-out runs, in their order
    predictions: list[np.ndarray] = field(default_factory=list, repr=False)
    #: per held-out run: the mean squared error (N²) of each block of whole cycles
    block_mse: list[np.ndarray] = field(default_factory=list, repr=False)
    #: per held-out run: std of the measured force (N) on its scored part, the nrmse normaliser
    force_std: list[float] = field(default_factory=list, repr=False)
    #: per held-out run: the first scored sample (after the early part that set the record)
    scored_from: list[int] = field(default_factory=list, repr=False)
    #: the model's parameters that vary on at least one identification run
    param_names: frozenset[str] = frozenset()
    #: per parameter: on how many identification runs it ended on a bound (a bound at 0, a
    #: physical sign, is not counted), and the number of identification runs
    at_bounds: dict[str, int] = field(default_factory=dict, repr=False)
    n_runs: int = 0
    #: the pressure structure the law's elements took in this identification
    #: (``identification.json`` ``pressure_structure``; None: the law offers none)
    structure: dict[str, Any] | None = field(default=None, repr=False)
    #: per held-out run: the nrmse of this identified model with the force of its *last*
    #: effect removed (that effect's ``Effect.absent`` values, every other parameter as
    #: identified; None when the last effect declares none) — how much of a fall the
    #: effect's own force carries (:attr:`Candidate.gain_carried_x_floor`)
    without_last: list[float] | None = None
    #: the identification raised: what and where (:func:`raised`; "" when it did not).  Its
    #: held-out nrmse are then NaN: there is no prediction to score
    error: str = ""
    #: predicting the identified model without its last effect (:attr:`without_last`)
    #: raised: what and where ("" when it did not); the fall cannot then be credited
    without_error: str = ""
    #: the held-out runs' labels, in their order (empty: not recorded)
    labels: list[str] = field(default_factory=list)
    #: CPU seconds the identification and its scoring took in the process that ran it (what
    #: the ladder orders later rounds by; in no output)
    seconds: float = field(default=0.0, repr=False, compare=False)

    @property
    def mean(self) -> float:
        return float(np.mean(self.nrmse)) if self.nrmse else float("nan")

    @property
    def judged(self) -> list[int]:
        """The held-out runs (indices) this model predicted (:func:`judged_runs`).  On the
        others its prediction diverged or ran off; they are no evidence for a candidate
        scored against it (:attr:`Candidate.evidence`)."""
        return judged_runs(self.nrmse)

    @property
    def unjudged(self) -> list[str]:
        """The labels of the held-out runs not in :attr:`judged` (diverged, or ran off to
        nrmse ≥ ``DIVERGED_NRMSE`` with a finite prediction), in their order."""
        kept = set(self.judged)
        names = self.labels or [f"held-out run {i + 1}" for i in range(len(self.nrmse))]
        return [n for i, n in enumerate(names) if i not in kept]


def judged_runs(nrmse: Sequence[float | None]) -> list[int]:
    """The held-out runs (indices) a model's per-run nrmse shows it predicted: finite and
    below ``DIVERGED_NRMSE`` (None, as diagnosis.json writes a missing value, is not)."""
    return [
        i for i, v in enumerate(nrmse) if v is not None and math.isfinite(v) and v < DIVERGED_NRMSE
    ]


def score(train: Sequence[Run], held: Sequence[Run], spec: ModelSpec) -> Scored:
    """Identify ``spec`` on ``train`` and validate on ``held`` — ``pmalab identify``'s path.

    BLAS runs on one thread (candidates are parallel over processes; the covariance and
    leave-one-pressure-out algebra of the joint fit is small and slower threaded)."""
    from pmalab.identify.estimation.solver import one_blas_thread

    start = time.process_time()
    with one_blas_thread():
        try:
            cf, vals, _ = fit_and_validate(list(train), spec, held, jobs=1, pressure_model="joint")
        except MemoryError:
            raise
        except Exception as exc:  # a candidate that fails is that candidate's failure
            return Scored(
                tuple(spec.effects),
                [math.nan] * len(held),
                error=raised(exc),
                labels=[r.label for r in held],
                seconds=time.process_time() - start,
            )
        try:
            without, without_error = _without_last(cf, spec, held), ""
        except MemoryError:
            raise
        except Exception as exc:  # ... and so is its own-fall check
            without, without_error = None, raised(exc)
    nr = _nrmse_of(vals)
    div = [v.run.label for v in vals if _diverged(v)]
    # the model's free parameters: free on at least one run (a parameter the fit fixes on
    # one run only, e.g. a collinear gamma, still belongs to the model)
    names = frozenset(p.name for rf in cf.runs for p in rf.result.params if p.vary)
    hits: dict[str, int] = {}
    for rf in cf.runs:
        for p in rf.result.params:
            if p.vary and _on_bound(p.value, p.lo, p.hi):
                hits[p.name] = hits.get(p.name, 0) + 1
    preds = [np.asarray(v.force_model, dtype=np.float64) for v in vals]
    i0 = [int(v.scored_from) for v in vals]
    blocks = [block_mse(v.run, p, i) for v, p, i in zip(vals, preds, i0)]
    sds = [float(np.std(v.run.force[i:])) for v, i in zip(vals, i0)]
    return Scored(
        tuple(spec.effects),
        nr,
        div,
        len(names),
        preds,
        blocks,
        sds,
        i0,
        names,
        hits,
        len(cf.runs),
        None if getattr(cf, "structure", None) is None else dict(cf.structure.as_json()),
        without,
        without_error=without_error,
        labels=[r.label for r in held],
        seconds=time.process_time() - start,
    )


#: packages whose frames :func:`raised` looks past (the place to name is the caller's)
_LIBRARIES = frozenset({"numpy", "scipy", "numba", "pandas", "h5py"})


def raised(exc: BaseException) -> str:
    """One line saying what ``exc`` is and where it was raised: ``"ValueError: message
    (file.py, line N)"``, the place being the innermost frame outside NumPy, SciPy, numba
    and the standard library — a user's effect or law file, or pmalab's own code."""
    import sysconfig
    from pathlib import Path

    import pmalab
    from pmalab.errors import printable

    paths = sysconfig.get_paths()
    std = paths["stdlib"]
    # installed packages may sit inside the standard library's directory (a system
    # Python's site-packages): they are not the standard library
    site = tuple({paths.get("purelib") or "\0", paths.get("platlib") or "\0"})
    home = Path(pmalab.__file__).parent.parent  # pmalab's own files are named from here
    where = ""
    tb = exc.__traceback__
    while tb is not None:
        code, mod = tb.tb_frame.f_code, str(tb.tb_frame.f_globals.get("__name__", ""))
        name = code.co_filename
        # generated code ("<string>": a dataclass's __init__, __eq__) has no file to name
        if (
            mod.split(".")[0] not in _LIBRARIES
            and (not name.startswith(std) or name.startswith(site))
            and not name.startswith("<")
        ):
            if mod.split(".")[0] == "pmalab" and Path(name).is_relative_to(home):
                name = Path(name).relative_to(home).as_posix()
            where = f" ({name}, line {tb.tb_lineno})"
        tb = tb.tb_next
    text = printable(" ".join(str(exc).split()))
    if len(text) > 200:
        text = text[:199] + "…"
    return f"{type(exc).__name__}{': ' + text if text else ''}{where}"


def _diverged(v: Any) -> bool:
    """A validation whose prediction diverged or whose nrmse is not finite."""
    return bool(v.diverged) or not math.isfinite(float(v.metrics["nrmse"]))


def _nrmse_of(vals: Sequence[Any]) -> list[float]:
    """Held-out nrmse per validation, a diverged or non-finite one as ``DIVERGED_NRMSE``."""
    return [
        DIVERGED_NRMSE if _diverged(v) else min(float(v.metrics["nrmse"]), DIVERGED_NRMSE)
        for v in vals
    ]


def _without_last(cf: Any, spec: ModelSpec, held: Sequence[Run]) -> list[float] | None:
    """The held-out nrmse of the identified model ``cf`` with the force of ``spec``'s last
    effect removed: that effect's parameters set to its ``Effect.absent`` values (a
    constant pressure law), every other parameter as identified, each held-out run's
    record parameters estimated on its early part as in any validation.  None when the
    last effect declares no absent values (or the model has none of its parameters)."""
    from dataclasses import replace

    from pmalab.identify.campaign.validation import validate_runs

    if not spec.effects:
        return None
    cls = EFFECTS.get(spec.effects[-1])
    absent = getattr(cls, "absent", None) if cls is not None else None
    # a parameter the law holds fixed (Duhem has no direction-dependent slope) has no
    # pressure law and keeps its fixed value
    absent = {n: v for n, v in (absent or {}).items() if n in cf.pressure}
    if not absent:
        return None
    if cf.model.measured_pressure:  # the runs as fit_and_validate took them
        from pmalab.identify.labels import use_measured

        held = use_measured(list(held), whole_run=True)
    laws = dict(cf.pressure)
    for name, value in absent.items():
        laws[name] = replace(laws[name], coef=(float(value), 0.0, 0.0), degree=0)
    vals, _ = validate_runs(replace(cf, pressure=laws), held)
    return _nrmse_of(vals)


def _on_bound(value: float, lo: float, hi: float) -> bool:
    """``value`` sits on a finite bound other than 0 (within 1e-6 of the range)."""
    span = hi - lo if math.isfinite(hi - lo) else max(abs(lo), abs(hi), 1.0)
    tol = 1e-6 * (span if math.isfinite(span) and span > 0 else 1.0)
    return any(math.isfinite(b) and b != 0.0 and abs(value - b) <= tol for b in (lo, hi))


def scored_part(run: Run) -> slice:
    """The samples of a held-out run its error is scored on (after the early part on which
    its record parameters are estimated, :func:`pmalab.identify.estimation.records.calibration_count`)."""
    from pmalab.identify.estimation.records import calibration_count

    return slice(calibration_count(run.time, run.frequency), None)


def heldout_floor(run: Run) -> float:
    """The noise floor (nrmse) of a held-out run as it is scored: the noise rms estimated on
    the whole record over the std of the measured force on its scored part."""
    from pmalab.identify.noise import noise_sigma

    sd = float(np.std(np.asarray(run.force, float)[scored_part(run)]))
    return noise_sigma(run.force, run.time) / sd if sd > 0 else float("nan")


def blocks_of(run: Run) -> list[slice]:
    """The run cut into blocks of one whole excitation cycle each; none when the run holds
    fewer than ``MIN_BLOCKS`` cycles or its frequency is unknown.

    Blocks are the within-run replicates of the paired comparison: with only 2–4 held-out
    runs, the spread of the improvement over cycles says whether it is more than noise.
    Only whole cycles are comparable (a stretch branch and a release branch are not)."""
    return cycle_blocks(run.time, run.frequency)


def cycle_blocks(time: np.ndarray, frequency_Hz: float | None) -> list[slice]:
    """Blocks of one whole excitation cycle each of samples at ``time`` (s) (see
    :func:`blocks_of`)."""
    n = len(time)
    f = frequency_Hz or 0.0
    if f <= 0 or n < 2:
        return []
    dt = float(np.median(np.diff(time)))
    per = int(round(1.0 / (f * dt))) if dt > 0 else 0
    k = n // per if per > 0 else 0
    if k < MIN_BLOCKS:
        return []
    return [slice(i * per, (i + 1) * per) for i in range(k)]


def block_mse(run: Run, pred: np.ndarray, start: int = 0) -> np.ndarray:
    """Mean squared error (N²) of ``pred`` against the measured force, per block of whole
    cycles of the run's part from sample ``start`` on (its scored part)."""
    e = (np.asarray(run.force, float) - np.asarray(pred, float))[start:]
    with np.errstate(all="ignore"):
        return np.array(
            [float(np.mean(e[b] ** 2)) for b in cycle_blocks(run.time[start:], run.frequency)]
        )


def _task(runs: tuple[list[Run], list[Run]], spec: ModelSpec) -> Scored:
    from pmalab.identify.campaign.batch import in_worker

    if in_worker():
        # a worker's runs are its context's, the same objects for every candidate: their
        # signals are filtered and differentiated once
        from pmalab.identify.signals import keep_run_signals

        keep_run_signals([*runs[0], *runs[1]])
    return score(runs[0], runs[1], spec)


def _task_sharing(
    runs: tuple[list[Run], list[Run]], task: tuple[ModelSpec, dict]
) -> tuple[Scored, dict]:
    """:func:`_task` in a kept pool's worker, which first takes the base-law fits the other
    workers made (``task[1]``: each run's base law refined alone, where every model with
    effects starts) and hands back those it made: each is computed once per diagnosis, not
    once per worker.  A base fit is the same numbers whichever process made it."""
    from pmalab.identify.estimation.single import remember_base_fits, with_new_base_fits

    spec, known = task
    remember_base_fits(known)
    return with_new_base_fits(lambda: _task(runs, spec))


def score_all(
    train: Sequence[Run],
    held: Sequence[Run],
    specs: Sequence[ModelSpec],
    jobs: int = 1,
    progress: bool = False,
    desc: str = "candidates",
    scheduler: str | None = None,
    pool: ContextPool | None = None,
    base_fits: dict | None = None,
) -> list[Scored]:
    """Score every model spec (in parallel over candidates: one identification each).

    Local worker processes receive the runs once each (as the pool's initializer argument,
    whatever the start method); on a Dask cluster (``scheduler``) each task carries them.
    ``pool``: workers already holding ``(train, held)`` as their context, kept across calls
    (:class:`~pmalab.identify.campaign.batch.ContextPool`; the same scores).  ``base_fits``
    (with ``pool``): the base-law fits the pool's workers made, extended as their results
    arrive; each candidate is handed out with those made so far (:func:`_task_sharing`)."""
    if pool is not None and not scheduler:
        if base_fits is None:
            return pool.map(_task, list(specs), progress=progress, desc=desc)
        shared = base_fits

        def fed(spec: ModelSpec) -> tuple[ModelSpec, dict]:
            return spec, dict(shared)  # what the workers made so far, as it is handed out

        def done(out: tuple[Scored, dict]) -> None:
            for k, v in out[1].items():
                shared.setdefault(k, v)

        outs = pool.map(
            _task_sharing, list(specs), progress=progress, desc=desc, fed=fed, done=done
        )
        return [o for o, _ in outs]
    return map_with_context(
        _task,
        (list(train), list(held)),
        list(specs),
        jobs=jobs,
        scheduler=scheduler,
        progress=progress,
        desc=desc,
    )


@dataclass
class Candidate:
    """One effect's score against the current model on the held-out runs."""

    effect: str
    before: Scored
    after: Scored
    significant: bool = False
    #: noise floor (nrmse) of each held-out run, in the runs' order
    floors: Sequence[float] = ()

    @property
    def evidence(self) -> list[int]:
        """The held-out runs (indices) that are evidence for or against this candidate:
        those the current model predicted.  A run on which its prediction diverged or ran
        off (nrmse not finite or ≥ ``DIVERGED_NRMSE``) has no error to fall from — any
        candidate that predicts there at all would show a fall of ~``DIVERGED_NRMSE``, the
        current model's failure and not the candidate's evidence — so it is left out of the
        fall, the gain, the every-run and the block tests (module docstring)."""
        return self.before.judged

    @property
    def left_out(self) -> list[str]:
        """The held-out runs left out of the evidence (:attr:`evidence`), by label."""
        return self.before.unjudged

    def _paired(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(before, after, floors) of the evidence runs; floors empty when not given."""
        i = self.evidence
        b = np.asarray(self.before.nrmse, float)[i]
        a = np.asarray(self.after.nrmse, float)
        a = a[i] if a.shape == (len(self.before.nrmse),) else a
        f = np.asarray(self.floors, float)
        f = f[i] if f.shape == (len(self.before.nrmse),) else f
        return b, a, f

    @property
    def nrmse_before(self) -> float:
        """Mean held-out nrmse of the current model over the evidence runs."""
        b, _, _ = self._paired()
        return float(np.mean(b)) if b.size else float("nan")

    @property
    def nrmse_after(self) -> float:
        """Mean held-out nrmse with the candidate over the evidence runs."""
        _, a, _ = self._paired()
        return float(np.mean(a)) if a.size else float("nan")

    @property
    def fall(self) -> float:
        """1 − mean(after)/mean(before) over the evidence runs: the relative fall the user
        sees."""
        b = self.nrmse_before
        return 1.0 - self.nrmse_after / b if b > 0 else 0.0

    @property
    def fall_se(self) -> float:
        """Standard error of the fall from the spread of the per-run ratios."""
        b, a, _ = self._paired()
        if b.size < 2 or np.any(b <= 0) or a.shape != b.shape:
            return 0.0
        return float(np.std(a / b, ddof=1) / math.sqrt(b.size))

    @property
    def gain_x_floor(self) -> float:
        """Mean absolute fall of the held-out nrmse in units of the runs' noise floor."""
        b, a, f = self._paired()
        fl = float(np.mean(f)) if f.size else float("nan")
        return float(np.mean(b - a) / fl) if b.size and a.shape == b.shape and fl > 0 else 0.0

    @property
    def carried(self) -> list[float] | None:
        """Per held-out run: how much of the nrmse the effect's own force carries — the
        identified model's nrmse with the effect's force removed (its ``Effect.absent``
        values, every other parameter as identified) minus its nrmse with it.  None when
        the effect declares no absent values (or ``after`` is not ``before`` + this effect)."""
        w = self.after.without_last
        if w is None or not self.after.effects or self.after.effects[-1] != self.effect:
            return None
        a = np.asarray(self.after.nrmse, float)
        wo = np.asarray(w, float)
        return [float(v) for v in wo - a] if wo.shape == a.shape else None

    @property
    def gain_carried_x_floor(self) -> float:
        """The mean fall the effect's own force carries, in noise floors: per held-out run
        the smaller of its fall (before − after) and what the effect's force carries there
        (:attr:`carried`), averaged over the runs, over the mean floor.  Equal to
        :attr:`gain_x_floor` when the effect declares no absent values.

        A fall on a run where the effect's force is negligible (an inertial force on a slow
        run) came from the other parameters moving, not from the effect: it is no evidence
        for it (docs/explanation/significance.md)."""
        c = self.carried
        if c is None:
            return self.gain_x_floor
        b, a, f = self._paired()
        fl = float(np.mean(f)) if f.size else float("nan")
        if not b.size or a.shape != b.shape or not fl > 0:
            return 0.0
        return float(np.mean(np.minimum(b - a, np.asarray(c, float)[self.evidence])) / fl)

    @property
    def block_t(self) -> float:
        """The paired block-by-block improvement over its standard error.

        Per block of whole cycles of every held-out run: d = (rms_before − rms_after) /
        std(F) of that run (nrmse units).  t = mean over runs of each run's mean d, divided
        by its standard error from the spread of the blocks *within* each run
        (se² = Σ_i s_i²/n_i / R²): blocks replicate the comparison within a run, so 2–4
        held-out runs still give a usable spread; a fall that differs from run to run is no
        evidence against the effect (that every run improves is checked apart)."""
        if not self.before.block_mse or len(self.before.block_mse) != len(self.after.block_mse):
            return math.nan
        kept = self.evidence
        if not kept:
            return math.nan
        means, var = [], 0.0
        for mb, ma, sd in (
            (self.before.block_mse[i], self.after.block_mse[i], self.after.force_std[i])
            for i in kept
        ):
            if mb.shape != ma.shape or sd <= 0 or mb.size < MIN_BLOCKS:
                return math.nan  # a run too short for blocks: the test is not made
            d = (np.sqrt(mb) - np.sqrt(ma)) / sd
            if not np.all(np.isfinite(d)):
                return 0.0
            means.append(float(np.mean(d)))
            var += float(np.var(d, ddof=1)) / d.size
        m = float(np.mean(means))
        se = math.sqrt(var) / len(means)
        return m / se if se > 0 else (math.inf if m > 0 else 0.0)

    def failure(self) -> str:
        """Why this candidate's identification failed ("" when it did not).

        Failed: a held-out prediction diverged; the held-out error rose by more than
        ``FAILED_FALL``; it rose by more than ``SCATTER_MIN_RISE`` with a standard error
        larger than the rise (per-run ratios all over the place); or it rose while a new
        parameter sits on a bound (not a sign bound at 0) on at least ``BOUND_SHARE`` of
        the identification runs; or the identification raised (:attr:`Scored.error`), or
        predicting it without the effect did (:attr:`Scored.without_error`: the fall cannot
        be credited to the effect, so it is not claimed)."""
        if self.after.error:
            return f"the identification raised {self.after.error}"
        if self.after.without_error and self.after.effects[-1:] == (self.effect,):
            return (
                "predicting the identified model without the effect (the check that the "
                f"fall is the effect's own) raised {self.after.without_error}"
            )
        if self.after.diverged:
            return f"the held-out prediction diverged on {', '.join(self.after.diverged)}"
        f, se = self.fall, self.fall_se
        new = sorted(self.after.param_names - self.before.param_names)
        n = max(self.after.n_runs, 1)
        hits = [
            f"{p} on {self.after.at_bounds[p]} of {n} runs"
            for p in new
            if self.after.at_bounds.get(p, 0) >= BOUND_SHARE * n
        ]
        bounds = f"; at its bound: {', '.join(hits)}" if hits else ""
        if f < -FAILED_FALL:
            return (
                f"the held-out error rose {100 * -f:.0f} % ± {100 * se:.0f} — a converged fit "
                f"with more freedom does not lose this much{bounds}"
            )
        if f < -SCATTER_MIN_RISE and se > -f:
            return (
                f"the held-out error rose {100 * -f:.0f} % ± {100 * se:.0f}, the per-run "
                f"changes scatter more than their mean{bounds}"
            )
        if f < 0 and hits:
            return f"the held-out error rose {100 * -f:.1f} %{bounds}"
        return ""

    @property
    def failed(self) -> bool:
        return bool(self.failure())

    @property
    def runs_improved(self) -> float:
        """Share of the evidence runs on which the held-out error fell."""
        b, a, _ = self._paired()
        return float(np.mean(a < b)) if b.size and a.shape == b.shape else 0.0

    @property
    def at_floor(self) -> list[bool]:
        """Per evidence run (:attr:`evidence`): at its noise floor without and with the
        candidate (below ``AT_FLOOR_RATIO``× its own floor both times)."""
        b, a, f = self._paired()
        if f.shape != b.shape or a.shape != b.shape:
            return [False] * b.size
        with np.errstate(invalid="ignore"):
            return [bool(x) for x in (b < AT_FLOOR_RATIO * f) & (a < AT_FLOOR_RATIO * f)]

    @property
    def every_run(self) -> bool:
        """The held-out error falls on every evidence run (:attr:`evidence`) that is not at
        its noise floor without and with the candidate (:attr:`at_floor`), and on at least
        one run.

        A run at its floor both times cannot show a fall beyond noise: requiring it to
        improve would make the verdict a coin flip (a tared drift on a 1 s record scored on
        its last 0.5 s: 8 N/s moves the zero by less than the 4 N noise there).  The mean
        gain of ``MIN_GAIN_X_FLOOR`` floors is still taken over every run."""
        b, a, _ = self._paired()
        if not b.size or a.shape != b.shape:
            return False
        fell = a < b
        return bool(np.any(fell) and np.all(fell | np.asarray(self.at_floor, bool)))

    def as_json(self) -> dict[str, Any]:
        """The ``diagnosis.json`` entry; a failed fit carries ``"status": "failed"``, its
        ``"reason"`` and no fall (``fall_percent``, ``fall_se_percent``, ``gain_x_floor`` null;
        an identification that raised has no ``nrmse_after``, ``per_run_after`` nor
        ``n_params`` either)."""
        cls = EFFECTS.get(self.effect)
        why = self.failure()
        out = {
            "effect": self.effect,
            "status": "failed" if why else "ok",
            **({"reason": why} if why else {}),
            # null when no held-out run is left to judge on (:attr:`evidence`)
            "nrmse_before": finite_or_none(self.nrmse_before),
            "nrmse_after": finite_or_none(self.nrmse_after),
            "fall_percent": None if why else float(100.0 * self.fall),
            "fall_se_percent": None if why else float(100.0 * self.fall_se),
            "significant": bool(self.significant),
            "n_params": int(self.after.n_params - self.before.n_params),
            "runs_improved": float(self.runs_improved),
            "runs_at_floor": int(sum(self.at_floor)),
            "gain_x_floor": None if why else float(self.gain_x_floor),
            # the part of the fall the effect's own force carries (its force removed from
            # the identified model, every other parameter kept); null: not measured
            "gain_carried_x_floor": None
            if why or self.carried is None
            else float(self.gain_carried_x_floor),
            "per_run_without_effect": None
            if self.after.without_last is None or self.carried is None
            else [float(v) for v in self.after.without_last],
            "block_t": None if math.isnan(self.block_t) else float(min(self.block_t, 1e6)),
            "per_run_before": [float(v) for v in self.before.nrmse],
            "per_run_after": [float(v) for v in self.after.nrmse],
            "diverged": list(self.after.diverged),
            # held-out runs on which the current model's prediction diverged: no evidence
            **({"left_out": self.left_out} if self.left_out else {}),
            "title": cls.title if cls else "",
            "explanation": cls.explanation if cls else "",
            "signature": cls.signature if cls else "",
        }
        if self.after.error:  # no identified model: nothing after to report
            out |= dict.fromkeys(
                ("nrmse_after", "n_params", "runs_improved", "runs_at_floor", "per_run_after")
            )
        return out


def finite_or_none(v: float) -> float | None:
    """``v`` as a float, or None when it is not finite (a mean over no evidence run: JSON
    has no NaN)."""
    return float(v) if math.isfinite(v) else None


def judge(
    cands: list[Candidate], single_frequency: bool = False
) -> tuple[list[Candidate], list[str]]:
    """Sort best first, mark significance (module docstring), find the ambiguous set.

    ``single_frequency``: the identification runs share one excitation frequency.  Then
    rate-dependent effects (``Effect.rate_dependent``: viscous force, a channel delay,
    inertia) are not identifiable apart — each is a force growing with the rate of motion,
    and the per-run fits trade it against the loop's width — so when the winner is one, every
    other significant rate-dependent effect is ambiguous with it, whatever the falls (on the
    seed protocol with hidden viscous friction, a delay's one campaign-wide constant
    extrapolated to the 0.3 Hz held-out run better than viscous damping's per-pressure law,
    which had traded against the hysteresis at 0.15 Hz: 67 % against 51 %)."""
    for c in cands:
        c.significant = is_significant(c)
    # failed fits last, never ranked by their fall
    cands.sort(key=lambda c: (c.failed, -c.fall if not c.failed else 0.0))
    sig = [c for c in cands if c.significant]
    amb: list[str] = []
    if len(sig) >= 2:
        close = [
            c
            for c in sig[1:]
            if (c.fall >= AMBIGUITY_RATIO * sig[0].fall and not clearly_better(sig[0], c))
            or (single_frequency and rate_dependent(sig[0].effect) and rate_dependent(c.effect))
        ]
        if close:
            amb = [sig[0].effect, *(c.effect for c in close)]
    return cands, amb


def alike(
    best_fall: float, best_runs: Sequence[float], other_fall: float, other_runs: Sequence[float]
) -> bool:
    """Two candidates explain the residual about equally: the rule that makes two
    significant effects *ambiguous* (the other's fall is ≥ ``AMBIGUITY_RATIO`` of the
    best's, and the best's held-out errors ``best_runs`` are not :func:`clearly_lower` than
    ``other_runs``), for candidates whether significant or not — what the held-out runs can
    tell apart, never a claim.  Falls are fractions (1 − after / before); a best fall ≤ 0
    (no fall to share) is never alike."""
    return bool(
        best_fall > 0.0
        and other_fall >= AMBIGUITY_RATIO * best_fall
        and not clearly_lower(best_runs, other_runs)
    )


def rate_dependent(effect: str) -> bool:
    """Whether the catalogue effect's force grows with the rate of motion
    (``Effect.rate_dependent``; False for a law or an unknown id)."""
    cls = EFFECTS.get(effect)
    return bool(cls is not None and cls.rate_dependent)


def is_significant(c: Candidate) -> bool:
    """The rule (module docstring): the held-out error falls on every held-out run (but
    those at their noise floor without and with it, :attr:`Candidate.every_run`), by at
    least ``MIN_GAIN_X_FLOOR`` noise floors on average — also counting only the part the
    effect's own force carries (:attr:`Candidate.gain_carried_x_floor`) — and, where the
    runs hold at least ``MIN_BLOCKS`` whole cycles, cycle by cycle beyond ``MIN_BLOCK_T``
    standard errors."""
    t = c.block_t
    return bool(
        not c.failed
        and c.every_run
        and c.gain_x_floor >= MIN_GAIN_X_FLOOR
        and c.gain_carried_x_floor >= MIN_GAIN_X_FLOOR
        and (math.isnan(t) or t >= MIN_BLOCK_T)
    )


def clearly_better(a: Candidate, b: Candidate) -> bool:
    """``a``'s held-out errors beat ``b``'s beyond chance, paired run by run.

    d_i = nrmse_after(b)_i − nrmse_after(a)_i over the held-out runs: ``a`` is clearly better
    when d_i > 0 on every one of ≥ ``MIN_PAIRED_RUNS`` runs (a sign test: p ≤ 1/16), or when
    mean(d) exceeds two standard errors on ≥ 3 runs.  Two runs never decide (p = 1/4): two
    effects that explain the residual about equally there stay ambiguous.  Only the runs that
    are evidence for both (:attr:`Candidate.evidence`) are compared: on a run where the
    current model diverged, both fall by ~``DIVERGED_NRMSE`` and the difference says nothing.
    """
    if len(a.after.nrmse) != len(b.after.nrmse):
        return False
    both = set(b.evidence)
    i = [k for k in a.evidence if k in both]
    return clearly_lower([a.after.nrmse[k] for k in i], [b.after.nrmse[k] for k in i])


def clearly_lower(a: Sequence[float], b: Sequence[float]) -> bool:
    """The held-out errors ``a`` beat ``b`` beyond chance, paired run by run (the test of
    :func:`clearly_better`, on the per-run nrmse themselves)."""
    if len(a) != len(b):
        return False
    d = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    n = d.size
    if n < 3 or not np.all(np.isfinite(d)):
        return False
    if n >= MIN_PAIRED_RUNS and bool(np.all(d > 0)):
        return True
    return bool(d.mean() - 2.0 * d.std(ddof=1) / math.sqrt(n) > 0)
