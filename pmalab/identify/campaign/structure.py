"""The pressure structure of an element law, chosen by leave-one-pressure-out evidence.

A law's file says what its elements are; how they change with pressure is the muscle's
business (:mod:`pmalab.identify.laws.structures` lists the candidates: ``free``,
``scaled``, ``scaled-thresholds``).  A structure with many pressure laws fits each level
best and may predict other levels worst (per-weight quadratics follow each run's noise); one
with few may miss how the muscle really changes.  So the campaign asks the data:

**Criterion (leave-one-pressure-out, LOPO).**  Every candidate is refined jointly on all
identification runs (:mod:`pmalab.identify.estimation.joint`; a structured candidate starts
from the free structure's joint laws).  Then, for every *interior* identification pressure
level L (the lowest and highest are never left out: predicting them would be
extrapolation, which a campaign never promises), the joint problem without the runs at L is
stepped once from the joint solution (Gauss–Newton: the influence approximation of
refitting without them, :func:`pmalab.identify.estimation.joint.approx_lopo`) and the runs
at L predicted, their start states re-estimated on them.  A structure's score is the root
mean square of those held-out nrmse; the lowest wins.  A simpler structure (fewer
pressure-law coefficients) is preferred unless the richer one's score is lower by more than
``SIMPLER_WITHIN`` (relative): the choice never hinges on round-off.  Known leaks, the same
for every candidate: the pressure orders and a structured candidate's start profile come
from all runs.

**Priors.**  Each candidate is also fitted with a prior whose strength is chosen by the same
evidence (:func:`prior_rows`, :func:`apply_prior`): smoothness over a threshold grid
(Prandtl-Ishlinskii), shrinkage of the element corrections toward the pooled profile
(Maxwell-slip).  Every strength is one Gauss–Newton step of the penalised problem from the
candidate's joint solution, its leave-one-pressure-out error computed with the prior kept
in every fold; λ = 0 wins unless another strength is lower by more than ``SIMPLER_WITHIN``.
The candidate's score is its kept strength's.

The winner's pressure laws (refined jointly like any campaign's) replace the free ones,
mapped onto the base law's parameters (:func:`pmalab.identify.laws.structures.base_laws`),
so everything downstream (validation, reports, ``simulate``, controllers) reads the base
law.  :class:`StructureChoice` is what ``identification.json`` reports as
``pressure_structure``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pmalab.identify.schema import (
    PressureStructure,
    StructureCandidate,
    StructureElements,
    StructurePrior,
)
from pmalab.runfile import Run

#: a structure with fewer parameters wins unless a richer one's LOPO score is lower by more
#: than this fraction
SIMPLER_WITHIN = 0.01
#: function evaluations of a structured candidate's joint fit
CANDIDATE_NFEV = 120
#: pressure levels (distinct nominal pressures, rounded to 1 kPa) a LOPO choice needs: one
#: interior level left out still leaves ≥ 3 levels for a quadratic
MIN_LEVELS = 4
#: the starts of a structured candidate's joint fit, as ``identification.json`` names the
#: one kept (:func:`_joint_structured`)
STARTS = ("free laws", "per-run fits")
#: the second start is refined only when the first start's refined fit falls short of the
#: structured law's own per-run fits by more than the free joint laws fall short of the free
#: per-run fits, by this fraction of that excess (:func:`needs_second_start`).  A first start
#: stuck in a worse minimum is far beyond it (ms-slip-growing on two strokes per level:
#: 3.6-5.3 times the free laws' excess); a first start 1.4 times beyond it (an effect
#: candidate of the campaign tutorial's diagnose) gained 0.1 % from its second start
SECOND_START_MARGIN = 0.5


@dataclass
class StructureChoice:
    """Which pressure structure won, by how much, and each candidate's evidence."""

    law: str
    chosen: str
    criterion: str
    #: structure → RMS held-out nrmse over the left-out levels' runs
    scores: dict[str, float]
    #: structure → pressure-law coefficients of the muscle (k, c0 and the law's; no h0)
    n_params: dict[str, int]
    #: the levels (MPa) left out in turn
    folds: list[float]
    #: structure → held-out nrmse per left-out run, in fold order
    per_run: dict[str, list[float]] = field(default_factory=dict)
    #: structures whose fits failed → reason
    failed: dict[str, str] = field(default_factory=dict)
    #: structure → the prior its fit was given (strength chosen by the same evidence)
    priors: dict[str, Prior] = field(default_factory=dict)
    #: structure → how many elements it keeps (chosen by the same evidence), when fewer
    #: than the law's were tried
    elements: dict[str, ElementCount] = field(default_factory=dict)
    #: structure → the start its kept joint fit came from (:data:`STARTS`)
    starts: dict[str, str] = field(default_factory=dict)

    @property
    def margin_percent(self) -> float:
        """How much higher (%) the best other structure's score is than the winner's."""
        others = [v for k, v in self.scores.items() if k != self.chosen and np.isfinite(v)]
        if not others:
            return float("nan")
        return 100.0 * (min(others) / self.scores[self.chosen] - 1.0)

    def as_json(self) -> PressureStructure:
        cands: list[StructureCandidate] = []
        for s in [*self.scores, *[f for f in self.failed if f not in self.scores]]:
            c = StructureCandidate(
                structure=s,
                heldout_nrmse=self.scores.get(s),
                n_params=self.n_params.get(s),
                heldout_nrmse_per_run=list(self.per_run.get(s, [])),
            )
            if s in self.starts:
                c["start"] = self.starts[s]
            if s in self.failed:
                c["status"], c["reason"] = "failed", self.failed[s]
            cands.append(c)
        out = PressureStructure(
            law=self.law,
            chosen=self.chosen,
            criterion=self.criterion,
            margin_percent=self.margin_percent,
            levels_left_out_MPa=list(self.folds),
            candidates=cands,
        )
        if self.priors:
            out["priors"] = {k: v.as_json() for k, v in self.priors.items()}
        if self.elements:
            out["element_counts"] = {k: v.as_json() for k, v in self.elements.items()}
        return out

    def summary(self) -> str:
        """One line: the winner, its score and its margin."""
        cands = ", ".join(
            f"{s} {v:.4f} ({self.n_params[s]} p.)"
            for s, v in sorted(self.scores.items(), key=lambda kv: kv[1])
        )
        tail = "" if self.chosen == "free" else "; its pressure laws replace the free ones"
        if self.chosen in self.elements:
            tail += f"; {self.elements[self.chosen].summary()}"
        if self.chosen in self.priors:
            tail += f"; {self.priors[self.chosen].what}: {self.priors[self.chosen].summary()}"
        return (
            f"{self.law}: pressure structure '{self.chosen}' chosen by leave-one-pressure-out "
            f"held-out nrmse ({cands}; {margin_words(self.margin_percent) or 'one candidate'})"
            f"{tail}"
        )


