"""A campaign: per-run fits, pressure quadratics, and the pressure-parametrised model.

``fit_campaign(runs, model)`` fits every identification run (in parallel, see
:mod:`pmalab.identify.campaign.batch`), makes the fixes consistent across runs (a parameter the fits
had to fix for collinearity on most runs is fixed on all, so the quadratics are not fed a
mix), and fits θ(p) = q0 + q1·p + q2·p² for every parameter through the per-run values
(weighted by their standard errors).  Those quadratics are only the start: the pressure
laws are then refined *jointly* on the free-run error of all runs at once, each
parameter's order (0, 1 or 2 in p) chosen so that collinear, poorly determined parameters
become constants instead of noisy quadratics (:mod:`pmalab.identify.estimation.joint`;
``pressure_model = "joint"``).

The pressure-parametrised model predicts *any* run from its measured position and muscle
pressure (:func:`predict_run`): the parameters are evaluated at the run's nominal pressure
(θ(p_nom)) and clipped into the law's bounds; a pressure outside the identified range is
extrapolation and is flagged (:meth:`CampaignFit.extrapolates`); effects that use the measured pressure trace get it through the signals; the
record parameters — the start state h0 and the effects' record nuisances
(``Effect.nuisance_params``, e.g. a load cell's drift rate; with a drifting-zero effect,
``Effect.tare``, also the force zero c0) — belong to one recording, not to the muscle: one
value per run in the joint fit, and estimated on each predicted record with the muscle
parameters held (:mod:`pmalab.identify.estimation.records`).
"""

from __future__ import annotations

import pickle
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pmalab.errors import PmalabError
from pmalab.identify.campaign.batch import map_split, map_tasks
from pmalab.identify.campaign.pressure import PressureFit, fit_quadratic, weighted_r2
from pmalab.identify.campaign.sharing import map_shared, sharing_here
from pmalab.identify.estimation.joint import JointFit, evaluate, prepare, refine, start_laws
from pmalab.identify.estimation.output_error import (
    OutputErrorFit,
    fit_output_error,
    position_data,
)
from pmalab.identify.estimation.records import TARE_NOTE, predict_record, scored_from
from pmalab.identify.estimation.single import (
    FitResult,
    default_fixed_notes,
    fit_run,
    remember_base_fits,
    with_new_base_fits,
)
from pmalab.identify.messages import detail, note, prefixed
from pmalab.identify.metrics import metrics
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals
from pmalab.runfile import Run

#: identification runs fitted worse than this (fit %) are named in the campaign warnings
POOR_FIT_PERCENT = 90.0
#: how far (MPa) outside the identified pressure range a prediction may go before it counts
#: as extrapolation
EXTRAPOLATION_TOLERANCE_MPa = 0.005
#: campaigns with fewer samples than this fit a base law in this process (see fit_runs)
PARALLEL_MIN_SAMPLES = 400_000
#: pressure-law methods: "joint" (refined, the default) or "per-run" (the seeds' quadratics)
PRESSURE_MODELS = ("joint", "per-run")


# --------------------------------------------------------------------------- models
def resolve_effects(ids: Sequence[str], files: Sequence[str] = ()) -> list:
    """Effect instances for ``ids`` (built-in or from user ``files``)."""
    if not ids and not files:
        return []
    try:
        from pmalab.identify.effects import get_effect, load_user_effects  # type: ignore[attr-defined]
    except ImportError:
        raise PmalabError(
            "effects are not available yet: pmalab.identify.effects has no "
            "get_effect/load_user_effects registry"
        ) from None
    for f in files:
        load_user_effects(f)
    return [get_effect(i) for i in ids]


@dataclass(frozen=True)
class ModelSpec:
    """A picklable recipe for a :class:`ForceModel`: law name, effect ids, user effect files."""

    law: str
    effects: tuple[str, ...] = ()
    effects_files: tuple[str, ...] = ()

    def build(self) -> ForceModel:
        return ForceModel(self.law, resolve_effects(self.effects, self.effects_files))


def _as_model(model: ForceModel | ModelSpec | str) -> ForceModel:
    if isinstance(model, ForceModel):
        return model
    if isinstance(model, ModelSpec):
        return model.build()
    return ForceModel(model)


