"""A campaign: per-run fits, pressure quadratics, and the pressure-parametrised model.

``fit_campaign(runs, model)`` fits every identification run (in parallel, see
:mod:`pmalab.identify.batch`), makes the fixes consistent across runs (a parameter the fits
had to fix for collinearity on most runs is fixed on all, so the quadratics are not fed a
mix), and fits θ(p) = q0 + q1·p + q2·p² for every parameter.

The pressure-parametrised model predicts *any* run from its measured position and muscle
pressure (:func:`predict_run`): the parameters are evaluated at the run's nominal pressure
(θ(p_nom)); effects that use the measured pressure trace get it through the signals; the
start state h0 comes from a one-cycle burn-in (h0 is the start state of one run, not a
property of the muscle, so its quadratic is reported but never used).
"""

from __future__ import annotations

import pickle
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from pmalab.errors import PmalabError
from pmalab.identify.batch import map_tasks
from pmalab.identify.fit import (
    COLLINEAR_FIXES,
    DEFAULT_FIXED,
    STATE_PARAMS,
    FitResult,
    default_fixed_notes,
    fit_run,
    predict_free,
)
from pmalab.identify.model import ForceModel
from pmalab.identify.pressure import PressureFit, fit_quadratic
from pmalab.identify.signals import Signals
from pmalab.identify.validate import metrics
from pmalab.runfile import Run

#: identification runs fitted worse than this (fit %) are named in the campaign warnings
POOR_FIT_PERCENT = 90.0


# --------------------------------------------------------------------------- models
def resolve_effects(ids: Sequence[str], files: Sequence[str] = ()) -> list:
    """Effect instances for ``ids`` (built-in or from user ``files``)."""
    if not ids and not files:
        return []
    try:
        from pmalab.identify.effects import get_effect, load_user_effects  # type: ignore[attr-defined]
    except ImportError:
        raise PmalabError("effects are not available yet: pmalab.identify.effects has no "
                          "get_effect/load_user_effects registry") from None
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

    @property
    def parameter_names(self) -> list[str]:
        return self.runs[0].result.params.names() if self.runs else []

    def theta(self, p: float) -> dict[str, float]:
        """Parameters at nominal pressure ``p`` (MPa) from the quadratics (h0 = 0)."""
        th = {name: float(pf(p)) for name, pf in self.pressure.items()}
        for s in STATE_PARAMS:
            if s in th:
                th[s] = 0.0
        return th

    def predict(self, run: Run | Signals, p_nom: float | None = None, *,
                force: np.ndarray | None = None, initial: str = "estimate") -> np.ndarray:
        """Free-run force (N) of ``run`` from its position and pressure (see module doc).

        The start state h0 is estimated from the first 50 ms of the measured force when it
        is available (``initial``: see :func:`pmalab.identify.fit.predict_free`).
        """
        if isinstance(run, Run):
            force = run.force if force is None else force
            sig = Signals.from_run(run)
        else:
            sig = run
        p = sig.p_nom if p_nom is None else float(p_nom)
        return predict_free(self.model, sig, self.theta(p), force=force, initial=initial)

    def validate(self, run: Run, initial: str = "estimate") -> dict:
        """Metrics of this model's free-run prediction of ``run``."""
        sig = Signals.from_run(run)
        return metrics(run.force, self.predict(sig, force=run.force, initial=initial), sig.x)


def predict_run(campaign_fit: CampaignFit, run: Run) -> np.ndarray:
    """The pressure-quadratic model's free-run force prediction (N) of ``run``."""
    return campaign_fit.predict(run)


# --------------------------------------------------------------------------- fitting
def _fit_task(args: tuple) -> FitResult:
    run, model, kwargs = args
    m = _as_model(model)
    res = fit_run(run, m, **kwargs)
    res.model = None  # type: ignore[assignment]  # re-attached by the parent (pickling)
    return res


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
    out = map_tasks(_fit_task, tasks, jobs=jobs, scheduler=scheduler, progress=progress,
                    desc="identify")
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
) -> CampaignFit:
    """Fit every run, make the fixes consistent, fit the pressure quadratics."""
    if not runs:
        raise PmalabError("no identification runs given")
    fm = _as_model(model)
    kwargs = {"fixed": fixed, "init": init, "free": tuple(free)}
    results = fit_runs(runs, model, jobs=jobs, scheduler=scheduler, progress=progress, **kwargs)
    warnings = list(default_fixed_notes(fm, free))

    # consistency: a collinear parameter fixed on most runs is fixed on all
    defaults = set(DEFAULT_FIXED.get(fm.law.name, {})) - set(free)
    user_fixed = set(fixed or {})
    for name, value in COLLINEAR_FIXES.get(fm.law.name, []):
        auto = [i for i, r in enumerate(results) if name in r.fixed and name not in defaults
                and name not in user_fixed]
        if not auto:
            continue
        if 2 * len(auto) >= len(results):
            redo = [i for i in range(len(results)) if name not in results[i].fixed]
            if redo:
                fx = {**(fixed or {}), name: value}
                again = fit_runs([runs[i] for i in redo], model, jobs=jobs, scheduler=scheduler,
                                 progress=progress, fixed=fx, init=init, free=tuple(free),
                                 auto_fix=False)
                for i, r in zip(redo, again):
                    r.warnings.append(f"{name} fixed at {value:g} on every run for consistent "
                                      f"pressure quadratics (collinear on {len(auto)} of "
                                      f"{len(results)} runs)")
                    results[i] = r
            warnings.append(f"{name} fixed at {value:g} on all runs: collinear with another "
                            f"parameter on {len(auto)} of {len(results)} runs (see run warnings)")
        else:
            warnings.append(f"{name} was fixed at {value:g} on {len(auto)} of {len(results)} runs "
                            "only (collinear there); its quadratic mixes fixed and fitted values")

    rfs = []
    for run, res in zip(runs, results):
        p, f, w = _run_meta(run)
        rfs.append(RunFit(file=run.file, run=run.name, p_nom=p, frequency_Hz=f, waveform=w,
                          result=res))
    for rf in rfs:
        if rf.result.fit_percent < POOR_FIT_PERCENT:
            warnings.append(
                f"{rf.label}: fit only {rf.result.fit_percent:.1f} % — {fm.name} misses something "
                "on this run (see `pmalab diagnose`); its parameters enter the quadratics "
                "weighted by their (large) standard errors")
    pressure = pressure_fits(rfs)
    levels = sorted({round(r.p_nom, 4) for r in rfs})
    if len(levels) < 3:
        warnings.append(f"only {len(levels)} pressure level(s) ({', '.join(f'{p:g}' for p in levels)} "
                        "MPa): quadratics reduced to degree "
                        f"{max(len(levels) - 1, 0)}; extrapolating in pressure is unreliable")
    return CampaignFit(model=fm, runs=rfs, pressure=pressure, warnings=warnings)


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


def with_model(cf: CampaignFit, model: ForceModel) -> CampaignFit:
    """A copy bound to another (equivalent) model object."""
    return replace(cf, model=model)