def levels_of(pressures: Sequence[float] | np.ndarray) -> list[float]:
    """Distinct nominal pressure levels (MPa, rounded to 1 kPa), ascending."""
    return sorted({round(float(p), 3) for p in pressures})


def margin_words(margin_percent: float | None) -> str:
    """A structure choice's margin in words, or ``""`` when there is none (one candidate).

    ``margin_percent`` (:attr:`StructureChoice.margin_percent`): how much higher (%) the
    best other candidate's held-out nrmse is than the winner's — negative when the winner
    was kept as the simpler one within ``SIMPLER_WITHIN`` of a better-scoring candidate,
    which is then said ("kept as the simpler, 0.026 % behind the best, ..."), never
    "-0 % ahead".

    Parameters
    ----------
    margin_percent
        The margin (%), None or NaN when the winner had no rival.

    Returns
    -------
    str
        E.g. ``"2.6 % ahead"``.
    """
    m = margin_percent
    if m is None or not np.isfinite(m):
        return ""

    def pct(a: float) -> str:
        return f"{a:.2g}" if a < 1.0 else f"{a:.1f}" if a < 10.0 else f"{a:.0f}"

    if m < 0.0:
        return (
            f"kept as the simpler, {pct(-m)} % behind the best, within the "
            f"{100 * SIMPLER_WITHIN:g} % allowed"
        )
    return f"{pct(m)} % ahead"


def pick(scores: Mapping[str, float], n_params: Mapping[str, int]) -> str:
    """The winner: the lowest score, unless a structure with fewer parameters is within
    ``SIMPLER_WITHIN`` of it (then the simplest such)."""
    ok = {s: v for s, v in scores.items() if np.isfinite(v)}
    best = min(ok, key=lambda s: ok[s])
    near = [s for s, v in ok.items() if v <= ok[best] * (1.0 + SIMPLER_WITHIN)]
    return min(near, key=lambda s: (n_params[s], ok[s]))


