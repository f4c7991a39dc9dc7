"""Diagnosis: where the model fails, which effect is missing, and the error falling.

``diagnose(runs, model="bouc-wen")`` (and ``pmalab diagnose``):

1. chooses the held-out runs exactly as ``pmalab identify`` would validate
   (:mod:`.heldout`: ``--validate`` and role-tagged runs, else interior runs);
2. identifies the base model and ranks every catalogue effect by the validation error
   ``pmalab identify --add EFFECT`` gives on those runs (:mod:`.ranking`), climbing the
   ladder (:mod:`.ladder`) while an effect is significant;
3. estimates the measurement-noise floor of every held-out run from the data
   (:mod:`pmalab.identify.noise`) and says what is left: the model at the floor, or an
   unexplained structured residual N× the floor and where it is worst;
4. computes the residual diagnostics of the base model on the held-out runs
   (:mod:`.diagnostics`) and writes ``diagnosis.json`` and ``predictions.h5`` (roles
   ``diagnosis`` for the base model, ``diagnosis-final`` for the final ladder model).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pmalab.errors import PmalabError
from pmalab.identify.campaign.structure import margin_words
from pmalab.identify.diagnosis.diagnostics import (
    campaign_diagnostics,
    residual_next_step,
    residual_shares,
    run_diagnostics,
)
from pmalab.identify.diagnosis.heldout import choose
from pmalab.identify.diagnosis.ladder import (
    AT_FLOOR_RATIO,
    LadderStep,
    Round,
    one_frequency,
    run_ladder,
)
from pmalab.identify.diagnosis.ranking import (
    AMBIGUITY_RATIO,
    DIVERGED_NRMSE,
    MIN_BLOCK_T,
    MIN_GAIN_X_FLOOR,
    Candidate,
    alike,
    finite_or_none,
    heldout_floor,
    judged_runs,
    rate_dependent,
    scored_part,
)
from pmalab.identify.effects import EFFECTS, load_user_effects
from pmalab.identify.labels import check_runs
from pmalab.identify.laws import LAWS
from pmalab.identify.predictions import PredictionItem, write_predictions_file
from pmalab.identify.schema import DiagnosisDoc
from pmalab.identify.signals import Signals
from pmalab.pressure_labels import label_warning
from pmalab.runfile import Run

#: the final model "reaches the noise floor" unless it exceeds it by at least what the
#: significance rule requires of an effect (MIN_GAIN_X_FLOOR noise floors, mean held-out):
#: a residual no significant effect could remove is not called structured.  A fixed ratio
#: (1.5×) called a systematic 1.4 N misfit on four 20,000-sample runs "nothing to explain".
#: The ladder stops at the same ratio (:data:`~.ladder.AT_FLOOR_RATIO`).
UNEXPLAINED_RATIO = AT_FLOOR_RATIO


#: what separates two look-alike effects (pairs not listed: each effect's own experiment)
PAIR_EXPERIMENTS: dict[frozenset[str], str] = {
    frozenset({"sensor-delay", "viscous-friction"}): (
        "repeat at two or more frequencies (e.g. 0.2 and 1 Hz) at the same pressure: a "
        "delay's phase error grows with frequency while viscous force grows with velocity "
        "amplitude; a triangle wave also helps (viscous force is constant on each branch)"
    ),
    frozenset({"sensor-delay", "inertia"}): (
        "repeat at three or more frequencies: an inertial force grows with the square of the "
        "frequency, a delay's error linearly"
    ),
    frozenset({"viscous-friction", "inertia"}): (
        "repeat at several frequencies: inertia grows with frequency squared and is in phase "
        "with position, viscous force grows linearly and is in phase with velocity"
    ),
    frozenset({"nonlinear-stiffness", "asymmetric-hysteresis"}): (
        "record a slow loop over the full stroke plus minor loops: a curved static "
        "characteristic bends the centre line on both branches alike, asymmetry only the "
        "branch shapes after reversals"
    ),
}


class DiagnoseError(PmalabError):
    """Bad diagnosis input (no runs, unknown model, too short runs...)."""


@dataclass
class Diagnosis:
    """The result of :func:`diagnose` (JSON-ready pieces plus the arrays for plots)."""

    model: str
    ranking: list[dict[str, Any]]
    ambiguous: list[str]
    suggested_experiment: str
    ladder: list[dict[str, Any]]
    diagnostics: dict[str, Any]
    campaign: dict[str, Any]
    summary: str
    #: measurement-noise floor (nrmse) per held-out run and its mean
    noise_floor: dict[str, Any] = field(default_factory=dict)
    #: "floor" (the final model reaches the noise floor) or "unexplained"
    verdict: str = ""
    rounds: list[dict[str, Any]] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    #: per run: (run, base model force at full rate, final model force at full rate)
    traces: list[tuple[Run, np.ndarray, np.ndarray]] = field(default_factory=list, repr=False)
    final_effects: list[str] = field(default_factory=list)
    #: the other laws scored like effects (``identify --model X``), best first: against the
    #: base model, a law the ladder switched to against the model of the step before
    laws: list[dict[str, Any]] = field(default_factory=list)
    #: the law of the final ladder model (the base law unless a step changed it)
    final_law: str = ""
    #: the laws that predict about equally well as the best law (best first; :func:`laws_alike`)
    laws_alike: list[str] = field(default_factory=list)
    #: where the final model's held-out residual beyond the noise lies (loop / above the
    #: motion band / session offset / other: shares of its power) and what to look at next
    residual: dict[str, Any] = field(default_factory=dict)

    @property
    def winner(self) -> str | None:
        """The first effect the ladder added (None when nothing is significant)."""
        return self.ladder[1]["added"] if len(self.ladder) > 1 else None

    def to_json(self) -> DiagnosisDoc:
        """The ``diagnosis.json`` content (:class:`pmalab.identify.schema.DiagnosisDoc`)."""
        out = {
            "model": self.model,
            "ranking": self.ranking,
            "ambiguous": self.ambiguous,
            "suggested_experiment": self.suggested_experiment,
            "ladder": self.ladder,
            "diagnostics": self.diagnostics,
            "campaign_diagnostics": self.campaign,
            "rounds": self.rounds,
            "final_model": "+".join([self.final_law or self.model, *self.final_effects]),
            "final_law": self.final_law or self.model,
            "laws": self.laws,
            "laws_alike": self.laws_alike,
            "residual": self.residual,
            "settings": self.settings,
            "summary": self.summary,
            "noise_floor": self.noise_floor,
            "verdict": self.verdict,
        }
        return json.loads(json.dumps(out, default=_json_default))

    def ranking_table(self) -> str:
        """The ranking as a fixed-width text table."""
        # "before" is the model a row was scored against (``scored_against``): the base
        # model, or for an effect the ladder added, the model of the step before
        rows = [
            (
                "effect",
                "against",
                "nrmse before",
                "nrmse after",
                "fall %",
                "± (2 se)",
                "k",
                "significant",
            )
        ]
        for r in self.ranking:
            against = against_words(r.get("scored_against"))
            if r.get("status") == "failed":
                after, k = r["nrmse_after"], r["n_params"]  # null: the identification raised
                rows.append(
                    (
                        r["effect"],
                        against,
                        _f4(r["nrmse_before"]),
                        _f4(after),
                        "—",
                        "—",
                        "—" if k is None else str(k),
                        "fit failed",
                    )
                )
                continue
            rows.append(
                (
                    r["effect"],
                    against,
                    _f4(r["nrmse_before"]),
                    _f4(r["nrmse_after"]),
                    f"{r['fall_percent']:+.1f}",
                    f"{2 * r['fall_se_percent']:.1f}",
                    str(r["n_params"]),
                    "yes"
                    if r["significant"]
                    else ("ambiguous" if r["effect"] in self.ambiguous else "no"),
                )
            )
        return _table(rows)

    def ladder_table(self) -> str:
        rows = [("step", "model", "added", "nrmse", "fit %")]
        for s in self.ladder:
            rows.append(
                (
                    str(s["step"]),
                    "+".join([s.get("law") or self.model, *s["effects"]]),
                    s["added"] or (f"law {s['switched_law']}" if s.get("switched_law") else "-"),
                    f"{s['nrmse']:.4f}",
                    f"{s['fit_percent']:.2f}",
                )
            )
        return _table(rows)

    def plot(self, path: str | Path | None = None):  # -> matplotlib Figure
        """Ranking (held-out nrmse before/after per effect) and the ladder, side by side."""
        import matplotlib

        if path is not None:
            matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
        names = [r["effect"] for r in self.ranking][::-1]
        # null: no held-out run left to judge on (or, after, the identification raised)
        before = [r["nrmse_before"] or 0.0 for r in self.ranking][::-1]
        after = [r["nrmse_after"] or 0.0 for r in self.ranking][::-1]  # null: it raised
        y = np.arange(len(names))
        a1.barh(y + 0.2, before, 0.4, color="0.7", label="without")
        a1.barh(
            y - 0.2,
            after,
            0.4,
            label="with the effect",
            color=["tab:green" if r["significant"] else "tab:blue" for r in self.ranking][::-1],
        )
        a1.set_yticks(y, names)
        a1.set_xlabel("held-out nrmse")
        a1.set_title("Effect ranking")
        a1.legend(loc="best", framealpha=0.9)
        steps = [s["step"] for s in self.ladder]
        a2.plot(steps, [s["nrmse"] for s in self.ladder], "o-")
        for s in self.ladder:
            a2.annotate(
                s["added"] or self.model,
                (s["step"], s["nrmse"]),
                textcoords="offset points",
                xytext=(4, 6),
                fontsize=8,
            )
        a2.set_xticks(steps)
        a2.set_xlabel("ladder step")
        a2.set_ylabel("held-out nrmse")
        a2.set_title("Ladder: the error falling")
        a2.set_ylim(bottom=0)
        if path is not None:
            fig.savefig(path)
        return fig


def _f4(v: float | None) -> str:
    """A held-out nrmse for a table: four decimals, "—" when null."""
    return "—" if v is None else f"{v:.4f}"


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def _table(rows: list[tuple[str, ...]]) -> str:
    w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = []
    for j, r in enumerate(rows):
        lines.append("  ".join(c.ljust(w[i]) if i == 0 else c.rjust(w[i]) for i, c in enumerate(r)))
        if j == 0:
            lines.append("  ".join("-" * x for x in w))
    return "\n".join(lines)


# --------------------------------------------------------------------------- orchestration
def suggest_experiment(ambiguous: Sequence[str]) -> str:
    """What to measure next to separate the ambiguous effects."""
    if len(ambiguous) < 2:
        return ""
    pair = frozenset(ambiguous[:2])
    if pair in PAIR_EXPERIMENTS:
        return PAIR_EXPERIMENTS[pair]
    texts = []
    for e in ambiguous:
        cls = EFFECTS.get(e)
        if cls is not None and cls.experiment:
            texts.append(f"for {e}: {cls.experiment}")
    return "; ".join(texts) or "repeat at other frequencies, amplitudes and pressures"


def _ranking_json(
    rounds: Sequence[Round], steps: Sequence[LadderStep], ambiguous: Sequence[str]
) -> list[dict[str, Any]]:
    """The ranking, best first, with *significant* only where the ladder added the effect.

    Every field of a row comes from one round's scoring, named by its ``round``: an effect
    the ladder added at step k from round k (nrmse without = the model of step k − 1, with
    = step k; its fall, credited fall, block test and status there), every other effect from
    round 1 (against the base model).  ``significant_alone`` is round 1's verdict (the
    effect against the base model alone); ``rounds[k - 1]`` holds each round's full rows.
    """
    if not rounds:
        return []
    added = [s.added for s in steps[1:]]
    out = []
    for c in rounds[0].candidates:
        k = added.index(c.effect) + 1 if c.effect in added else None
        at = c if k is None else next(x for x in rounds[k - 1].candidates if x.effect == c.effect)
        d = at.as_json() | _round_keys(c, k, steps)
        d["significant"] = k is not None
        out.append(d)
    out.sort(key=_ladder_order)
    return out


def _round_keys(first: Candidate, k: int | None, steps: Sequence[LadderStep]) -> dict[str, Any]:
    """The keys that say which round a ``ranking`` or ``laws`` row comes from: the step
    ``k`` that took the candidate (None: not taken; its row is round 1's), round 1's verdict
    (``first``, against the base model alone) and the model the row was scored against."""
    return {
        "significant_alone": bool(first.significant),
        "ladder_step": k,
        "round": k or 1,
        "scored_against": "base" if not k or k == 1 else _model_words(steps[0], steps[k - 1]),
    }


def _ladder_order(d: Mapping[str, Any]) -> tuple:
    """Best first: the ladder's order, then the rest by their held-out fall
    (ranking.Candidate.fall); failed fits last (they carry no fall)."""
    return (
        d["ladder_step"] is None,
        d["ladder_step"] or 0,
        d.get("status") == "failed",
        -(d["fall_percent"] or 0.0),
    )


def _final_round(rounds: Sequence[Round], steps: Sequence[LadderStep]) -> Round | None:
    """The round scored against the final model, or None when the ladder stopped before
    scoring one (at its step limit or at the noise floor)."""
    return rounds[-1] if rounds and rounds[-1].step == len(steps) else None


def _law_row(c: Candidate) -> dict[str, Any]:
    """A law scored like an effect (``Candidate.effect`` is the law's id), as a ``laws`` row."""
    return {
        "law": c.effect,
        "status": "failed" if c.failed else "ok",
        **({"reason": c.failure()} if c.failed else {}),
        # null when no held-out run is left to judge on (Candidate.evidence)
        "nrmse_before": finite_or_none(c.nrmse_before),
        # an identification that raised has no error after it
        "nrmse_after": None if c.after.error else finite_or_none(c.nrmse_after),
        "fall_percent": None if c.failed else float(100.0 * c.fall),
        "gain_x_floor": None if c.failed else float(c.gain_x_floor),
        "block_t": None if c.block_t != c.block_t else float(min(c.block_t, 1e6)),
        "runs_improved": None if c.after.error else float(c.runs_improved),
        "significant": bool(c.significant),
        "per_run_before": [float(v) for v in c.before.nrmse],
        "per_run_after": None if c.after.error else [float(v) for v in c.after.nrmse],
        "runs_at_floor": int(sum(c.at_floor)),
        **({"left_out": c.left_out} if c.left_out else {}),
        # how the law's elements change with pressure, chosen by the identification's
        # own leave-one-pressure-out evidence (None: the law offers no structures)
        **_structure_keys(c.after.structure),
    }


def _laws_json(rounds: Sequence[Round], steps: Sequence[LadderStep]) -> list[dict[str, Any]]:
    """The other laws, best first, judged as the effects are (:func:`_ranking_json`):
    *significant* only where the ladder switched to the law and no later step replaced it
    (the final model's law; a replaced law keeps its ``ladder_step``).

    A law the ladder switched to at step k is shown from round k (against the model of step
    k − 1); every other law from round 1, against the base model.  ``significant_alone`` is
    round 1's verdict; ``significant_last`` the verdict against the final model, where the
    ladder scored the law against it (its last round; null when it stopped before, at its
    step limit or at the noise floor; absent when the ladder took no step or took this law).
    A law significant against the base model alone that the ladder did not take has
    absorbed what the effects it added explain — the same evidence effects are held to (a
    sensor drift on the held-out records lets any law's refit lower the base model's
    error)."""
    if not rounds:
        return []
    switched = {s.switched: s.step for s in steps[1:] if s.switched}
    # the final model's law: a law a later step replaced is no longer claimed
    final = steps[-1].law
    last = _final_round(rounds, steps)
    out = []
    for c in rounds[0].laws:
        k = switched.get(c.effect)
        at = c if k is None else next(x for x in rounds[k - 1].laws if x.effect == c.effect)
        d = _law_row(at) | _round_keys(c, k, steps)
        d["significant"] = k is not None and c.effect == final
        if k is None and last is not None and last is not rounds[0]:
            now = next((x for x in last.laws if x.effect == c.effect), None)
            d["significant_last"] = None if now is None else bool(now.significant)
        elif k is None and len(steps) > 1:
            d["significant_last"] = None  # the ladder stopped before scoring it again
        out.append(d)
    out.sort(key=_ladder_order)
    return out


def _alike_rows(rounds: Sequence[Round], steps: Sequence[LadderStep]) -> list[dict[str, Any]]:
    """The law rows :func:`laws_alike` compares: the laws of one round (their rows are scored
    against one model) — the round in which the ladder switched to the final model's law;
    without a switch, the round scored against the final model (round 1 when the ladder
    took no step; none when it added effects and stopped before scoring the laws again: a
    comparison against a model it moved past says nothing about the final one)."""
    if not rounds:
        return []
    k = next((s.step for s in reversed(steps[1:]) if s.switched), None)
    if k is not None:
        return [_law_row(c) for c in rounds[k - 1].laws]
    last = _final_round(rounds, steps)
    return [] if last is None else [_law_row(c) for c in last.laws]


def against_words(scored_against: str | None) -> str:
    """A row's ``scored_against`` for a table: ``base``, or the model of that step as the
    base law plus its effects (``base+viscous-friction``), or its own law when a step changed
    it (``maxwell-slip+viscous-friction``)."""
    if not scored_against or scored_against == "base":
        return "base"
    first = scored_against.split("+", 1)[0]
    return scored_against if first in LAWS else f"base+{scored_against}"


def _model_words(base: LadderStep, step: LadderStep) -> str:
    """The model of a ladder ``step`` as its effects joined by "+", led by its law when a
    step changed the law from the ``base`` step's."""
    return "+".join([*([step.law] if step.law != base.law else []), *step.effects])


#: what each pressure structure of an element law says about the muscle
STRUCTURE_WORDS = {
    "free": "every element parameter its own pressure law",
    "scaled": "one element profile whose magnitude scales with pressure",
    "scaled-thresholds": "one element profile whose magnitude and slip displacements "
    "scale with pressure",
}


def _structure_keys(js: Mapping[str, Any] | None) -> dict[str, Any]:
    """The ``laws[i]`` keys naming the law's pressure structure (empty without one)."""
    if not js:
        return {}
    return {
        "structure": js.get("chosen"),
        "structure_margin_percent": js.get("margin_percent"),
        "structure_heldout_nrmse": {
            c["structure"]: c.get("heldout_nrmse") for c in js.get("candidates", [])
        },
    }


def closest_law_phrase(
    model: str, laws: Sequence[Mapping[str, Any]], floors: Sequence[float] = ()
) -> str:
    """What the laws say when none is significant: the law that predicts best, if it beats
    the base model at all, with its gain against the rule's threshold — so a user whose loop
    has that law's shape is told, and told which part of the rule it fails (the gain within
    what noise gives, a held-out run it does not improve, or cycles that do not agree);
    ``""`` when no law predicts better than the base model.  ``floors``: the held-out runs'
    noise floors (nrmse), to tell which runs are at their floor (:func:`_why_not_claimed`)."""
    ok = [
        lw
        for lw in laws
        if lw.get("status") != "failed"
        and lw.get("gain_x_floor") is not None
        and lw["nrmse_after"] is not None
        and lw["nrmse_before"] is not None
        and lw["nrmse_after"] < lw["nrmse_before"]
    ]
    if not ok:
        return ""
    b = min(ok, key=lambda lw: lw["nrmse_after"])
    fall = 100.0 * (1.0 - b["nrmse_after"] / b["nrmse_before"])
    return (
        f"Of the hysteresis laws, {b['law']}{structure_phrase(b)} predicts best: "
        f"{b['nrmse_before']:.4f} → {b['nrmse_after']:.4f} (−{fall:.0f} %, "
        f"{b['gain_x_floor']:.2f} noise floors; a claim needs ≥ {MIN_GAIN_X_FLOOR:g}): the "
        f"loop may have its shape, but {_why_not_claimed(b, model, floors)}, so it is not "
        "claimed."
    )


def _absorbed_law_phrase(
    row: Mapping[str, Any], ladder: Sequence[Mapping[str, Any]], stop: str = ""
) -> str:
    """Why a law significant against the base model alone (``significant_alone``) is not
    claimed once the ladder added effects: against the final model it was not significant
    (``significant_last`` false), or it was not scored against it (the ladder stopped at its
    step limit)."""
    added = [s["added"] for s in ladder[1:] if s.get("added")]
    what = " and ".join(added) or "the ladder's steps"
    head = (
        f"Against the base model alone the {row['law']} law cut the validation error "
        f"{row['nrmse_before']:.4f} → {row['nrmse_after']:.4f} "
        f"(−{row['fall_percent']:.0f} %), "
    )
    if row.get("significant_last") is False:
        return (
            head + f"but not against the model with {what}: its fall there was part of what "
            f"{what} explain{'s' if len(added) == 1 else ''}, so it is not claimed."
        )
    why = {
        "max steps": "at its step limit (raise --max-steps to judge it)",
        "at the noise floor": "at the noise floor, where no law has a claim's gain left",
        "every candidate in": "with every candidate in the model",
    }.get(stop, stop or "first")
    return (
        head + f"but it was not scored against the model with {what} (the ladder stopped "
        f"{why}), so it is not claimed."
    )


def _why_not_claimed(row: Mapping[str, Any], model: str, floors: Sequence[float] = ()) -> str:
    """The part of the significance rule a not-significant law row fails, in words (the
    first that fails, in the rule's order: the mean gain, every held-out run, cycle by
    cycle).  With the held-out runs' noise floors (``floors``) a run is exempt from falling
    where it is at its floor without and with the law (``Candidate.at_floor``); without them
    only the count ``runs_at_floor`` is known, and a run that rose shows only when more runs
    rose than are at their floor."""
    if row["gain_x_floor"] < MIN_GAIN_X_FLOOR:
        return f"the gain over the {model} model is within what noise gives"
    before, after = row.get("per_run_before"), row.get("per_run_after")
    if before and after and len(before) == len(after):
        judged = judged_runs(before)
        fell = sum(after[i] < before[i] for i in judged)
        if len(floors) == len(before):
            held = sum(
                after[i] < before[i] or max(before[i], after[i]) < AT_FLOOR_RATIO * floors[i]
                for i in judged
            )
        else:
            held = fell + int(row.get("runs_at_floor") or 0)
        if held < len(judged):
            return (
                f"it lowers the error on only {fell} of {len(judged)} held-out runs (the rule "
                "asks for every run not at its noise floor)"
            )
    t = row.get("block_t")
    if t is not None and t < MIN_BLOCK_T:
        return f"its fall is not consistent cycle by cycle (block t {t:.1f} < {MIN_BLOCK_T:g})"
    return "it does not pass the significance rule"


def laws_alike(laws: Sequence[Mapping[str, Any]]) -> list[str]:
    """The laws that predict the held-out runs about equally well as the best one (the
    best first), or ``[]``: among the laws (of one round: their rows scored against one
    model) that cut that model's error, those whose
    fall is ≥ ``AMBIGUITY_RATIO`` of the best's and which the best does not beat run by run
    beyond chance (:func:`~pmalab.identify.diagnosis.ranking.alike` — the rule that makes
    two significant effects ambiguous).  A statement of what the runs can tell apart, not a
    claim: significance is the ranking rule's alone."""
    ok = [
        lw
        for lw in laws
        if lw.get("status") != "failed"
        and lw.get("fall_percent") is not None
        and lw.get("per_run_after") is not None
        and lw["fall_percent"] > 0.0
    ]
    if len(ok) < 2:
        return []
    best = max(ok, key=lambda lw: lw["fall_percent"])
    # the runs the base model predicted (every law row is scored against the same base): a
    # run it diverged on is no evidence, and both laws "fall" ~DIVERGED_NRMSE there
    before = best.get("per_run_before")
    judged = judged_runs(before) if before else range(len(best["per_run_after"]))

    def runs(lw: Mapping[str, Any]) -> list[float]:
        r = lw["per_run_after"]
        return [r[i] for i in judged] if len(r) == len(best["per_run_after"]) else list(r)

    same = [
        lw["law"]
        for lw in sorted(ok, key=lambda lw: -lw["fall_percent"])
        if lw is not best
        and alike(best["fall_percent"] / 100.0, runs(best), lw["fall_percent"] / 100.0, runs(lw))
    ]
    return [best["law"], *same] if same else []


def alike_phrase(alike_laws: Sequence[str]) -> str:
    """The summary's sentence on :func:`laws_alike` (``""`` for none)."""
    if len(alike_laws) < 2:
        return ""
    best, others = alike_laws[0], list(alike_laws[1:])
    names = " and ".join(others)
    elements = all(LAWS.get(lw) is not None and LAWS[lw].structures for lw in alike_laws)
    return (
        f"The {names} law{'s' if len(others) > 1 else ''} predict"
        f"{'' if len(others) > 1 else 's'} the held-out runs about as well as {best} "
        f"(≥ {100 * AMBIGUITY_RATIO:.0f} % of its fall, and {best} is not lower run by run "
        "beyond chance): these runs cannot tell them apart"
        + (" (both are sums of elasto-slide elements)." if elements else ".")
    )


def structure_phrase(row: Mapping[str, Any]) -> str:
    """`` with <the structure in words> (chosen by … by N %)`` for a laws row, or ``""``."""
    st = row.get("structure")
    if not st:
        return ""
    m = row.get("structure_margin_percent")
    words = margin_words(m) if isinstance(m, (int, float)) else ""
    by = f", {words}" if words else ""
    return (
        f" with {STRUCTURE_WORDS.get(st, st)} ('{st}', chosen by leave-one-pressure-out "
        f"held-out error{by})"
    )


def _not_carried(ranking: Sequence[dict]) -> list[str]:
    """A sentence for each effect whose fall would pass the rule but which itself carries too
    little of it (``gain_carried_x_floor``): why it is not claimed."""
    out = []
    for r in ranking:
        g, c = r.get("gain_x_floor"), r.get("gain_carried_x_floor")
        # an effect claimed alone or added by the ladder is not "not claimed"
        if r.get("significant_alone") or r.get("significant") or g is None or c is None:
            continue
        if g >= MIN_GAIN_X_FLOOR > c:
            out.append(
                f"{r['effect']} cut the validation error by {g:.2f} noise floors, but the "
                f"effect itself carries only {max(c, 0.0):.2f} of them (the identified model "
                "without it predicts the held-out runs about as well): the fall came from the "
                "other parameters moving, so it is no evidence for the effect and is not claimed."
            )
    return out


def _summary(
    model: str,
    ladder: list[dict],
    ranking: list[dict],
    ambiguous: list[str],
    floor: float,
    worst: tuple[str, str] | None,
    suggestion: str,
    scheme: str,
    run_floors: Sequence[float] = (),
    laws: Sequence[dict] = (),
    rest: dict | None = None,
    single_frequency: float | None = None,
    stop: str = "",
    alike_rows: Sequence[dict] | None = None,
) -> tuple[str, str]:
    """(summary sentence, verdict).  Every number is the held-out (validation) nrmse of an
    identification, i.e. what ``pmalab identify [--add ...]`` reports on the same runs."""
    base, last = ladder[0], ladder[-1]
    parts = [
        f"Base {model} model: validation nrmse {base['nrmse']:.4f} "
        f"({base['nrmse'] / floor:.1f}× the noise floor {floor:.4f}; {scheme})."
    ]
    if div := base.get("diverged"):
        every = len(div) == len(base.get("per_run") or div)
        parts.append(
            f"Its held-out prediction diverged or ran off on {', '.join(div)} (counted at "
            f"nrmse {DIVERGED_NRMSE:g}): the {model} identification does not hold there, so "
            + (
                "no held-out run is left to judge a candidate on."
                if every
                else f"{'that run is' if len(div) == 1 else 'those runs are'} no evidence "
                "for any candidate: each is judged on the other runs, and one whose own "
                "prediction diverges there too is a failed fit."
            )
        )
    if len(ladder) == 1:
        best = next(
            (
                r
                for r in ranking
                if r.get("status") != "failed"
                and r.get("nrmse_before") is not None
                and r.get("nrmse_after") is not None
            ),
            None,
        )
        parts.append(
            "No catalogue effect cuts the validation error significantly"
            + (
                f" (best: {best['effect']}, {best['nrmse_before']:.4f} → "
                f"{best['nrmse_after']:.4f}, {best['fall_percent']:.0f} %)."
                if best
                else "."
            )
        )
    else:
        names = ", then ".join(s["added"] or f"the {s['switched_law']} law" for s in ladder[1:])
        total = 100.0 * (1.0 - last["nrmse"] / base["nrmse"]) if base["nrmse"] > 0 else 0.0
        steps = " → ".join(
            f"{'+' + s['added'] if s['added'] else s['switched_law'] + ' law'} {s['nrmse']:.4f}"
            for s in ladder[1:]
        )
        what = (
            "Ladder"
            if any(s.get("switched_law") for s in ladder[1:])
            else f"Missing effect{'s' if len(ladder) > 2 else ''}"
        )
        parts.append(
            f"{what}: {names} — validation nrmse {base['nrmse']:.4f} {steps} (−{total:.0f} %)."
        )
    parts += _not_carried(ranking)
    failed = [r for r in ranking if r.get("status") == "failed"]
    failed += [lw for lw in laws if lw.get("status") == "failed"]
    if failed:
        parts.append(
            "Fit failed (not ranked): "
            + "; ".join(f"{r.get('effect') or r.get('law')}: {r['reason']}" for r in failed)
            + "."
        )
    # the law of the final model: the last step that switched it (a later switch replaces
    # an earlier one's law)
    switch = next((s for s in reversed(ladder[1:]) if s.get("switched_law")), None)
    if switch is not None:
        prev = ladder[switch["step"] - 1]
        fall = 100.0 * (1.0 - switch["nrmse"] / prev["nrmse"]) if prev["nrmse"] > 0 else 0.0
        lw_row = next((lw for lw in laws if lw["law"] == switch["switched_law"]), {})
        parts.append(
            f"The loop's shape is the {switch['switched_law']} law's"
            f"{structure_phrase(lw_row)}: try `--model "
            f"{switch['switched_law']}`: {prev['nrmse']:.4f} → {switch['nrmse']:.4f} "
            f"(−{fall:.0f} %)."
        )
    else:
        alone = [lw for lw in laws if lw.get("significant_alone") and not lw["significant"]]
        if alone and len(ladder) > 1:
            parts.append(_absorbed_law_phrase(alone[0], ladder, stop))
        elif alone:  # round 1 is the ladder's only round: nothing else to weigh it against
            b = alone[0]
            parts.append(
                f"Also significant: the {b['law']} law{structure_phrase(b)}: try "
                f"`--model {b['law']}`: {b['nrmse_before']:.4f} → "
                f"{b['nrmse_after']:.4f} (−{b['fall_percent']:.0f} %)."
            )
        elif closest := closest_law_phrase(model, laws, run_floors):
            parts.append(closest)
    if same := alike_phrase(laws_alike(laws if alike_rows is None else alike_rows)):
        parts.append(same)
    ratio = last["nrmse"] / floor if floor > 0 else float("inf")
    if ratio < UNEXPLAINED_RATIO:
        verdict = "floor"
        parts.append(
            f"The {'final ' if len(ladder) > 1 else ''}model is at {ratio:.2f}× the "
            "noise floor: what is left is less than any effect the significance rule "
            f"could call real (≥ {MIN_GAIN_X_FLOOR:g} noise floors), nothing "
            "structured is left to explain."
        )
    else:
        verdict = "unexplained"
        # the worst place of the FINAL model (the base model's worst runs are listed apart)
        whose = "the final model's" if len(ladder) > 1 else "the model's"
        where = f"; {whose} largest residual is on {worst[0]}: {worst[1]}" if worst else ""
        parts.append(
            f"Unexplained structured residual, {ratio:.1f}× the noise floor{where} "
            "(a hysteresis law of another shape or an effect not in the catalogue)."
        )
        if rest and rest.get("text"):
            parts.append(rest["text"])
    if ambiguous and single_frequency is not None and all(rate_dependent(e) for e in ambiguous):
        parts.append(
            f"Ambiguous: {', '.join(ambiguous)} all grow with the rate of motion, and every "
            f"identification run is at {single_frequency:g} Hz — one frequency cannot tell "
            f"them apart (nor from the loop's width); to separate them, {suggestion}."
        )
    elif ambiguous:
        parts.append(
            f"Ambiguous: {', '.join(ambiguous)} explain the residual about equally; "
            f"to separate them, {suggestion}."
        )
    return " ".join(parts), verdict


def pressure_sentence(
    checks: Sequence[Any],
    steps: Sequence[LadderStep],
    ranking: Sequence[Mapping[str, Any]],
    stop: str = "",
) -> str:
    """What the summary says about the runs' pressure labels ("" when every label agrees
    with its measured mean): the offsets, and which of the two pressure effects the ladder
    added — the per-run offset (``pressure-offset``, the runs at their measured means) or
    the within-run variation (``pressure-variation``)."""
    line = label_warning(checks)
    if not line:
        return ""
    added = [s.added for s in steps[1:]]
    head = f" Pressure labels: {line.split(' — give')[0]}."
    if "pressure-offset" in added:
        k = added.index("pressure-offset") + 1
        return head + (
            f" The ladder took each run at its measured mean pressure (pressure-offset, step "
            f"{k}): the labels are off, not the pressure within the runs"
            + (
                "; the within-run variation came on top of it (pressure-variation)."
                if "pressure-variation" in added
                else "; the model then sits at the noise floor, nothing is left for the "
                "pressure within the runs."
                if stop == "at the noise floor"
                else "; the pressure within the runs explains nothing more (pressure-variation "
                "not significant)."
            )
            + " To identify with the measured pressures: --pressure measured (or --add "
            "pressure-offset)."
        )
    row = next((r for r in ranking if r.get("effect") == "pressure-offset"), None)
    if row is None:
        return head + (
            " pressure-offset (each run at its measured mean) was not among the candidates: "
            "compare with --pressure measured."
        )
    if row.get("status") == "failed":
        return head + (
            " The identification with each run at its measured mean (pressure-offset) "
            "failed (above): compare with --pressure measured."
        )
    fall = (
        ""
        if row["nrmse_before"] is None or row["nrmse_after"] is None
        else f" ({row['nrmse_before']:.4f} → {row['nrmse_after']:.4f})"
    )
    return head + (
        f" Taking each run at its measured mean (pressure-offset) does not cut the validation "
        f"error significantly{fall}: the offsets do not matter to this model."
    )


def diagnose(
    runs: Sequence[Run],
    model: str = "bouc-wen",
    validate: Sequence[Run] = (),
    effects: Sequence[str] | None = None,
    effects_files: Sequence[str | Path] = (),
    max_steps: int = 3,
    jobs: int = 1,
    progress: bool = False,
    whole_run: bool = False,
    laws: Sequence[str] | None = None,
    scheduler: str | None = None,
) -> Diagnosis:
    """Diagnose ``model`` on ``runs``: rank the effects, climb the ladder, localise the error.

    ``effects``: candidate ids (default: the whole catalogue, plus any user effects loaded
    from ``effects_files``).  ``laws``: the other hysteresis laws scored like effects
    (default: every registered law; ``()`` scores none).  ``validate``: held-out runs (default: see
    :mod:`pmalab.identify.diagnosis.heldout`).  ``whole_run``: use every sample instead of
    each recorded run's full-amplitude cycles (:meth:`~pmalab.runfile.Run.steady`).
    ``scheduler``: a Dask scheduler's address (``tcp://host:8786``): the candidates'
    identifications run on its workers (the same numbers as locally).
    """
    if model not in LAWS:
        raise DiagnoseError(f"unknown model '{model}' (choose from {', '.join(LAWS)})")
    runs = list(runs) if whole_run else [r.steady() for r in runs]
    validate = list(validate) if whole_run else [r.steady() for r in validate]
    if not runs:
        raise DiagnoseError("no runs to diagnose")
    user: list[str] = []
    files = [str(f) for f in effects_files]
    for f in files:
        user += load_user_effects(f)
    cand = list(effects) if effects is not None else [*EFFECTS]
    for e in [*cand, *user]:
        if e not in EFFECTS:
            raise DiagnoseError(f"unknown effect '{e}' (choose from {', '.join(EFFECTS)})")
    cand += [u for u in user if u not in cand]
    for r in [*runs, *validate]:
        if len(r) < 200:
            raise DiagnoseError(f"{r.label}: too few samples to diagnose ({len(r)}; need ≥ 200)")
    # runs whose measured mean pressure is not their label: said with the pressure effects
    label_checks = check_runs([*runs, *validate], whole_run=True)
    # pressure-offset (every run at its measured mean) is a candidate where a label is off:
    # with every label within its tolerance of the measurement the relabelled identification
    # differs by less than the gauge's noise and the regulator's resolution (not scored, said)
    not_scored: dict[str, str] = {}
    if effects is None and not any(c.offset for c in label_checks):
        for e in [e for e in cand if EFFECTS[e].pressure_source == "measured"]:
            cand.remove(e)
            not_scored[e] = (
                "every run's measured mean pressure is within its tolerance of the label"
            )
    split = choose(runs, validate)
    if not split.train:
        raise DiagnoseError("no identification runs left: every run is held out")
    # each run's floor as its error is scored (the part after its early part)
    floors = {r.label: heldout_floor(r) for r in split.held}
    floor = float(np.mean(list(floors.values())))
    other_laws = (
        [lw for lw in LAWS if lw != model] if laws is None else [lw for lw in laws if lw != model]
    )
    for lw in other_laws:
        if lw not in LAWS:
            raise DiagnoseError(f"unknown law '{lw}' (choose from {', '.join(LAWS)})")
    climbed = run_ladder(
        split.train,
        split.held,
        model,
        cand,
        files,
        max_steps,
        jobs,
        progress,
        laws=other_laws,
        scheduler=scheduler,
    )
    steps, rounds = climbed.steps, climbed.rounds
    amb = rounds[0].ambiguous if rounds else []
    suggestion = suggest_experiment(amb)
    final = steps[-1].effects

    # the base and final identifications' predictions of the held-out runs → diagnostics
    base_pred, final_pred = steps[0].scored.predictions, steps[-1].scored.predictions
    diagnostics: dict[str, Any] = {}
    traces: list[tuple[Run, np.ndarray, np.ndarray]] = []
    camp_items = []
    for run, fb, ff in zip(split.held, base_pred, final_pred):
        sig = Signals.from_run(run)
        d = run_diagnostics(sig, run.force, fb)
        sp = scored_part(run)
        d["nrmse_final"] = float(
            np.sqrt(np.mean((run.force[sp] - ff[sp]) ** 2)) / np.std(run.force[sp])
        )
        d["noise_floor_nrmse"] = floors[run.label]
        d["residual_shares"] = residual_shares(
            run.time,
            run.position,
            run.force - ff,
            floors[run.label] * float(np.std(run.force)),
            run.frequency,
            model_force=ff,
        )
        diagnostics[run.label] = d
        traces.append((run, fb, ff))
        camp_items.append((sig.p_nom, run.frequency, run.force - fb))
    worst = None
    if diagnostics:
        # where the FINAL model is worst (relative to each run's noise floor)
        i = int(
            np.argmax(
                [
                    diagnostics[r.label]["nrmse_final"] / max(floors[r.label], 1e-12)
                    for r in split.held
                ]
            )
        )
        run, _, ff = traces[i]
        worst = (
            run.label,
            str(run_diagnostics(Signals.from_run(run), run.force, ff).get("worst_region", "")),
        )
    ladder = [s.as_json() for s in steps]
    laws_json = _laws_json(rounds, steps)
    alike_rows = _alike_rows(rounds, steps)
    final_law = steps[-1].law or model
    ranking = _ranking_json(rounds, steps, amb)
    rest = residual_next_step([d["residual_shares"] for d in diagnostics.values()])
    summary, verdict = _summary(
        model,
        ladder,
        ranking,
        amb,
        floor,
        worst,
        suggestion,
        split.scheme,
        [floors[r.label] for r in split.held],
        laws_json,
        rest,
        single_frequency=one_frequency(split.train),
        stop=climbed.stop,
        alike_rows=alike_rows,
    )
    summary += pressure_sentence(label_checks, steps, ranking, climbed.stop)
    campaign = campaign_diagnostics(camp_items)
    rounds_json = [
        {
            "step": r.step,
            "ambiguous": r.ambiguous,
            "candidates": [c.as_json() for c in r.candidates],
            "laws": [_law_row(c) for c in r.laws],
        }
        for r in rounds
    ]
    settings = {
        "validation": split.scheme,
        "held_out": [r.label for r in split.held],
        "identification_runs": [r.label for r in split.train],
        "identify_hint": split.identify_hint,
        "max_steps": max_steps,
        # why the ladder stopped, and the identifications it made (each model once)
        "ladder_stop": climbed.stop,
        "identifications": climbed.identifications,
        "candidates": cand,
        "not_scored": not_scored,
        "scoring": "validation nrmse of `pmalab identify --add EFFECT` on the held-out "
        "runs (one identification per candidate); each held-out run's record parameters "
        "(start state, force zero, effect nuisances) estimated on its early part, the "
        "error scored on the rest",
        "pressure_labels": [c.as_json() for c in label_checks],
    }
    return Diagnosis(
        model=model,
        ranking=ranking,
        ambiguous=list(amb),
        suggested_experiment=suggestion,
        ladder=ladder,
        diagnostics=diagnostics,
        campaign=campaign,
        summary=summary,
        noise_floor={
            "mean_nrmse": floor,
            "per_run": floors,
            "method": "third differences of the measured force, robust "
            "scale (pmalab.identify.noise)",
        },
        verdict=verdict,
        rounds=rounds_json,
        settings=settings,
        traces=traces,
        final_effects=list(final),
        laws=laws_json,
        final_law=final_law,
        laws_alike=laws_alike(alike_rows),
        residual=rest,
    )


# --------------------------------------------------------------------------- writing
def write_outputs(diag: Diagnosis, out_dir: str | Path, force: bool = False) -> tuple[Path, Path]:
    """DIR/diagnosis.json and DIR/predictions.h5 (refuses to overwrite without ``force``).

    Both are written under temporary names before either is renamed: a failure (a full
    disk) leaves neither behind."""
    from pmalab.paths import check_output, write_together

    d = Path(out_dir)
    jpath = check_output(d / "diagnosis.json", force)
    hpath = check_output(d / "predictions.h5", force)
    d.mkdir(parents=True, exist_ok=True)
    write_together(
        {
            jpath: lambda p: p.write_text(json.dumps(diag.to_json(), indent=1, allow_nan=False)),
            hpath: lambda p: _write_predictions(diag, p),
        }
    )
    return jpath, hpath


def _write_predictions(diag: Diagnosis, hpath: Path) -> None:
    """Each held-out run under the base and the final model (:mod:`pmalab.identify.predictions`)."""
    final_name = "+".join([diag.final_law or diag.model, *diag.final_effects])
    items = []
    for run, fb, ff in diag.traces:
        items += [
            PredictionItem(run, "diagnosis", fb, diag.model),
            PredictionItem(run, "diagnosis-final", ff, final_name),
        ]
    write_predictions_file(hpath, items, final_name)