def check_free(model: ForceModel, free: Sequence[str]) -> None:
    """Refuse a ``free`` (``--free``) name the model does not hold fixed by default: a typo
    or an already fitted parameter would otherwise be ignored without a word."""
    held = model.held_fixed()
    for name in free:
        if name not in held:
            fixes = f"fixes only {', '.join(held)}" if held else "fixes no parameter"
            raise PmalabError(
                f"--free {name}: model {model.name} {fixes} by default; "
                "every other parameter is fitted already"
            )


# --------------------------------------------------------------------------- results
@dataclass
class RunFit:
    """One identification run's fit with the run's identity."""

    file: str
    run: str
    p_nom: float
    frequency_Hz: float | None
    waveform: str
    result: FitResult

    @property
    def label(self) -> str:
        from pathlib import Path

        return f"{Path(self.file).name}:{self.run}" if self.file else self.run


@dataclass
class CampaignFit:
    """Per-run fits plus pressure quadratics: a model of the muscle over pressure."""

    model: ForceModel
    runs: list[RunFit]
    pressure: dict[str, PressureFit]
    warnings: list[str] = field(default_factory=list)
    #: "joint" (pressure laws refined on all runs at once) or "per-run" quadratics
    pressure_model: str = "per-run"
    #: the joint refinement (None when not done)
    joint: JointFit | None = None
    #: the per-run weighted quadratics (the seeds' method; the joint fit's start)
    per_run_pressure: dict[str, PressureFit] = field(default_factory=dict)
    #: the per-run-quadratic model's mean nrmse on the (subsampled) identification runs
    per_run_nrmse: list[float] = field(default_factory=list)
    #: the output-error refinement on the simulated position (``identify --output
    #: position``; :mod:`pmalab.identify.estimation.output_error`), None for force output
    output_error: OutputErrorFit | None = None
    #: the law's shared shape (``HysteresisLaw.shared_shape``) the campaign held on every
    #: run, at its reference run's values (empty when the law has none or the user fixed it)
    shape_reference: dict[str, float] = field(default_factory=dict)
    #: the pressure structure the campaign chose for the law's elements
    #: (:class:`~pmalab.identify.campaign.structure.StructureChoice`; None: not chosen)
    structure: Any = None

    @property
    def output(self) -> str:
        """The output the model was fitted on: ``"force"`` or ``"position"``."""
        return "force" if self.output_error is None else "position"

    @property
    def parameter_names(self) -> list[str]:
        return self.runs[0].result.params.names() if self.runs else []

    @property
    def pressure_range(self) -> tuple[float, float]:
        """(lowest, highest) identified nominal pressure, MPa."""
        ps = [r.p_nom for r in self.runs]
        return (min(ps), max(ps)) if ps else (float("nan"), float("nan"))

    def extrapolates(self, p: float) -> bool:
        """True when ``p`` (MPa) lies outside the identified pressure range."""
        lo, hi = self.pressure_range
        return bool(p < lo - EXTRAPOLATION_TOLERANCE_MPa or p > hi + EXTRAPOLATION_TOLERANCE_MPa)

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """Each parameter's (lo, hi): the widest of the per-run fits' bounds."""
        return parameter_bounds(self.runs)

    def theta(self, p: float) -> dict[str, float]:
        """Parameters at nominal pressure ``p`` (MPa) from the pressure laws (h0 = 0).

        Every value is clipped into the law's bounds: a quadratic evaluated away from the
        levels it was fitted on (extrapolation) can leave them.
        """
        bounds = self.bounds
        th = {}
        for name, pf in self.pressure.items():
            v = float(pf(p))
            lo, hi = bounds.get(name, (-np.inf, np.inf))
            th[name] = float(min(max(v, lo), hi)) if np.isfinite(v) else v
        for s in self.model.record_params:
            th[s] = 0.0  # record parameters (h0, nuisance) belong to another run
        return th

    def record_prior(self) -> dict[str, tuple[float, float]]:
        """Per effect nuisance parameter (a drift rate; not h0 nor a record's zero): the
        mean and spread of its values over the identification runs — what the campaign says
        a record's value is before the record is seen (its prior, mean ± sd; the sd at least
        10 % of |mean| or 1e-9).  A predicted record's value is estimated on its early part
        pulled toward this prior (:func:`~pmalab.identify.estimation.records.estimate_record`)."""
        names = [n for n in self.model.record_params if n not in self.model.state_params]
        out: dict[str, tuple[float, float]] = {}
        for n in names:
            if self.joint is not None and n in self.joint.nuisance:
                vals = np.asarray(self.joint.nuisance[n], dtype=float)
            else:
                vals = np.asarray(
                    [rf.result.params[n].value for rf in self.runs if n in rf.result.params],
                    dtype=float,
                )
            vals = vals[np.isfinite(vals)]
            if vals.size == 0:
                continue
            mu = float(np.mean(vals))
            sd = float(np.std(vals, ddof=1)) if vals.size > 1 else abs(mu)
            out[n] = (mu, max(sd, 0.1 * abs(mu), 1e-9))
        return out

    def predict(
        self,
        run: Run | Signals,
        p_nom: float | None = None,
        *,
        force: np.ndarray | None = None,
        initial: str = "estimate",
    ) -> np.ndarray:
        """Free-run force (N) of ``run`` from its position and pressure (see module doc).

        The record parameters (h0, effect nuisances, a drifting zero) are set by ``initial``
        (:mod:`pmalab.identify.estimation.records`: by default estimated on the record
        itself with every muscle parameter held).
        """
        if isinstance(run, Run):
            force = run.force if force is None else force
            sig = Signals.from_run(run)
        else:
            sig = run
        p = sig.p_nom if p_nom is None else float(p_nom)
        return predict_record(
            self.model,
            sig,
            self.theta(p),
            force=force,
            initial=initial,
            bounds=self.bounds,
            prior=self.record_prior(),
        )

    def validate(self, run: Run, initial: str = "estimate") -> dict:
        """Metrics of this model's free-run prediction of ``run``."""
        sig = Signals.from_run(run)
        fm = self.predict(sig, force=run.force, initial=initial)
        i0 = scored_from(sig, initial)  # after the early part the record was set on
        return metrics(run.force[i0:], fm[i0:], sig.x[i0:])