def choose_structure(
    cf,
    runs: Sequence[Run],
    *,
    fixed: Mapping[str, float | None] | None = None,
    structure: str = "auto",
    jobs: int = 1,
    scheduler: str | None = None,
) -> StructureChoice | None:
    """Choose ``cf``'s pressure structure (``"auto"``: by LOPO; or the one named) and, when it
    is not ``"free"``, replace ``cf.pressure``'s laws by the winner's (in place; see module
    doc).  Returns the choice (also in ``cf.structure``); None when the law offers no
    structures, the campaign has too few levels, its pressure laws were not refined jointly
    (the evidence is the joint fit's), or the user fixed element parameters.

    Each structured candidate is a joint fit on the free campaign's records from up to two
    starts, the lower training cost kept (:func:`_joint_structured`; the second is refined
    only when the first's fit falls short of what the data allow,
    :func:`needs_second_start`): the free structure's joint laws
    (k, c0 and the effects' laws as they are, the magnitude s(p) through the free laws'
    summed element stiffness, t = 1, the profile corrections 1), and the structured law's
    own per-run fits (:func:`per_run_laws`: s, t and h0 on every run, the profile held;
    quadratics through their s and t).  ``jobs``, ``scheduler``: where those per-run fits
    run (as the campaign's own, :func:`~pmalab.identify.campaign.fit.fit_runs`)."""
    from dataclasses import replace

    from pmalab.identify.campaign.pressure import weighted_r2
    from pmalab.identify.laws.structures import base_laws, profile, structured_law
    from pmalab.identify.messages import note
    from pmalab.identify.model import ForceModel

    law = cf.model.law
    if not law.structures or structure == "free" or not cf.runs:
        return None
    if structure != "auto" and structure not in law.structures:
        from pmalab.errors import PmalabError

        raise PmalabError(
            f"--structure {structure}: {law.name} offers {', '.join(['free', *law.structures])}"
        )
    k_names, d_names = law.element_names()
    elem = {*k_names, *d_names}
    user = {n for n in (fixed or {}) if n in elem}
    if user:
        cf.warnings.append(
            f"{law.name}: pressure structure not chosen: element parameters fixed by the user "
            f"({', '.join(sorted(user))}); every parameter keeps its own pressure law"
        )
        return None
    lv = levels_of([rf.p_nom for rf in cf.runs])
    if cf.joint is None:
        if structure != "auto":
            cf.warnings.append(
                f"--structure {structure}: not applied — the pressure laws were not refined "
                "jointly (the structures are fitted jointly)"
            )
        return None
    if structure == "auto" and (len(lv) < MIN_LEVELS or not cf.joint.lopo):
        return None
    thetas = [cf.theta(rf.p_nom) for rf in cf.runs]
    kappa, delta = profile(law, thetas)
    if not d_names:  # a threshold grid: zero shares between used elements may grow back
        kappa = revive(kappa)
    cands = ["free", *law.structures] if structure == "auto" else [structure]
    models = {
        s: ForceModel(structured_law(law, s, kappa, delta), cf.model.effects)
        for s in cands
        if s != "free"
    }
    choice = StructureChoice(
        law=law.name,
        chosen=structure,
        criterion="leave-one-pressure-out (joint fit, one Gauss-Newton step per left-out level)"
        if structure == "auto"
        else "user",
        scores={},
        n_params={},
        folds=lv[1:-1],
    )
    joints: dict = {"free": cf.joint}
    per_run = per_run_laws(cf, runs, models, jobs=jobs, scheduler=scheduler)
    tasks = {s: _starts(cf, runs, m, thetas, per_run.get(s)) for s, m in models.items()}
    fits = _refine_gated(cf, tasks, per_run, jobs)
    for s in models:
        try:
            joints[s], choice.starts[s] = _keep_lower(fits[s])
        except (ValueError, np.linalg.LinAlgError) as exc:  # reported, never fatal
            choice.failed[s] = str(exc)
    if d_names and structure in ("auto", *law.structures):
        _element_counts(cf, runs, law, models, joints, thetas, choice, per_run, jobs)
    for s, j in list(joints.items()):
        rows = prior_rows(j, law, models[s].law if s in models else law, s)
        got = apply_prior(j, rows)
        if got is not None:
            choice.priors[s], joints[s] = got
    for j in joints.values():  # the influence machinery's problem and Jacobian: done
        j.problem = j.z = j.jac = None
    if structure == "auto":
        for s, j in joints.items():
            labels = [rf.label for rf in cf.runs if rf.label in j.lopo]
            left_out = [j.lopo[lb] for lb in labels]
            choice.scores[s] = (
                float(np.sqrt(np.mean(np.square(left_out)))) if left_out else float("nan")
            )
            choice.per_run[s] = left_out
            # pressure-law coefficients of the muscle (record parameters excluded)
            choice.n_params[s] = sum(d + 1 for d in j.degree.values())
        choice.chosen = pick(choice.scores, choice.n_params)
    elif structure in choice.failed:
        from pmalab.errors import PmalabError

        raise PmalabError(f"--structure {structure}: the fit failed ({choice.failed[structure]})")
    cf.structure = choice
    prior = choice.priors.get(choice.chosen)
    if choice.chosen != "free" or (prior is not None and prior.chosen > 0):
        js = joints[choice.chosen]
        coefs = (
            base_laws(law, models[choice.chosen].law, js.coef)  # type: ignore[arg-type]
            if choice.chosen != "free"
            else {}
        )
        if choice.chosen == "free":
            cf.joint = js  # the free laws with their prior
        new = dict(cf.pressure)
        for n, pf in cf.pressure.items():
            if n in coefs:
                q = coefs[n]
                src = "s" if n in k_names else "t"
                d = js.degree.get(src, 0)
            elif n in js.coef:
                q, d = js.coef[n], js.degree[n]
            else:
                continue
            fitted = [q[0] + q[1] * p + q[2] * p * p for p in pf.pressures]
            r2, resid = weighted_r2(pf.values, fitted, pf.stderr)
            new[n] = replace(
                pf,
                coef=tuple(float(v) for v in q),
                degree=int(d),
                r2=r2,
                residuals=resid,
                method=f"structure:{choice.chosen}"
                + (f"+prior:{prior.chosen:g}" if prior is not None and prior.chosen > 0 else ""),
            )
        cf.pressure = new
    cf.warnings.append(
        note(
            "pressure-structure",
            choice.summary()
            if choice.scores
            else f"{law.name}: pressure structure '{choice.chosen}' (chosen by the user)",
            **choice.as_json(),
        )
    )
    return choice


@dataclass
class PerRunLaws:
    """Per-run fits of one structured law, its profile held (:func:`per_run_laws`): the
    second start of the structure's joint fit."""

    #: the profile's element shares κ_i (Σ = 1) and slip displacements δ_i (mm) the runs
    #: were fitted with
    kappa: np.ndarray
    delta: np.ndarray
    #: per run: nominal pressure (MPa), magnitude s (N/mm), peak-to-peak stroke (mm)
    p: np.ndarray
    s: np.ndarray
    stroke: np.ndarray
    #: per run: the threshold scale t (1); None where the structure holds it
    t: np.ndarray | None
    #: per run: the structured law's own fit's nrmse (what the law reaches on that run)
    nrmse: np.ndarray | None = None

    def start(self, kappa: np.ndarray, delta: np.ndarray, top: int) -> dict[str, tuple]:
        """Start laws (monomial q, order ``top``) of s and t through the per-run values, for
        the profile (κ', δ) — this one, or this one with elements dropped (κ'_i = 0).

        s: through every run, scaled by the kept elements' share Σκ_i (each kept element's
        stiffness s·κ_i as fitted).  t: through the runs whose stroke slides the largest kept
        element (2·t·δ_max < stroke: there every element's slip displacement shows in the
        loop), or through every run when those leave fewer than ``top`` + 1 levels.

        Parameters
        ----------
        kappa, delta
            The profile the start is for (κ' ≥ 0; δ in mm at t = 1).
        top
            The pressure order of both laws.

        Returns
        -------
        dict
            ``{"s": q}`` and, when t is fitted, ``{"t": q}``; q monomial in MPa.
        """
        from pmalab.identify.estimation.basis import fit_polynomial

        kept = np.asarray(kappa, dtype=np.float64) > 0
        share = float(np.sum(self.kappa[kept])) or 1.0
        out = {"s": tuple(fit_polynomial(self.p, self.s * share, max_degree=top).coef)}
        if self.t is not None:
            d_max = float(np.max(np.asarray(delta, dtype=np.float64)[kept], initial=0.0))
            slides = 2.0 * self.t * d_max < self.stroke
            if len(levels_of(self.p[slides])) < top + 1:
                slides = np.ones_like(slides)
            out["t"] = tuple(fit_polynomial(self.p[slides], self.t[slides], max_degree=top).coef)
        return out


