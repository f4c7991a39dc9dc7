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

from pmalab.identify.schema import PressureStructure, StructureCandidate
from pmalab.runfile import Run

#: a structure with fewer parameters wins unless a richer one's LOPO score is lower by more
#: than this fraction
SIMPLER_WITHIN = 0.01
#: function evaluations of a structured candidate's joint fit
CANDIDATE_NFEV = 120
#: pressure levels (distinct nominal pressures, rounded to 1 kPa) a LOPO choice needs: one
#: interior level left out still leaves ≥ 3 levels for a quadratic
MIN_LEVELS = 4


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
            if s in self.failed:
                c["status"], c["reason"] = "failed", self.failed[s]
            cands.append(c)
        return PressureStructure(
            law=self.law,
            chosen=self.chosen,
            criterion=self.criterion,
            margin_percent=self.margin_percent,
            levels_left_out_MPa=list(self.folds),
            candidates=cands,
        )

    def summary(self) -> str:
        """One line: the winner, its score and its margin."""
        cands = ", ".join(
            f"{s} {v:.4f} ({self.n_params[s]} p.)"
            for s, v in sorted(self.scores.items(), key=lambda kv: kv[1])
        )
        tail = "" if self.chosen == "free" else "; its pressure laws replace the free ones"
        return (
            f"{self.law}: pressure structure '{self.chosen}' chosen by leave-one-pressure-out "
            f"held-out nrmse ({cands}; margin {self.margin_percent:.1f} %){tail}"
        )


def levels_of(pressures: Sequence[float] | np.ndarray) -> list[float]:
    """Distinct nominal pressure levels (MPa, rounded to 1 kPa), ascending."""
    return sorted({round(float(p), 3) for p in pressures})


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
) -> StructureChoice | None:
    """Choose ``cf``'s pressure structure (``"auto"``: by LOPO; or the one named) and, when it
    is not ``"free"``, replace ``cf.pressure``'s laws by the winner's (in place; see module
    doc).  Returns the choice (also in ``cf.structure``); None when the law offers no
    structures, the campaign has too few levels, its pressure laws were not refined jointly
    (the evidence is the joint fit's), or the user fixed element parameters.

    Each structured candidate is one joint fit on the free campaign's records, started from
    the free structure's joint laws (k, c0 and the effects' laws as they are, the magnitude
    s(p) through the free laws' summed element stiffness, t = 1, the profile corrections
    1): no per-run fits are needed, the laws are the joint fit's anyway."""
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
    for s, m in models.items():
        try:
            joints[s] = _joint_structured(cf, runs, m, thetas)
        except (ValueError, np.linalg.LinAlgError) as exc:  # reported, never fatal
            choice.failed[s] = str(exc)
    if structure == "auto":
        for s, j in joints.items():
            labels = [rf.label for rf in cf.runs if rf.label in j.lopo]
            per_run = [j.lopo[lb] for lb in labels]
            choice.scores[s] = (
                float(np.sqrt(np.mean(np.square(per_run)))) if per_run else float("nan")
            )
            choice.per_run[s] = per_run
            # pressure-law coefficients of the muscle (record parameters excluded)
            choice.n_params[s] = sum(d + 1 for d in j.degree.values())
        choice.chosen = pick(choice.scores, choice.n_params)
    elif structure in choice.failed:
        from pmalab.errors import PmalabError

        raise PmalabError(f"--structure {structure}: the fit failed ({choice.failed[structure]})")
    cf.structure = choice
    if choice.chosen != "free":
        sm = models[choice.chosen]
        js = joints[choice.chosen]
        coefs = base_laws(law, sm.law, js.coef)  # type: ignore[arg-type]
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
                method=f"structure:{choice.chosen}",
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


def _joint_structured(cf, runs: Sequence[Run], model, thetas: Sequence[Mapping[str, float]]):
    """The joint fit (with leave-one-pressure-out evidence) of the structured ``model`` on
    ``cf``'s records, started from ``cf``'s free joint laws (see :func:`choose_structure`)."""
    from pmalab.identify.campaign.fit import parameter_bounds
    from pmalab.identify.estimation.basis import fit_polynomial
    from pmalab.identify.estimation.joint import prepare, refine

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
    jruns = [prepare(r, rf.result.rmse) for r, rf in zip(runs, cf.runs)]
    h0 = list(j.h0) if j.h0 else None
    fit, _ = refine(
        model,
        jruns,
        start,
        degree,
        constants,
        bounds,
        h0,
        nuisance_start=j.nuisance or None,
        fixed_order=[*shape, *(n for n in model.campaign_shared if n in start)],
        lopo=True,
        # one refinement from the free laws, its orders pruned like the free fit's (the
        # candidates compare like with like)
        prune=True,
        max_nfev=CANDIDATE_NFEV,
    )
    return fit