def predict_run(campaign_fit: CampaignFit, run: Run) -> np.ndarray:
    """The pressure-quadratic model's free-run force prediction (N) of ``run``."""
    return campaign_fit.predict(run)


# --------------------------------------------------------------------------- fitting
def parameter_bounds(rfs: Sequence[RunFit]) -> dict[str, tuple[float, float]]:
    """Each parameter's (lo, hi) over the runs' fits (data-sized bounds differ per run)."""
    out: dict[str, tuple[float, float]] = {}
    for rf in rfs:
        for p in rf.result.params:
            lo, hi = out.get(p.name, (np.inf, -np.inf))
            out[p.name] = (min(lo, p.lo), max(hi, p.hi))
    return out


def _fit_task(args: tuple) -> FitResult:
    run, model, kwargs = args
    m = _as_model(model)
    res = fit_run(run, m, **kwargs)
    res.model = None  # type: ignore[assignment]  # re-attached by the parent (pickling)
    return res


def _fit_task_remembering(args: tuple) -> tuple[FitResult, dict]:
    """:func:`_fit_task`, and the base fits it remembered (:func:`map_split`'s child hands
    them back, so the parent holds what fitting in process would hold)."""
    return with_new_base_fits(lambda: _fit_task(args))


def _fit_here(tasks: list[tuple], progress: bool) -> list[FitResult]:
    """:func:`_fit_task` on every task in this process — or, in a kept pool's worker whose
    sibling waits for work, partly in that sibling (:func:`map_shared`: the same results,
    and the base fits it made kept here as if made here)."""
    if progress or not sharing_here():
        return map_tasks(_fit_task, tasks, jobs=1, progress=progress, desc="identify")
    out = []
    for res, remembered in map_shared(_fit_task_remembering, tasks):
        remember_base_fits(remembered)
        out.append(res)
    return out


def _run_meta(run: Run) -> tuple[float, float | None, str]:
    return run.nominal_pressure, run.frequency, str(run.attrs.get("waveform", ""))