def per_run_laws(
    cf, runs: Sequence[Run], models: Mapping, *, jobs: int = 1, scheduler: str | None = None
) -> dict[str, PerRunLaws]:
    """Every structured candidate's law fitted on every identification run on its own: s, t
    and h0 free (with k, c0 and the effects' parameters, as the campaign's own per-run fits),
    the profile's corrections held at 1, the campaign's fixes held and every campaign-wide
    parameter (``Effect.campaign_shared``: a sensor delay's τ) held at the free joint fit's
    value.

    The joint fit's first start holds every slip displacement where the free laws put them
    (t = 1); a muscle whose slip displacements grow with pressure is then reached, if at all,
    through a worse minimum.  Each run's own s and t see that growth directly, so their
    quadratics are the second start (:meth:`PerRunLaws.start`).  The fits are fitted once
    per structure and serve its element-count refits too.

    Parameters
    ----------
    cf
        The campaign (its free joint fit done).
    runs
        Its identification runs, in ``cf.runs`` order.
    models
        Structure → the structured :class:`~pmalab.identify.model.ForceModel`.
    jobs, scheduler
        Where the fits run (:func:`~pmalab.identify.campaign.fit.fit_runs`).

    Returns
    -------
    dict
        Structure → its per-run values; a structure whose fits failed is left out (its joint
        fit then has one start).
    """
    from pmalab.errors import PmalabError
    from pmalab.identify.campaign.fit import fit_runs

    if cf.joint is None or not models:
        return {}
    base = cf.model.law
    elem = {*base.element_names()[0], *base.element_names()[1]}
    own = {p.name for p in base.params}
    shared = {p.name for p in cf.runs[0].result.params} - elem - own
    held = {n: float(v) for n, v in cf.joint.constants.items() if n in shared}
    # a campaign-wide parameter (a sensor delay's τ) is one value for every run, in the
    # structured candidates' joint fits too (order 0): held at the free joint fit's value
    # here, not fitted again on every run (with its multi-start grid, the dearest part of
    # these fits on a model with a delay)
    th = cf.joint.theta(cf.runs[0].p_nom)
    held |= {n: float(th[n]) for n in cf.model.campaign_shared if n in shared and n in th}
    p = np.array([rf.p_nom for rf in cf.runs], dtype=np.float64)
    # peak-to-peak contraction (a gap in a record is NaN: not a stroke)
    stroke = np.array(
        [float(np.nanmax(r.position) - np.nanmin(r.position)) for r in runs], dtype=np.float64
    )
    out: dict[str, PerRunLaws] = {}
    for st, m in models.items():
        law = m.law
        fx = {**held, **dict.fromkeys(law.shared_shape, 1.0)}
        try:
            res = fit_runs(runs, m, jobs=jobs, scheduler=scheduler, fixed=fx)
        except (PmalabError, ValueError, np.linalg.LinAlgError):
            continue
        sv = np.array([float(r.values["s"]) for r in res], dtype=np.float64)
        tv = (
            None
            if "t" in law.default_fixed
            else np.array([float(r.values["t"]) for r in res], dtype=np.float64)
        )
        if not np.all(np.isfinite(sv)) or (tv is not None and not np.all(np.isfinite(tv))):
            continue
        nr = np.array([float(r.nrmse) for r in res], dtype=np.float64)
        out[st] = PerRunLaws(np.array(law.kappa), np.array(law.delta), p, sv, stroke, tv, nr)
    return out


def _starts(
    cf,
    runs: Sequence[Run],
    model,
    thetas: Sequence[Mapping[str, float]],
    per_run: PerRunLaws | None = None,
) -> list[tuple]:
    """The structured ``model``'s joint refinements on ``cf``'s records, one per start
    (:func:`_refine_start`'s arguments; see :func:`_joint_structured`)."""
    from pmalab.identify.campaign.fit import parameter_bounds
    from pmalab.identify.estimation.basis import fit_polynomial
    from pmalab.identify.estimation.joint import prepare

    j = cf.joint
    law = model.law
    base = cf.model.law
    elem = {*base.element_names()[0], *base.element_names()[1]}
    own = {p.name for p in law.params}
    bounds = {n: b for n, b in parameter_bounds(cf.runs).items() if n not in elem}
    bounds.update({p.name: (p.lo, p.hi) for p in law.params})
    constants = {n: v for n, v in j.constants.items() if n not in elem}
    constants.update({n: float(v) for n, v in law.default_fixed.items() if v is not None})
    start: dict[str, tuple[float, float, float]] = {}
    degree: dict[str, int] = {}
    for n, q in j.coef.items():
        if n not in elem:
            start[n], degree[n] = q, j.degree[n]
    top = min(2, len(levels_of([rf.p_nom for rf in cf.runs])) - 1)
    # the magnitude: the free laws' summed element stiffness at every run (κ sums to 1)
    ps = [rf.p_nom for rf in cf.runs]
    mag = [float(np.sum(base.elements(th)[0])) for th in thetas]
    pf = fit_polynomial(ps, mag, max_degree=top)
    start["s"], degree["s"] = pf.coef, top
    if "t" not in constants:
        start["t"], degree["t"] = (1.0, 0.0, 0.0), top
    shape = [n for n in law.shared_shape if n in own]
    for n in shape:
        start[n], degree[n] = (1.0, 0.0, 0.0), 0
    starts = [start]
    if per_run is not None:
        alt = per_run.start(law.kappa, law.delta, top)
        starts.append({**start, **{n: q for n, q in alt.items() if n in start}})
    jruns = [prepare(r, rf.result.rmse) for r, rf in zip(runs, cf.runs)]
    h0 = list(j.h0) if j.h0 else None
    fixed_order = [*shape, *(n for n in model.campaign_shared if n in start)]
    return [
        (model, jruns, st, degree, constants, bounds, h0, j.nuisance or None, fixed_order)
        for st in starts
    ]


