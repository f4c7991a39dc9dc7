"""The ladder: add the best significant effect, diagnose again, repeat.

Step 0 is the base law.  At every step each effect not yet in the model is fitted on top of
the current model (warm-started from the current fit, the new parameters at their neutral
values), scored on held-out data (:mod:`pmalab.identify.ranking`), and the best is added if
it is significant.  The ladder stops when nothing significant is left, when every effect
is in, or after ``max_steps`` additions.  The held-out nrmse of every step is the error
falling step by step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pmalab.identify.effects import get_effect
from pmalab.identify.ranking import (
    Candidate,
    FitOutcome,
    PreparedRun,
    build_model,
    campaign_value,
    effective_n,
    group_by_pressure,
    judge,
    run_tasks,
    score_candidate,
)


@dataclass
class LadderStep:
    """One rung: the effects in the model after this step and its held-out error."""

    step: int
    effects: list[str]
    added: str | None
    nrmse: float
    fits: list[FitOutcome] = field(default_factory=list, repr=False)
    scores: list[float] = field(default_factory=list, repr=False)

    @property
    def fit_percent(self) -> float:
        return 100.0 * (1.0 - self.nrmse)

    def as_json(self) -> dict:
        return {"step": self.step, "effects": list(self.effects), "added": self.added,
                "nrmse": float(self.nrmse), "fit_percent": float(self.fit_percent),
                "model": "+".join(self.effects) or "base"}


@dataclass
class Round:
    """The ranking of the remaining effects at one ladder step."""

    step: int
    candidates: list[Candidate]
    ambiguous: list[str]


# --------------------------------------------------------------------------- held-out scoring
def _quadratic(ps: np.ndarray, vals: np.ndarray) -> np.ndarray:
    deg = min(2, len(np.unique(np.round(ps, 3))) - 1)
    if deg <= 0:
        return np.array([float(np.median(vals))])
    return np.polyfit(ps, vals, deg)


def predict_validation(law: str, effects: Sequence[str], fits: Sequence[FitOutcome],
                       groups: Sequence[Sequence[PreparedRun]], val: PreparedRun) -> np.ndarray:
    """Free-run prediction (decimated grid) of a validation run from the training fits.

    Every parameter is a quadratic in the nominal muscle pressure across the training runs
    (DESIGN.md); the hysteretic start state comes from a one-cycle burn-in
    (:func:`pmalab.identify.fit.predict_free`).
    """
    from pmalab.identify.fit import predict_free

    model = build_model(law, effects)
    ps = np.array([pr.dsig.p_nom for g in groups for pr in g])
    thetas = [th for f in fits for th in f.thetas]
    theta = {}
    for name in thetas[0]:
        vals = np.array([th[name] for th in thetas])
        theta[name] = float(np.polyval(_quadratic(ps, vals), val.dsig.p_nom))
    return predict_free(model, val.dsig, theta)


def heldout_nrmse(law: str, effects: Sequence[str], fits: Sequence[FitOutcome],
                  groups: Sequence[Sequence[PreparedRun]], val: Sequence[PreparedRun]) -> list[float]:
    """Held-out nrmse per scored run: the validation runs if any, else each run's last part."""
    if not val:
        return [float(v) for f in fits for v in f.nrmse_val]
    out = []
    for v in val:
        pred = predict_validation(law, effects, fits, groups, v)
        sd = float(np.std(v.dforce))
        out.append(float(np.sqrt(np.mean((pred - v.dforce) ** 2)) / sd))
    return out


# --------------------------------------------------------------------------- the ladder
def _light(pr: PreparedRun) -> PreparedRun:
    """A copy without the full-rate arrays (what a worker process needs)."""
    return PreparedRun(key=pr.key, run=None, sig=None, dsig=pr.dsig, dforce=pr.dforce,  # type: ignore[arg-type]
                       fit_mask=pr.fit_mask, val_mask=pr.val_mask)


def run_ladder(
    train: Sequence[PreparedRun],
    law: str,
    effect_ids: Sequence[str],
    val: Sequence[PreparedRun] = (),
    max_steps: int = 3,
    jobs: int = 1,
    progress: bool = False,
) -> tuple[list[LadderStep], list[Round], list[list[int]]]:
    """Climb the ladder.

    Returns the steps (0 = base), the ranking round of each step, and the pressure groups
    (indices into ``train``) the fits were made on.
    """
    light = [_light(p) for p in train]
    gidx = group_by_pressure(light)
    groups = [[light[i] for i in g] for g in gidx]
    lval = [_light(v) for v in val]
    base = run_tasks([(g, law, (), None) for g in groups], jobs, progress, "base fits")
    base_scores = heldout_nrmse(law, (), base, groups, lval)
    steps = [LadderStep(0, [], None, float(np.mean(base_scores)), base, base_scores)]
    rounds: list[Round] = []
    current: tuple[str, ...] = ()
    #: campaign-wide parameters of the effects already in the model (held in every fit)
    fixed: dict[str, float] = {}
    while len(current) < max_steps:
        remaining = [e for e in effect_ids if e not in current]
        if not remaining:
            break
        cur = steps[-1].fits
        n_eff = [[effective_n((pred - pr.dforce)[pr.fit_mask]) for pred, pr in zip(f.preds, g)]
                 for f, g in zip(cur, groups)]
        tasks = [(g, law, (*current, e), f.thetas, fixed)
                 for e in remaining for g, f in zip(groups, cur)]
        outs = run_tasks(tasks, jobs, progress, f"step {len(steps)}: {len(remaining)} effects")
        n = len(groups)
        # effects with a rig property (e.g. a channel delay): one value for the whole
        # campaign, from the groups' estimates, then every group refitted with it held
        camp: dict[str, dict[str, float]] = {}
        refits = []
        for i, e in enumerate(remaining):
            names = tuple(getattr(get_effect(e), "campaign_shared", ()))
            if names and n > 1:
                fits = outs[i * n:(i + 1) * n]
                camp[e] = {nm: campaign_value(nm, fits) for nm in names}
                refits += [(g, law, (*current, e), f.thetas, {**fixed, **camp[e]})
                           for g, f in zip(groups, fits)]
        if refits:
            routs = run_tasks(refits, jobs, progress, "campaign-wide refits")
            j = 0
            for i, e in enumerate(remaining):
                if e in camp:
                    outs[i * n:(i + 1) * n] = routs[j:j + n]
                    j += n
        cands = []
        for i, e in enumerate(remaining):
            fits = outs[i * n:(i + 1) * n]
            scores = heldout_nrmse(law, (*current, e), fits, groups, lval)
            c = score_candidate(e, cur, fits, n_eff, steps[-1].scores, scores,
                                campaign_params=len(camp.get(e, {})))
            c.campaign = dict(camp.get(e, {}))
            cands.append(c)
        cands, amb = judge(cands)
        rounds.append(Round(len(steps), cands, amb))
        best = cands[0]
        if not best.significant:
            break
        fixed = {**fixed, **best.campaign}
        current = (*current, best.effect)
        steps.append(LadderStep(len(steps), list(current), best.effect, best.nrmse_after,
                                best.fits, best.scores))
    return steps, rounds, gidx