def fit_runs(
    runs: Sequence[Run],
    model: ForceModel | ModelSpec | str,
    *,
    jobs: int = 1,
    scheduler: str | None = None,
    progress: bool = False,
    per_run_kwargs: Sequence[dict] | None = None,
    **kwargs,
) -> list[FitResult]:
    """:func:`fit_run` on every run, in parallel; results in run order."""
    fm = _as_model(model)
    ship: ForceModel | ModelSpec | str = model
    if isinstance(model, ForceModel) and (jobs > 1 or scheduler):
        try:
            pickle.dumps(model)
        except Exception:
            jobs, scheduler = 1, None  # a user model that cannot be shipped: run here
    kw = per_run_kwargs or [{} for _ in runs]
    tasks = [(r, ship, {**kwargs, **k}) for r, k in zip(runs, kw)]
    if not scheduler and sum(len(r) for r in runs) < PARALLEL_MIN_SAMPLES and not fm.effects:
        # the base law fits a decimated record in ~10 ms: a pool's start and shipping the
        # runs cost more than that; a fork after the first fit (numba loaded) does not
        if jobs > 1 and not progress:
            out = []
            for res, remembered in map_split(_fit_task_remembering, tasks):
                remember_base_fits(remembered)
                out.append(res)
        else:
            out = _fit_here(tasks, progress)
    elif jobs <= 1 and not scheduler:
        out = _fit_here(tasks, progress)
    else:
        out = map_tasks(
            _fit_task, tasks, jobs=jobs, scheduler=scheduler, progress=progress, desc="identify"
        )
    for r, res in zip(runs, out):
        res.model = fm
        res.label = r.label
    return out


def fit_campaign(
    runs: Sequence[Run],
    model: ForceModel | ModelSpec | str,
    *,
    fixed: dict[str, float | None] | None = None,
    init: dict[str, float] | None = None,
    free: Sequence[str] = (),
    jobs: int = 1,
    scheduler: str | None = None,
    progress: bool = False,
    pressure_model: str = "joint",
    structure: str = "auto",
) -> CampaignFit:
    """Fit every run, make the fixes consistent, fit the pressure laws.

    ``structure``: the pressure structure of an element law's elements — ``"auto"`` (chosen
    by leave-one-pressure-out evidence, :mod:`pmalab.identify.campaign.structure`),
    ``"free"`` (every parameter its own pressure law) or one the law offers.

    ``pressure_model``: ``"joint"`` (default) refines the per-run quadratics jointly on all
    runs with chosen orders (:mod:`pmalab.identify.estimation.joint`); ``"per-run"`` keeps the seeds'
    stderr-weighted quadratics through the per-run values.
    """
    if pressure_model not in PRESSURE_MODELS:
        raise PmalabError(
            f"pressure_model must be one of {', '.join(PRESSURE_MODELS)}, not {pressure_model!r}"
        )
    if not runs:
        raise PmalabError("no identification runs given")
    fm = _as_model(model)
    check_free(fm, free)
    if structure not in ("auto", "free", *fm.law.structures):
        offers = ", ".join(["free", *fm.law.structures])
        raise PmalabError(f"--structure {structure}: {fm.law.name} offers {offers}")
    kwargs = {"fixed": fixed, "init": init, "free": tuple(free)}
    results = fit_runs(runs, model, jobs=jobs, scheduler=scheduler, progress=progress, **kwargs)
    warnings: list[str] = list(default_fixed_notes(fm, free))
    if fm.tares:
        warnings.append(note("tare", TARE_NOTE))

    # consistency: a collinear parameter fixed on most runs is fixed on all
    defaults = set(fm.law.default_fixed) - set(free)
    user_fixed = set(fixed or {})
    for name, value in fm.law.collinear_fixes:
        auto = [
            i
            for i, r in enumerate(results)
            if name in r.fixed and name not in defaults and name not in user_fixed
        ]
        if not auto:
            continue
        if 2 * len(auto) >= len(results):
            redo = [i for i in range(len(results)) if name not in results[i].fixed]
            if redo:
                fx = {**(fixed or {}), name: value}
                again = fit_runs(
                    [runs[i] for i in redo],
                    model,
                    jobs=jobs,
                    scheduler=scheduler,
                    progress=progress,
                    fixed=fx,
                    init=init,
                    free=tuple(free),
                    auto_fix=False,
                )
                for i, r in zip(redo, again):
                    r.warnings.append(
                        detail(
                            "consistent-fix",
                            f"{name} fixed at {value:g} on every run for "
                            f"consistent pressure quadratics (collinear on {len(auto)} of "
                            f"{len(results)} runs)",
                            name=name,
                            value=value,
                        )
                    )
                    results[i] = r
            warnings.append(
                note(
                    "collinear-fix-all",
                    f"{name} fixed at {value:g} on all runs: collinear with "
                    f"another parameter on {len(auto)} of {len(results)} runs (see run warnings)",
                    name=name,
                    value=value,
                    runs=len(auto),
                )
            )
        else:
            warnings.append(
                f"{name} was fixed at {value:g} on {len(auto)} of {len(results)} runs "
                "only (collinear there); its quadratic mixes fixed and fitted values"
            )

    results, shape_ref, shape_notes = share_shape(
        fm, runs, results, kwargs, jobs=jobs, scheduler=scheduler, progress=progress
    )
    warnings += shape_notes

    rfs = []
    for run, res in zip(runs, results):
        p, f, w = _run_meta(run)
        rfs.append(
            RunFit(file=run.file, run=run.name, p_nom=p, frequency_Hz=f, waveform=w, result=res)
        )
    for rf in rfs:
        if rf.result.fit_percent < POOR_FIT_PERCENT:
            warnings.append(
                f"{rf.label}: fit only {rf.result.fit_percent:.1f} % — {fm.name} misses something "
                "on this run (see `pmalab diagnose`); it enters the pressure laws with a "
                "weight reduced accordingly (its own rmse)"
            )
    pressure = pressure_fits(rfs)
    levels = sorted({round(r.p_nom, 4) for r in rfs})
    if len(levels) < 3:
        warnings.append(
            f"only {len(levels)} pressure level(s) ({', '.join(f'{p:g}' for p in levels)} "
            "MPa): quadratics reduced to degree "
            f"{max(len(levels) - 1, 0)}; extrapolating in pressure is unreliable"
        )
    cf = CampaignFit(
        model=fm,
        runs=rfs,
        pressure=pressure,
        warnings=warnings,
        per_run_pressure=pressure,
        shape_reference=shape_ref,
    )
    if pressure_model == "joint" and len(rfs) > 1:
        refine_pressure_laws(cf, runs)
    if fm.law.structures and structure != "free" and len(rfs) > 1:
        from pmalab.identify.campaign.structure import choose_structure

        choose_structure(cf, runs, fixed=fixed, structure=structure, jobs=jobs, scheduler=scheduler)
    return cf