def _refine_start(args: tuple):
    """One start's joint refinement (with leave-one-pressure-out evidence), its orders pruned
    like the free fit's (the candidates compare like with like); a failed fit is returned as
    its error (reported per candidate, never fatal to the others)."""
    from pmalab.identify.estimation.joint import refine

    model, jruns, start, degree, constants, bounds, h0, nuisance, fixed_order = args
    try:
        fit, _ = refine(
            model,
            jruns,
            start,
            degree,
            constants,
            bounds,
            h0,
            nuisance_start=nuisance,
            fixed_order=fixed_order,
            lopo=True,
            prune=True,
            max_nfev=CANDIDATE_NFEV,
        )
    except (ValueError, np.linalg.LinAlgError) as exc:
        return exc
    return fit


def _refine_all(tasks: Sequence[tuple], jobs: int) -> list:
    """:func:`_refine_start` on every task, on two cores when ``jobs`` > 1 (a forked child
    takes half: :func:`~pmalab.identify.campaign.batch.map_split`; it falls back to this
    process wherever forking is not safe or the child fails); with one job, in a kept
    pool's worker, an idle sibling may take some
    (:func:`~pmalab.identify.campaign.sharing.map_shared`; the same results)."""
    from pmalab.identify.campaign.batch import map_split
    from pmalab.identify.campaign.sharing import map_shared

    if jobs > 1 and len(tasks) > 1:
        return map_split(_refine_start, tasks, first_here=0)
    return map_shared(_refine_start, tasks)


def _refine_gated(
    cf, tasks: Mapping[str, Sequence[tuple]], per_run: Mapping[str, PerRunLaws], jobs: int
) -> dict[str, list]:
    """Candidate → its refinements (:func:`_refine_start`'s results, in start order):
    every candidate's first start refined in one batch (side by side on two cores when
    ``jobs`` > 1), then, in a second batch, the second starts of those whose first fell
    short of what the data allow (:func:`needs_second_start`).  ``tasks``: candidate → its
    starts (:func:`_starts`); ``per_run``: candidate → its per-run fits (absent: none)."""
    firsts = _refine_all([t[0] for t in tasks.values()], jobs)
    fits: dict[str, list] = {s: [f] for s, f in zip(tasks, firsts)}
    second = [
        s for s in tasks if len(tasks[s]) > 1 and needs_second_start(cf, fits[s][0], per_run.get(s))
    ]
    for s, f in zip(second, _refine_all([tasks[s][1] for s in second], jobs)):
        fits[s].append(f)
    return fits


def _keep_lower(fits: Sequence) -> tuple:
    """(the fit of the lower training cost, the name of its start in :data:`STARTS`) among
    one candidate's refinements (:func:`_refine_start`'s results, in start order).

    The training cost on one footing: the weighted residual of the same records, weights
    and cap in every problem, compared by BIC on a common N_eff (the largest) should the
    pruned orders differ; a tie keeps the first.  A failed start is skipped; when every
    start failed the first's error is raised."""
    from pmalab.identify.metrics import information_criteria

    ok = [(i, f) for i, f in enumerate(fits) if not isinstance(f, BaseException)]
    if not ok:
        raise fits[0]
    if len(ok) == 1:
        return ok[0][1], STARTS[ok[0][0]]
    n_eff = max(f.n_eff for _, f in ok)
    best, best_ic = ok[0], np.inf
    for i, f in ok:
        r = f.problem.residual(f.z)
        ic = information_criteria(float(r @ r), f.problem.n_rows, f.problem.n_var, n_eff)[1]
        if ic < best_ic:
            best, best_ic = (i, f), ic
    return best[1], STARTS[best[0]]


def _joint_structured(
    cf,
    runs: Sequence[Run],
    model,
    thetas: Sequence[Mapping[str, float]],
    per_run: PerRunLaws | None = None,
    jobs: int = 1,
):
    """The joint fit (with leave-one-pressure-out evidence) of the structured ``model`` on
    ``cf``'s records; returns (the fit, the name of its start in :data:`STARTS`).

    Up to two starts, each refined (and its orders pruned) like the free fit: the free joint
    laws (see :func:`choose_structure`) and, given ``per_run``, quadratics through the
    structured law's per-run s and t (:meth:`PerRunLaws.start`; everything else as in the
    first), refined only when the first start's fit falls short of what the data allow
    (:func:`needs_second_start`; :func:`_refine_gated`, the two one after the other).  The
    lower training cost is kept (:func:`_keep_lower`)."""
    tasks = {model.name: _starts(cf, runs, model, thetas, per_run)}
    per = {model.name: per_run} if per_run is not None else {}
    return _keep_lower(_refine_gated(cf, tasks, per, jobs)[model.name])


