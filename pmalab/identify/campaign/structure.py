"""The pressure structure of an element law, chosen by leave-one-pressure-out evidence.

A law's file says what its elements are; how they change with pressure is the muscle's
business (:mod:`pmalab.identify.laws.structures` lists the candidates: ``free``,
``scaled``, ``scaled-thresholds``).  A structure with many pressure laws fits each level
best and may predict other levels worst (per-weight quadratics follow each run's noise); one
with few may miss how the muscle really changes.  So the campaign asks the data:

**Criterion (leave-one-pressure-out, LOPO).**  For every *interior* identification
pressure level L (the lowest and highest are never left out: predicting them would be
extrapolation, which a campaign never promises), every parameter's pressure law is fitted
through the per-run values of the runs at the *other* levels (the one polynomial fit,
:func:`~pmalab.identify.estimation.basis.fit_polynomial`: 1/stderr weights, order 0–2 by
BIC, at most levels − 1), and the runs at L are predicted free-run from those laws (their
start state estimated on the record, as validation does).  A structure's score is the root
mean square of those held-out nrmse; the lowest wins.  A simpler structure (fewer
parameters) is preferred unless the richer one's score is lower by more than
``SIMPLER_WITHIN`` (relative): the choice never hinges on round-off.  The per-run values
are the engine's own fits of each structure (the structured laws hold the profile pooled
over every run; only their magnitude and threshold scale are per run).

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

from pmalab.identify.estimation.basis import fit_polynomial, weights
from pmalab.identify.estimation.records import predict_record
from pmalab.identify.estimation.single import FitResult
from pmalab.identify.schema import PressureStructure, StructureCandidate
from pmalab.identify.signals import Signals
from pmalab.runfile import Run

#: a structure with fewer parameters wins unless a richer one's LOPO score is lower by more
#: than this fraction
SIMPLER_WITHIN = 0.01
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


def lopo_score(
    model,
    runs: Sequence[Run],
    results: Sequence[FitResult],
    bounds: Mapping[str, tuple[float, float]],
) -> tuple[float, list[float], list[float], int]:
    """Leave-one-pressure-out score of one structure's per-run fits (see module doc).

    Returns (RMS held-out nrmse, per held-out run nrmse, the levels left out, the number of
    muscle parameters with a pressure law)."""
    record = set(model.record_params)
    names = [n for n in results[0].params.names() if n not in record]
    pressures = np.array([float(r.nominal_pressure) for r in runs])
    lv = levels_of(pressures)
    key = np.round(pressures, 3)
    varying = [n for n in names if any(r.params[n].vary for r in results)]
    nrmse: list[float] = []
    folds = lv[1:-1]
    for L in folds:
        train = key != L
        th: dict[str, float] = {}
        n_train_levels = len(set(key[train]))
        for n in names:
            vals = np.array([float(r.params[n].value) for r in results])
            if n not in varying:
                th[n] = float(vals[0])
                continue
            se = [r.params[n].stderr for i, r in enumerate(results) if train[i]]
            pf = fit_polynomial(
                pressures[train],
                vals[train],
                weights(se, int(train.sum())),
                max_degree=min(2, n_train_levels - 1),
                select=True,
            )
            v = float(pf(L))
            lo, hi = bounds.get(n, (-np.inf, np.inf))
            th[n] = float(min(max(v, lo), hi))
        for n in record:
            th[n] = 0.0
        for i in np.flatnonzero(~train).tolist():
            run = runs[int(i)]
            sig = Signals.from_run(run)
            yh = predict_record(model, sig, th, force=run.force, bounds=bounds)
            y = np.asarray(run.force, dtype=np.float64)
            sd = float(np.std(y))
            nrmse.append(float(np.sqrt(np.mean((yh - y) ** 2)) / sd) if sd > 0 else float("nan"))
    score = float(np.sqrt(np.mean(np.square(nrmse)))) if nrmse else float("nan")
    return score, nrmse, folds, len(varying)


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
    jobs: int = 1,
    scheduler: str | None = None,
    progress: bool = False,
    pressure_model: str = "joint",
    structure: str = "auto",
) -> StructureChoice | None:
    """Choose ``cf``'s pressure structure (``"auto"``: by LOPO; or the one named) and, when it
    is not ``"free"``, replace ``cf.pressure``'s laws by the winner's (in place; see module
    doc).  Returns the choice (also in ``cf.structure``), None when the law offers no
    structures, the campaign has too few levels, or the user fixed element parameters."""
    from dataclasses import replace

    from pmalab.identify.campaign.fit import fit_campaign, parameter_bounds
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
    if structure == "auto" and len(lv) < MIN_LEVELS:
        return None
    kappa, delta = profile(law, [cf.theta(rf.p_nom) for rf in cf.runs])
    others = {n: v for n, v in (fixed or {}).items() if n not in elem}
    cands = ["free", *law.structures] if structure == "auto" else [structure]
    models = {
        s: ForceModel(structured_law(law, s, kappa, delta), cf.model.effects)
        for s in cands
        if s != "free"
    }
    choice = StructureChoice(
        law=law.name,
        chosen=structure,
        criterion="leave-one-pressure-out" if structure == "auto" else "user",
        scores={},
        n_params={},
        folds=[],
    )
    camps = {}
    for s, m in models.items():
        try:
            camps[s] = fit_campaign(
                runs,
                m,
                fixed=others or None,
                shape={n: 1.0 for n in m.law.shared_shape},
                jobs=jobs,
                scheduler=scheduler,
                progress=progress,
                pressure_model=pressure_model,
            )
        except Exception as exc:  # a failed candidate is reported, not fatal
            choice.failed[s] = str(exc)
    if structure == "auto":
        every = {"free": cf, **camps}
        joint = all(c.joint is not None and c.joint.lopo for c in every.values())
        choice.criterion = (
            "leave-one-pressure-out (joint fit, one Gauss-Newton step per left-out level)"
            if joint
            else "leave-one-pressure-out (per-run values)"
        )
        for s, c in every.items():
            if joint:
                per = c.joint.lopo
                labels = [rf.label for rf in c.runs if rf.label in per]
                per_run = [per[lb] for lb in labels]
                choice.folds = levels_of([rf.p_nom for rf in c.runs])[1:-1]
                # pressure-law coefficients of the muscle (record parameters excluded)
                n_par = sum(d + 1 for d in c.joint.degree.values())
                score = float(np.sqrt(np.mean(np.square(per_run)))) if per_run else float("nan")
            else:
                m = cf.model if s == "free" else models[s]
                bounds = parameter_bounds(c.runs)
                score, per_run, choice.folds, n_par = lopo_score(
                    m, runs, [rf.result for rf in c.runs], bounds
                )
            choice.scores[s], choice.per_run[s], choice.n_params[s] = score, per_run, n_par
        choice.chosen = pick(choice.scores, choice.n_params)
    elif structure in choice.failed:
        from pmalab.errors import PmalabError

        raise PmalabError(f"--structure {structure}: the fit failed ({choice.failed[structure]})")
    cf.structure = choice
    if choice.chosen != "free":
        sm = models[choice.chosen]
        cs = camps[choice.chosen]
        own = ("s", "t", *sm.law.shared_shape)
        coefs = base_laws(
            law,
            sm.law,  # type: ignore[arg-type]
            {n: cs.pressure[n].coef for n in own if n in cs.pressure},
        )
        deg = {n: cs.pressure[n].degree for n in ("s", "t") if n in cs.pressure}
        new = dict(cf.pressure)
        for n, pf in cf.pressure.items():
            if n in coefs:
                q = coefs[n]
                d = deg.get("s" if n in k_names else "t", 2)
            elif n in cs.pressure and n not in cf.model.record_params:
                q, d = cs.pressure[n].coef, cs.pressure[n].degree
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


def _bounds(results: Sequence[FitResult]) -> dict[str, tuple[float, float]]:
    out: dict[str, tuple[float, float]] = {}
    for r in results:
        for p in r.params:
            lo, hi = out.get(p.name, (np.inf, -np.inf))
            out[p.name] = (min(lo, p.lo), max(hi, p.hi))
    return out