#: two elements whose slip displacements differ by less than this factor are one element
#: split in two (a degenerate fit) when a shape reference is chosen
SHAPE_DISTINCT = 1.2
#: reference shapes tried (each is one more pass of per-run fits)
SHAPE_CANDIDATES = 3


def share_shape(
    model: ForceModel,
    runs: Sequence[Run],
    results: list[FitResult],
    kwargs: dict,
    *,
    jobs: int = 1,
    scheduler: str | None = None,
    progress: bool = False,
) -> tuple[list[FitResult], dict[str, float], list[str]]:
    """Hold the law's shared shape at one reference run's values on every run.

    A law's ``shared_shape`` (Maxwell-slip's slip displacements) is a material property, the
    same at every pressure, but each run fits it on its own: its elements come out in any
    order, and on a short stroke an element that never slides takes any value — per-run
    values of the *other* parameters then belong to different elements and their pressure
    laws interpolate nonsense between levels.  The reference is the run on which the most
    distinct elements slide (2·d < stroke; two within a factor 1.2 count once), and among
    those the lowest fit nrmse; the best three such runs (distinct shapes) are each held on
    every run, in the law's canonical element order, and the one all runs fit best is kept.
    The joint fit then refines them as constants in p.  Returns (results, the reference values, notes).  Nothing is done when the law has no
    shared shape, the user fixed it, or there is one run.
    """
    law = model.law
    user_fixed = set(kwargs.get("fixed") or {})
    names = [n for n in law.shared_shape if n not in user_fixed]
    if not names or len(results) < 2:
        return results, {}, []
    strokes = np.array([float(np.ptp(r.position)) for r in runs])

    def distinct(i: int) -> int:
        """Elements that slide on run i (2·d < stroke) and are not a copy of a smaller one."""
        th = law.canonical(results[i].values)
        d = [float(th[n]) for n in names if 2.0 * float(th[n]) < strokes[i]]
        return sum(1 for j, v in enumerate(d) if j == 0 or v > SHAPE_DISTINCT * d[j - 1])

    # candidates: the runs with the most distinct sliding elements, best fit first (a
    # first-pass fit can still be degenerate in ways the count misses, e.g. an element of
    # near-zero slip displacement standing in for an offset), shapes within 5 % merged
    order = sorted(range(len(runs)), key=lambda i: (-distinct(i), results[i].nrmse))
    cands: list[tuple[int, dict[str, float]]] = []
    for i in order:
        th = law.canonical(results[i].values)
        shape = {n: float(th[n]) for n in names}
        if any(all(abs(shape[n] / max(c[n], 1e-12) - 1.0) < 0.05 for n in names) for _, c in cands):
            continue
        cands.append((i, shape))
        if len(cands) == SHAPE_CANDIDATES:
            break
    # each candidate held on every run; the one the runs fit best (mean nrmse²) is kept —
    # scored by the same per-run fit identify reports.  The shape is the law's: with
    # effects in the model the candidates are scored by the law alone (an effect's
    # multi-start fits made each pass of a model with a delay cost ~4 s), and the model
    # with its effects is fitted once, with the chosen shape
    scorer = ForceModel(law) if model.effects else model
    base_names = {*(lp.name for lp in law.params), "k", "c0"}

    def refit(m: ForceModel, shape: dict[str, float]) -> list[FitResult]:
        """Every run fitted by ``m`` with ``shape`` held (the user's fixes, start values
        and frees that ``m`` has)."""
        own = m is model
        return fit_runs(
            runs,
            m,
            jobs=jobs,
            scheduler=scheduler,
            progress=progress,
            fixed={
                **{k: v for k, v in (kwargs.get("fixed") or {}).items() if own or k in base_names},
                **shape,
            },
            init=kwargs.get("init") if own else None,
            free=[n for n in kwargs.get("free", ()) if own or n in base_names],
        )

    best: tuple[float, int, dict[str, float], list[FitResult]] | None = None
    for i, shape in cands:
        again = refit(scorer, shape)
        score = float(np.mean([r.nrmse**2 for r in again]))
        if best is None or score < best[0]:
            best = (score, i, shape, again)
    assert best is not None
    _, ref_i, ref, again = best
    if scorer is not model:
        again = refit(model, ref)
    rise = max(b.nrmse / max(a.nrmse, 1e-300) - 1.0 for a, b in zip(results, again))
    values = ", ".join(f"{n} {v:.3g}" for n, v in ref.items())
    label = getattr(runs[ref_i], "label", str(ref_i))
    notes: list[str] = [
        note(
            "shared-shape",
            f"{law.name}: {', '.join(names)} are the same at every pressure (a material "
            f"property): held at {label}'s values ({values}) on every run, then refined "
            f"jointly as constants (per-run nrmse rose by at most {100.0 * rise:.1f} %)",
            reference=label,
            values=ref,
            rise_percent=100.0 * rise,
        )
    ]
    return again, ref, notes