def needs_second_start(cf, first, per_run: PerRunLaws | None) -> bool:
    """Whether a structured candidate's second start (its own per-run fits) must be refined
    too: the first start's refined joint fit ``first`` fell short of what the data allow.

    What the data allow is judged run by run against the structured law's own per-run fits
    (the best that law reaches on each run alone): the joint fit's excess is the mean over
    the runs of (joint nrmse / per-run nrmse)².  A pressure law always costs something, and
    the free joint laws show how much on these records: the same excess of ``cf.joint``
    over the campaign's free per-run fits.  The first start stands unless its excess exceeds
    the free laws' by more than :data:`SECOND_START_MARGIN` of it (a worse minimum, e.g.
    slip displacements held where the free laws put them although they grow with
    pressure); a failed first start, or an excess that cannot be judged, always asks for
    the second.

    Parameters
    ----------
    cf
        The campaign (its free joint fit and per-run fits done).
    first
        The first start's refinement (:func:`_refine_start`'s result: a fit or an error).
    per_run
        The structured law's per-run fits (:func:`per_run_laws`); None: there is no second
        start, so False.

    Returns
    -------
    bool
        True when the second start is to be refined.
    """
    if per_run is None:
        return False
    if isinstance(first, BaseException) or per_run.nrmse is None or cf.joint is None:
        return True
    own = np.asarray(per_run.nrmse, dtype=np.float64)
    free = np.array([rf.result.nrmse for rf in cf.runs], dtype=np.float64)
    jf = np.asarray(first.nrmse, dtype=np.float64)
    jfree = np.asarray(cf.joint.nrmse, dtype=np.float64)
    if not (own.shape == jf.shape == free.shape == jfree.shape) or jf.size == 0:
        return True
    with np.errstate(divide="ignore", invalid="ignore"):
        excess = float(np.mean(np.square(jf / own)))
        allowed = float(np.mean(np.square(jfree / free)))
    if not (np.isfinite(excess) and np.isfinite(allowed)):
        return True
    return excess > allowed * (1.0 + SECOND_START_MARGIN)


# --------------------------------------------------------------------------- priors
#: strengths λ of an element law's prior (the penalty's share of the joint fit's data cost
#: per unit mean square of the penalised quantity), tried in turn; 0 is the unpenalised fit
PRIOR_GRID = (0.0, 0.03, 0.3, 3.0, 30.0)
#: a revived element (a grid element the free fit left at zero between used ones) starts at
#: this share of the largest, so the joint fit (and the prior) can grow it
REVIVE_SHARE = 0.02
#: a kept penalised step is checked by one evaluation: its data cost may exceed the linear
#: prediction by at most this factor, else the prior is not applied
STEP_COST_RATIO = 1.25


@dataclass
class Prior:
    """An element law's prior on one structure's fit, its strength chosen by the same
    leave-one-pressure-out evidence as the structure."""

    #: what is penalised (words)
    what: str
    #: strengths tried, and the RMS held-out nrmse of each
    strengths: list[float]
    scores: list[float]
    #: the strength kept (0: no prior)
    chosen: float
    #: why a chosen strength was not applied, or ""
    note: str = ""

    def as_json(self) -> StructurePrior:
        out = StructurePrior(
            prior=self.what,
            criterion="leave-one-pressure-out held-out nrmse",
            strengths=list(self.strengths),
            heldout_nrmse=list(self.scores),
            chosen_strength=self.chosen,
        )
        if self.note:
            out["note"] = self.note
        return out

    def summary(self) -> str:
        i = self.strengths.index(self.chosen) if self.chosen in self.strengths else 0
        return f"prior λ = {self.chosen:g} ({self.scores[i]:.4f}; λ = 0: {self.scores[0]:.4f})" + (
            f" — {self.note}" if self.note else ""
        )


def revive(kappa: np.ndarray) -> np.ndarray:
    """The profile with every zero share between the first and last non-zero ones raised
    to ``REVIVE_SHARE`` of the largest (a free fit's zero in the middle of a threshold grid
    is a fit's choice among neighbours, not evidence that the element is absent)."""
    k = np.array(kappa, dtype=np.float64)
    nz = np.flatnonzero(k > 0)
    if nz.size < 2:
        return k
    a, b = int(nz[0]), int(nz[-1])
    mid = k[a : b + 1]
    mid[mid <= 0] = REVIVE_SHARE * float(k.max())
    return k


