"""The ladder: add the best significant effect, score the rest again, repeat.

Step 0 is the base law.  At every step each effect not yet in the model is added to the
current model and scored by the identification it gives on the held-out runs
(:mod:`.ranking`); the best is added if it is significant.  The ladder stops when nothing
significant is left, when every effect is in, or after ``max_steps`` additions.  The held-out
nrmse of every step is ``pmalab identify --add ...``'s validation nrmse of that model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from pmalab.identify.campaign import ModelSpec
from pmalab.identify.diagnosis.ranking import Candidate, Scored, judge, score, score_all
from pmalab.runfile import Run


@dataclass
class LadderStep:
    """One rung: the effects in the model after this step and its held-out error."""

    step: int
    effects: list[str]
    added: str | None
    scored: Scored

    @property
    def nrmse(self) -> float:
        return self.scored.mean

    @property
    def fit_percent(self) -> float:
        return 100.0 * (1.0 - self.nrmse)

    def as_json(self) -> dict:
        return {"step": self.step, "effects": list(self.effects), "added": self.added,
                "nrmse": float(self.nrmse), "fit_percent": float(self.fit_percent),
                "per_run": [float(v) for v in self.scored.nrmse],
                "model": "+".join(self.effects) or "base"}


@dataclass
class Round:
    """The ranking of the remaining effects at one ladder step."""

    step: int
    candidates: list[Candidate]
    ambiguous: list[str]


def run_ladder(
    train: Sequence[Run],
    held: Sequence[Run],
    law: str,
    effect_ids: Sequence[str],
    effects_files: Sequence[str] = (),
    max_steps: int = 3,
    jobs: int = 1,
    progress: bool = False,
) -> tuple[list[LadderStep], list[Round]]:
    """Climb the ladder; returns the steps (0 = base) and the ranking round of each step."""
    from pmalab.identify.noise import noise_floor_nrmse

    files = tuple(str(f) for f in effects_files)
    floors = [noise_floor_nrmse(r.force, r.time) for r in held]
    base = score(train, held, ModelSpec(law, (), files))
    steps = [LadderStep(0, [], None, base)]
    rounds: list[Round] = []
    current: tuple[str, ...] = ()
    while len(current) < max_steps:
        remaining = [e for e in effect_ids if e not in current]
        if not remaining:
            break
        specs = [ModelSpec(law, (*current, e), files) for e in remaining]
        outs = score_all(train, held, specs, jobs, progress,
                         f"step {len(steps)}: {len(remaining)} candidate effects")
        cands, amb = judge([Candidate(e, steps[-1].scored, o, floors=floors)
                            for e, o in zip(remaining, outs)])
        rounds.append(Round(len(steps), cands, amb))
        best = cands[0]
        if not best.significant:
            break
        current = (*current, best.effect)
        steps.append(LadderStep(len(steps), list(current), best.effect, best.after))
    return steps, rounds