def _undetermined(res: FitResult, name: str) -> bool:
    """Was ``name`` poorly determined on this run (collinear, at a bound, no stderr)?"""
    p = res.params[name]
    if not p.vary or p.stderr is None or not np.isfinite(p.stderr):
        return True
    span = p.hi - p.lo
    if np.isfinite(span) and min(p.value - p.lo, p.hi - p.value) <= 1e-6 * span:
        return True
    if name in res.names:
        i = res.names.index(name)
        for j, other in enumerate(res.names):
            if j == i or {name, other} == {"k", "c0"}:
                continue  # k–c0: an artefact of c0 being extrapolated to x = 0 (see fit.py)
            if abs(float(res.correlation[i, j])) > RHO_LIMIT_JOINT:
                return True
    return False


#: the joint laws are kept unless their mean training nrmse exceeds the per-run quadratics'
#: by this factor
JOINT_TOLERANCE = 1.02
#: a parameter collinear beyond this with another on a run is "undetermined" there
RHO_LIMIT_JOINT = 0.95


def refine_pressure_laws(cf: CampaignFit, runs: Sequence[Run]) -> None:
    """Replace ``cf.pressure`` by the jointly refined laws (in place; see module doc).

    Parameters fixed on every run stay constants; each free parameter's order comes from
    :func:`pmalab.identify.estimation.joint.start_laws`, then the joint fit (with per-run h0)
    refines the coefficients and prunes unsupported orders.  Every choice is recorded in
    ``cf.warnings``.
    """
    rfs = cf.runs
    names = cf.parameter_names
    results = [rf.result for rf in rfs]
    # record nuisance parameters (e.g. a drift rate): one value per run, like h0
    state = cf.model.state_params
    nuis_names = [
        n
        for n in cf.model.record_params
        if n not in state and n in names and any(r.params[n].vary for r in results)
    ]
    if cf.model.tares and "c0" in names and any(r.params["c0"].vary for r in results):
        # a drifting zero: each record's force offset differs by the drift accumulated
        # before it, which c0's pressure law would absorb (the runs of a campaign are
        # recorded in pressure order, so time trends look like pressure trends).  c0 is then
        # a per-run parameter of the joint fit; its per-run quadratic is kept for prediction
        # and every predicted run gets its own (estimation.records).
        nuis_names.append("c0")
    nuisance = {n: [float(r.params[n].value) for r in results] for n in nuis_names}
    shape = cf.shape_reference  # held by the campaign, refined here as constants in p
    constants = {
        n: float(results[0].params[n].value)
        for n in names
        if n not in state
        and n not in nuisance
        and n not in shape
        and all(not r.params[n].vary for r in results)
    }
    free = [n for n in names if n not in constants and n not in state and n not in nuisance]
    if not free:
        return
    has_h0 = "h0" in names and any(r.params["h0"].vary for r in results)
    bounds = parameter_bounds(rfs)
    pressures = [rf.p_nom for rf in rfs]
    levels = len({round(p, 4) for p in pressures})
    values = {n: [r.params[n].value for r in results] for n in free}
    stderr = {n: [r.params[n].stderr for r in results] for n in free}
    und = {n: [_undetermined(r, n) for r in results] for n in free}
    start, degrees, notes = start_laws(
        [n for n in free if n not in shape],
        pressures,
        values,
        stderr,
        und,
        max_degree=min(2, levels - 1),
    )
    for n in shape:
        start[n], degrees[n] = (shape[n], 0.0, 0.0), 0
    jruns = [prepare(r, rf.result.rmse) for r, rf in zip(runs, rfs)]
    h0 = [float(r.params["h0"].value) for r in results] if has_h0 else None
    try:
        # the plain per-run quadratics are a second start (the brief's order: they may be
        # the better start when the per-run values are well determined)
        plain = ({n: cf.pressure[n].coef for n in free}, {n: cf.pressure[n].degree for n in free})
        joint, jnotes = refine(
            cf.model,
            jruns,
            start,
            degrees,
            constants,
            bounds,
            h0,
            alternatives=[plain],
            nuisance_start=nuisance or None,
            fixed_order=[n for n in (*cf.model.campaign_shared, *shape) if n in free],
            # an element law's pressure structure is chosen on this evidence (.structure)
            lopo=bool(cf.model.law.structures or cf.model.law.structure_of),
        )
    except (ValueError, np.linalg.LinAlgError) as exc:  # keep the per-run quadratics
        cf.warnings.append(
            f"joint refinement of the pressure laws failed ({exc}); using the per-run quadratics"
        )
        return
    per_run = evaluate(
        cf.model,
        jruns,
        {n: cf.pressure[n].coef for n in free},
        constants,
        bounds,
        h0,
        nuisance or None,
    )
    cf.per_run_nrmse = per_run
    # a sanity check: the joint fit starts from (among others) the per-run quadratics, so it
    # only ends above them by the BIC-accepted order pruning (a small, deliberate loss)
    if not np.isfinite(joint.mean_nrmse) or joint.mean_nrmse > JOINT_TOLERANCE * float(
        np.mean(per_run)
    ):
        cf.warnings.append(
            f"joint refinement did not improve on the per-run quadratics (mean nrmse "
            f"{joint.mean_nrmse:.4f} vs {float(np.mean(per_run)):.4f}); using the per-run quadratics"
        )
        return
    new: dict[str, PressureFit] = {}
    for n, pf in cf.pressure.items():
        if n in joint.coef:
            q = joint.coef[n]
            fitted = [q[0] + q[1] * p + q[2] * p * p for p in pf.pressures]
            r2, resid = weighted_r2(pf.values, fitted, pf.stderr)
            new[n] = PressureFit(
                name=n,
                coef=q,
                degree=joint.degree[n],
                r2=r2,
                pressures=pf.pressures,
                values=pf.values,
                stderr=pf.stderr,
                residuals=resid,
                method="joint",
                per_run_coef=pf.coef,
                per_run_r2=pf.r2,
                per_run_degree=pf.degree,
            )
        elif n in constants:
            new[n] = replace(
                pf,
                coef=(constants[n], 0.0, 0.0),
                degree=0,
                method="joint",
                per_run_coef=pf.coef,
                per_run_r2=pf.r2,
                per_run_degree=pf.degree,
            )
        else:
            new[n] = pf  # h0 / record nuisance: per-run, never used for prediction
    cf.pressure = new
    cf.joint = joint
    cf.pressure_model = "joint"
    orders = ", ".join(f"{n} {joint.degree[n]}" for n in free)
    per = ", ".join(["h0"] * bool(h0 is not None) + nuis_names) or "none"
    cf.warnings.append(
        note(
            "joint-refined",
            f"pressure laws refined jointly on all {len(rfs)} runs (free-run error, per-run {per}): "
            f"mean nrmse {float(np.mean(per_run)):.4f} with the per-run quadratics -> "
            f"{joint.mean_nrmse:.4f}; orders in p: {orders}",
            nrmse_per_run_quadratics=float(np.mean(per_run)),
            nrmse=joint.mean_nrmse,
            orders=dict(joint.degree),
        )
    )
    cf.warnings += notes + jnotes
    if not joint.success:
        cf.warnings.append(f"joint refinement stopped early: {joint.message}")