def prior_rows(j, base, law, structure: str):
    """(what, g(z), D) of ``structure``'s prior, or None: the penalty is ‖D·g(z)‖ (g linear
    in the fit's coefficients z).

    * a threshold grid (Prandtl-Ishlinskii), ``scaled``: the stiffness profile g_i = κ_i·c_i
      ÷ its mean over the used span, D its second difference over the grid — smooth in
      threshold;
    * a threshold grid, ``free``: every pressure-law coefficient (Legendre order 0, 1, 2) of
      the weights over the used span ÷ the order-0 mean, D the second difference — smooth
      in threshold at every order of pressure;
    * free elements (Maxwell-slip), a profile structure: the corrections c_i − 1 and
      r_i − 1, D the identity — shrunk toward the pooled profile.
    """
    prob, z0 = j.problem, j.z
    if prob is None or z0 is None:
        return None
    k_names, d_names = base.element_names()
    if structure == "free":
        if d_names:
            return None
        names = [n for n in k_names if n in prob.slices]
        if len(names) < 4:
            return None
        order0 = np.array([z0[prob.slices[n].start] for n in names])
        nz = np.flatnonzero(np.abs(order0) > 0)
        if nz.size < 4:
            return None
        a, b = int(nz[0]), int(nz[-1]) + 1
        names = names[a:b]
        scale = float(np.mean(np.abs(order0[a:b]))) or 1.0
        top = max(prob.degree[n] for n in names)

        def g_free(z: np.ndarray) -> np.ndarray:
            out = []
            for o in range(top + 1):
                out.extend(
                    z[prob.slices[n].start + o] / scale if prob.degree[n] >= o else 0.0
                    for n in names
                )
            return np.asarray(out, dtype=np.float64)

        m = len(names)
        D1 = np.diff(np.eye(m), n=2, axis=0)
        D = np.kron(np.eye(top + 1), D1)
        return "second difference over the threshold grid of every weight's pressure law", g_free, D
    if d_names:  # free elements: shrink the corrections toward the pooled profile
        pars = [f"c{i + 1}" for i in law.c_index] + [f"r{i + 1}" for i in law.r_index]
        pars = [n for n in pars if n in prob.slices]
        if not pars:
            return None

        def g_ms(z: np.ndarray) -> np.ndarray:
            th = prob.thetas(z)[0]
            return np.array([th[n] - 1.0 for n in pars])

        return (
            "shrinkage of the element corrections toward the pooled profile",
            g_ms,
            np.eye(len(pars)),
        )
    nz = np.flatnonzero(np.asarray(law.kappa) > 0)
    if nz.size < 4 or not all(f"c{i + 1}" in prob.slices for i in law.c_index):
        return None
    a, b = int(nz[0]), int(nz[-1]) + 1
    th0 = prob.thetas(z0)[0]
    gbar = float(np.mean((np.asarray(law.kappa) * law.corrections(th0)[0])[a:b])) or 1.0

    def g_scaled(z: np.ndarray) -> np.ndarray:
        c, _ = law.corrections(prob.thetas(z)[0])
        return (np.asarray(law.kappa) * c)[a:b] / gbar

    return (
        "second difference of the stiffness profile over the threshold grid",
        g_scaled,
        np.diff(np.eye(b - a), n=2, axis=0),
    )


def penalised_step(j, rows, lam: float) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """One Gauss–Newton step of ``j``'s problem with the prior ``rows`` at strength ``lam``
    from its unpenalised solution: (Δz, the linearised residual there, the leave-one-
    pressure-out nrmse per run with the prior kept in every fold).  λ = 0: no step, ``j``'s
    own LOPO evidence."""
    from pmalab.identify.estimation.joint import approx_lopo

    prob, z0, J = j.problem, j.z, j.jac
    r0 = prob.residual(z0)
    if lam == 0.0:
        return np.zeros_like(z0), r0, dict(j.lopo)
    _, g_of, D = rows
    g0 = g_of(z0)
    G = np.zeros((g0.size, z0.size))
    h = 1e-6
    for col in range(prob.n_coef):  # g is linear in the coefficients
        dz = np.zeros_like(z0)
        dz[col] = h
        G[:, col] = (g_of(z0 + dz) - g0) / h
    w = np.sqrt(lam / max(D.shape[0], 1)) * float(np.linalg.norm(r0))
    M = w * (D @ G)
    p0 = w * (D @ g0)
    A = J.T @ J + M.T @ M
    bb = J.T @ r0 + M.T @ p0
    d = np.sqrt(np.maximum(np.diag(A), 0.0))
    d = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    dz = -d * np.linalg.lstsq(A * d[:, None] * d[None, :], bb * d, rcond=1e-12)[0]
    r = r0 + J @ dz
    return dz, r, approx_lopo(prob, z0 + dz, J, r=r, prior=(M, p0 + M @ dz))


def apply_prior(j, rows) -> tuple[Prior, object] | None:
    """Choose the strength of the prior ``rows`` (:func:`prior_rows`) on the joint fit ``j``
    (refined with ``lopo``); returns (the choice, the joint fit to keep: ``j`` itself, or
    ``j`` stepped to the penalised solution), or None.

    The penalty rows are √(λ/n)·‖r‖·D·g(z): roughness costs λ times the data cost per unit
    mean square of D·g.  Each λ is one Gauss–Newton step of the penalised problem from the
    unpenalised solution (g is linear in the coefficients), scored by :func:`approx_lopo`
    with the prior kept in every fold; the lowest score wins unless it is within
    ``SIMPLER_WITHIN`` of λ = 0.  The kept step is checked by one evaluation (see
    ``STEP_COST_RATIO``)."""
    from dataclasses import replace

    prob, z0, J = j.problem, j.z, j.jac
    if prob is None or z0 is None or J is None or not j.lopo or rows is None:
        return None
    what = rows[0]
    steps = [penalised_step(j, rows, lam) for lam in PRIOR_GRID]
    labels = list(j.lopo)
    scores: list[float] = []
    for _, _, lo in steps:
        vals = [lo[lb] for lb in labels if lb in lo]
        scores.append(float(np.sqrt(np.mean(np.square(vals)))) if vals else float("nan"))
    if not np.isfinite(scores[0]):
        return None
    ok = [i for i, v in enumerate(scores) if np.isfinite(v)]
    best = min(ok, key=lambda i: scores[i])
    if scores[best] > scores[0] * (1.0 - SIMPLER_WITHIN):
        best = 0
    pr = Prior(what, list(PRIOR_GRID), scores, PRIOR_GRID[best])
    if best == 0:
        return pr, j
    dz, r_lin, lo = steps[best]
    lo_b, hi_b = prob.z_bounds()
    z = np.clip(z0 + dz, lo_b, hi_b)
    with np.errstate(all="ignore"):
        r = prob.residual(z)
    if not np.all(np.isfinite(r)) or float(r @ r) > STEP_COST_RATIO * float(r_lin @ r_lin):
        pr.note = (
            f"λ = {PRIOR_GRID[best]:g} not applied: its one-step solution left the linear "
            "range (data cost above the prediction)"
        )
        pr.chosen = 0.0
        return pr, j
    coef = {n: j.basis.to_monomial(z[prob.slices[n]]) for n in prob.free}
    rv = prob.run_values(z)
    stepped = replace(
        j,
        coef=coef,
        h0=rv.get("h0", []),
        nrmse=prob.per_run_nrmse(z),
        lopo=lo,
        z=z,
        nuisance={n: rv[n] for n in j.nuisance},
        legendre={n: np.array(z[prob.slices[n]]) for n in prob.free},
    )
    return pr, stepped


