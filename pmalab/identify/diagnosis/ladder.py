"""The ladder: add the best significant effect, score the rest again, repeat.

Step 0 is the base law.  At every step each effect not yet in the model is added to the
current model and scored by the identification it gives on the held-out runs
(:mod:`.ranking`); the best is added if it is significant.  The ladder stops when nothing
significant is left, when every effect is in, or after ``max_steps`` additions.  The held-out
nrmse of every step is ``pmalab identify --add ...``'s validation nrmse of that model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from pmalab.identify.campaign import ModelSpec
from pmalab.identify.diagnosis.ranking import (
    Candidate,
    Scored,
    heldout_floor,
    judge,
    score,
    score_all,
)
from pmalab.runfile import Run


@dataclass
class LadderStep:
    """One rung: the law and effects in the model after this step and its held-out error.

    ``added`` is the effect this step added; a step that changed the law has ``added`` None
    and ``switched`` the new law id."""

    step: int
    effects: list[str]
    added: str | None
    scored: Scored
    law: str = ""
    switched: str | None = None

    @property
    def nrmse(self) -> float:
        return self.scored.mean

    @property
    def fit_percent(self) -> float:
        return 100.0 * (1.0 - self.nrmse)

    def as_json(self) -> dict:
        return {
            "step": self.step,
            "effects": list(self.effects),
            "added": self.added,
            "law": self.law,
            "switched_law": self.switched,
            "nrmse": float(self.nrmse),
            "fit_percent": float(self.fit_percent),
            "per_run": [float(v) for v in self.scored.nrmse],
            "model": "+".join(self.effects) or "base",
        }


@dataclass
class Round:
    """The ranking of the remaining effects (and of the other laws) at one ladder step."""

    step: int
    candidates: list[Candidate]
    ambiguous: list[str]
    #: the other laws with the same effects, scored like effects (``Candidate.effect`` is
    #: the law id)
    laws: list[Candidate] = field(default_factory=list)


def one_frequency(train: Sequence[Run]) -> float | None:
    """The one excitation frequency (Hz) all identification runs share, else None (several,
    or one run's frequency unknown: not known to be one)."""
    freqs = [r.frequency for r in train]
    if not freqs or any(f is None for f in freqs):
        return None
    distinct = {round(float(f), 6) for f in freqs if f is not None}
    return distinct.pop() if len(distinct) == 1 else None


def run_ladder(
    train: Sequence[Run],
    held: Sequence[Run],
    law: str,
    effect_ids: Sequence[str],
    effects_files: Sequence[str] = (),
    max_steps: int = 3,
    jobs: int = 1,
    progress: bool = False,
    laws: Sequence[str] = (),
    scheduler: str | None = None,
) -> tuple[list[LadderStep], list[Round]]:
    """Climb the ladder; returns the steps (0 = base) and the ranking round of each step.

    At every step each remaining effect is added to the current model and each law of
    ``laws`` replaces the current law (same effects); all are scored by the same
    identification on the same held-out runs and judged by the same rule.  The best
    significant candidate — an effect or a law — is taken."""
    files = tuple(str(f) for f in effects_files)
    floors = [heldout_floor(r) for r in held]
    # one excitation frequency in the identification runs: rate-dependent effects are then
    # not identifiable apart (ranking.judge)
    single = one_frequency(train) is not None
    base = score(train, held, ModelSpec(law, (), files))
    steps = [LadderStep(0, [], None, base, law)]
    rounds: list[Round] = []
    current: tuple[str, ...] = ()
    cur_law = law
    tried = {law}
    while len(steps) <= max_steps:
        remaining = [e for e in effect_ids if e not in current]
        others = [lw for lw in laws if lw not in tried]
        if not remaining and not others:
            break
        specs = [ModelSpec(cur_law, (*current, e), files) for e in remaining]
        specs += [ModelSpec(lw, current, files) for lw in others]
        outs = score_all(
            train,
            held,
            specs,
            jobs,
            progress,
            f"step {len(steps)}: {len(remaining)} effects, {len(others)} laws",
            scheduler=scheduler,
        )
        prev = steps[-1].scored
        cands, amb = judge(
            [Candidate(e, prev, o, floors=floors) for e, o in zip(remaining, outs)],
            single_frequency=single,
        )
        law_cands, _ = judge(
            [Candidate(lw, prev, o, floors=floors) for lw, o in zip(others, outs[len(remaining) :])]
        )
        rounds.append(Round(len(steps), cands, amb, law_cands))
        pool = [c for c in [*cands, *law_cands] if c.significant]
        if not pool:
            break
        best = max(pool, key=lambda c: c.fall)
        if best in law_cands:
            cur_law = best.effect
            tried.add(cur_law)
            steps.append(LadderStep(len(steps), list(current), None, best.after, cur_law, cur_law))
        else:
            current = (*current, best.effect)
            steps.append(LadderStep(len(steps), list(current), best.effect, best.after, cur_law))
    return steps, rounds