def pressure_fits(rfs: Sequence[RunFit]) -> dict[str, PressureFit]:
    """θ(p) quadratic for every parameter over the runs' nominal pressures."""
    out: dict[str, PressureFit] = {}
    names = rfs[0].result.params.names()
    pressures = [r.p_nom for r in rfs]
    for name in names:
        vals = [r.result.params[name].value for r in rfs]
        ses = [r.result.params[name].stderr for r in rfs]
        out[name] = fit_quadratic(name, pressures, vals, ses)
    return out


# --------------------------------------------------------------------------- output error
def refine_output_error(cf: CampaignFit, runs: Sequence[Run]) -> CampaignFit:
    """``cf`` with its pressure laws refined on the simulated position of ``runs`` (the
    identification runs, same order): :mod:`pmalab.identify.estimation.output_error`.  The
    force-direction fit is the start; the orders in pressure stay the ones it chose."""
    from pmalab.identify.forward import plant_slots

    model = cf.model
    plant_slots(model)  # refuses an effect without a forward form, by name
    fixed = set(cf.runs[0].result.fixed) if cf.runs else set()
    record = set(model.record_params)
    free = {n: pf.coef for n, pf in cf.pressure.items() if n not in fixed and n not in record}
    held = {n: pf.coef for n, pf in cf.pressure.items() if n in fixed and n not in record}
    degree = {n: int(cf.pressure[n].degree) for n in free}
    data = [position_data(r.label, Signals.from_run(r), r.force, r.position) for r in runs]
    h0 = [float(rf.result.values.get("h0", 0.0)) for rf in cf.runs]
    oe = fit_output_error(model, data, free, degree, held, h0, cf.bounds)
    pressure = {}
    for n, pf in cf.pressure.items():
        if n not in oe.coef:
            pressure[n] = pf
            continue
        q = oe.coef[n]
        vals = [float(q[0] + q[1] * p + q[2] * p * p) for p in pf.pressures]
        pressure[n] = replace(
            pf,
            coef=tuple(q),
            values=vals,
            method="output-error",
            stderr=[oe.stderr.get(n)] * len(vals),
            residuals=[0.0] * len(vals),
        )
    # the per-run force fits were the start: their warnings are about that start
    tag = "force-direction start (refined by output error): "
    runs_out = [
        replace(
            rf, result=replace(rf.result, warnings=[prefixed(tag, w) for w in rf.result.warnings])
        )
        for rf in cf.runs
    ]
    return replace(
        cf,
        pressure=pressure,
        pressure_model="output-error",
        output_error=oe,
        runs=runs_out,
        warnings=[*cf.warnings, *oe.notes],
    )