# --------------------------------------------------------------------------- element count
#: an element carrying less of the friction (slip force at the campaign's middle pressure)
#: than this share is a candidate for removal: fewer elements are tried only then (one more
#: joint fit per count), so a muscle whose elements all matter costs nothing more
REMOVE_SHARE = 0.1
#: the fewest elements a free-element law is cut to
MIN_ELEMENTS = 2


@dataclass
class ElementCount:
    """How many elements a free-element structure keeps, chosen by the same evidence."""

    #: counts tried (ascending; the last is the law's own) and the RMS held-out nrmse of each
    counts: list[int]
    scores: list[float]
    chosen: int
    #: elements removed (1-based, in the law's order) for the chosen count
    removed: list[int]

    def as_json(self) -> StructureElements:
        return StructureElements(
            criterion="leave-one-pressure-out held-out nrmse (one joint fit per count); the "
            f"fewest elements within {100 * SIMPLER_WITHIN:g} % of the best",
            counts=list(self.counts),
            heldout_nrmse=list(self.scores),
            chosen=self.chosen,
            removed=list(self.removed),
        )

    def summary(self) -> str:
        i = self.counts.index(self.chosen)
        return (
            f"{self.chosen} of {self.counts[-1]} elements ({self.scores[i]:.4f}; "
            f"{self.counts[-1]}: {self.scores[-1]:.4f})"
        )


def _element_counts(
    cf, runs, base, models, joints, thetas, choice, per_run=None, jobs: int = 1
) -> None:
    """Fewer elements for every free-element candidate structure whose fitted elements
    include ones carrying < ``REMOVE_SHARE`` of the friction: the structure is refitted
    jointly without the smallest one, then the two smallest (down to ``MIN_ELEMENTS``), each
    from the free laws like any candidate, and the fewest elements whose leave-one-pressure-
    out score is within ``SIMPLER_WITHIN`` of the best count's replace the candidate
    (``models``, ``joints``, ``choice.elements`` and ``choice.starts`` updated in place).
    ``per_run``: structure → its per-run fits (:func:`per_run_laws`), the second start of
    every count's joint fit (the dropped elements' share taken out of s), refined when the
    first start's falls short (:func:`needs_second_start`)."""
    from pmalab.identify.laws.structures import structured_law
    from pmalab.identify.model import ForceModel

    lv = levels_of([rf.p_nom for rf in cf.runs])
    p_mid = float(np.median(lv))

    def score(j) -> float:
        vals = list(j.lopo.values())
        return float(np.sqrt(np.mean(np.square(vals)))) if vals else float("nan")

    for s in [k for k in list(models) if k in joints]:
        law = models[s].law
        j = joints[s]
        th = j.theta(p_mid)
        k, d = law.elements(th)
        f = np.abs(np.asarray(k) * np.asarray(d))
        if f.sum() <= 0:
            continue
        share = f / f.sum()
        # the elements the law has (an element at zero weight is not one: removing it would
        # refit the same law under a count one lower)
        present = np.asarray(law.kappa) > 0
        small = [int(i) for i in np.argsort(share) if present[i] and share[i] < REMOVE_SHARE]
        m = int(np.count_nonzero(present))
        small = small[: max(0, m - MIN_ELEMENTS)]
        if not small:
            continue
        counts: dict[int, tuple[float, tuple[int, ...], object, object, str]] = {
            m: (score(j), (), models[s], j, choice.starts.get(s, STARTS[0]))
        }
        for n_rm in range(1, len(small) + 1):
            gone = tuple(sorted(small[:n_rm]))
            kappa = np.array(law.kappa, dtype=np.float64)
            kappa[list(gone)] = 0.0
            mod = ForceModel(structured_law(base, s, kappa, law.delta), models[s].effects)
            try:
                jr, how = _joint_structured(
                    cf, runs, mod, thetas, (per_run or {}).get(s), jobs=jobs
                )
            except (ValueError, np.linalg.LinAlgError):
                continue
            counts[m - n_rm] = (score(jr), gone, mod, jr, how)
        ok = {c: v for c, v in counts.items() if np.isfinite(v[0])}
        best = min(v[0] for v in ok.values())
        chosen = min(c for c, v in ok.items() if v[0] <= best * (1.0 + SIMPLER_WITHIN))
        order = sorted(ok)
        choice.elements[s] = ElementCount(
            order, [ok[c][0] for c in order], chosen, [i + 1 for i in ok[chosen][1]]
        )
        models[s], joints[s], choice.starts[s] = ok[chosen][2], ok[chosen][3], ok[chosen][4]
