"""The ladder: add the best significant effect, score the rest again, repeat.

Step 0 is the base law.  At every step each effect not yet in the model is added to the
current model and scored by the identification it gives on the held-out runs
(:mod:`.ranking`); the best is added if it is significant.  The ladder stops when nothing
significant is left, when every effect is in, after ``max_steps`` additions, or when the
model reached the noise floor (below).  The held-out nrmse of every step is
``pmalab identify --add ...``'s validation nrmse of that model.

At the floor, no round is scored.  A candidate is significant only if it cuts the mean
held-out nrmse by ``MIN_GAIN_X_FLOOR`` (0.25) noise floors: mean(after) ≤ mean(before) −
0.25·mean(floor).  No model predicts the measurement noise of a record it did not see (the
noise on a run's scored part is independent of its prediction), so mean(after) ≥ mean(floor)
up to the sampling error of the noise power (≈ √(2/N) relative on N scored samples, under
1 % on these records).  A model whose held-out nrmse is below ``AT_FLOOR_RATIO`` = 1.25× the
floor therefore leaves no candidate that could pass the rule, and the ladder stops there
without scoring one (after step 0 the ranking round is always scored: it is the report).
This is the same threshold at which the summary calls the model "at the noise floor".

Work is not repeated: every identification is keyed by its model (law, effects), and a
model scored in an earlier round (the other laws with the same effects, after a step that
changed the law) is taken from there — the numbers are those of the same identification.
The base model is identified together with the first round's candidates, first (the base
law's per-run fits it makes are handed to the candidates that start from them), and each
round's other identifications are started longest first (laws with pressure structures,
then by number of effects), so two workers finish a round together.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pmalab.errors import PmalabError
from pmalab.identify.campaign import ModelSpec
from pmalab.identify.campaign.batch import ContextPool
from pmalab.identify.diagnosis.ranking import (
    AT_FLOOR_RATIO,
    Candidate,
    Scored,
    heldout_floor,
    judge,
    score_all,
)
from pmalab.identify.laws import LAWS
from pmalab.identify.signals import keep_run_signals
from pmalab.runfile import Run

__all__ = ["AT_FLOOR_RATIO", "Ladder", "LadderError", "LadderStep", "Round", "run_ladder"]


class LadderError(PmalabError):
    """The ladder cannot climb: the base model's identification failed."""


#: why the ladder stopped (``Ladder.stop``)
STOP_REASONS = ("nothing significant", "at the noise floor", "max steps", "every candidate in")


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
            # runs its prediction diverged or ran off (nrmse ≥ DIVERGED_NRMSE) on: no
            # evidence for the next step's candidates
            **({"diverged": self.scored.unjudged} if self.scored.unjudged else {}),
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


@dataclass
class Ladder:
    """The climbed ladder: its steps (0 = the base law), the ranking round scored at each
    step, why it stopped (one of ``STOP_REASONS``) and how many identifications it made."""

    steps: list[LadderStep]
    rounds: list[Round]
    stop: str
    identifications: int

    def __iter__(self):  # ``steps, rounds = run_ladder(...)``
        return iter((self.steps, self.rounds))


def one_frequency(train: Sequence[Run]) -> float | None:
    """The one excitation frequency (Hz) all identification runs share, else None (several,
    or one run's frequency unknown: not known to be one)."""
    freqs = [r.frequency for r in train]
    if not freqs or any(f is None for f in freqs):
        return None
    distinct = {round(float(f), 6) for f in freqs if f is not None}
    return distinct.pop() if len(distinct) == 1 else None


def cost_order(specs: Sequence[ModelSpec], seconds: Mapping[str, float] | None = None) -> list[int]:
    """Indices of ``specs``, the dearest identification first: a law with pressure
    structures (which fits each structure) before one without, then the dearer the
    identification that last added the same effect (``seconds``: effect id → CPU seconds it
    took, measured in an earlier round; a delay makes every fit dearer, whatever the law),
    then more effects first."""
    took = seconds or {}

    def cost(i: int) -> tuple[int, float, int]:
        law = LAWS.get(specs[i].law)
        last = specs[i].effects[-1] if specs[i].effects else ""
        return (
            1 if law is not None and law.structures else 0,
            took.get(last, 0.0),
            len(specs[i].effects),
        )

    return sorted(range(len(specs)), key=cost, reverse=True)


class Scorer:
    """Scores model specs on one split, each identification once (keyed by its spec)."""

    def __init__(
        self,
        train: Sequence[Run],
        held: Sequence[Run],
        jobs: int = 1,
        progress: bool = False,
        scheduler: str | None = None,
    ) -> None:
        self.train, self.held = list(train), list(held)
        self.jobs, self.progress, self.scheduler = jobs, progress, scheduler
        self.done: dict[ModelSpec, Scored] = {}
        #: identifications made (a spec taken from an earlier round is not counted)
        self.count = 0
        #: local workers kept across the rounds (see :meth:`close`)
        self.pool = None if scheduler else ContextPool((self.train, self.held), jobs)
        #: the base-law fits the workers made, handed to every later round's candidates
        #: (:func:`~pmalab.identify.diagnosis.ranking.score_all`)
        self.base_fits: dict = {}
        #: effect id → CPU seconds of the latest identification whose last effect it is: a
        #: later round starts the candidates adding the dearest effects first (cost_order)
        self.seconds: dict[str, float] = {}

    def close(self) -> None:
        """Shut the workers kept across the rounds down."""
        if self.pool is not None:
            self.pool.close()

    def __call__(
        self, specs: Sequence[ModelSpec], desc: str, first: ModelSpec | None = None
    ) -> list[Scored]:
        todo = list(dict.fromkeys(s for s in specs if s not in self.done))
        order = [todo[i] for i in cost_order(todo, self.seconds)]
        if first in order:
            # handed out before the rest (see run_ladder)
            order.remove(first)
            order.insert(0, first)
        outs = score_all(
            self.train,
            self.held,
            order,
            self.jobs,
            self.progress,
            desc,
            scheduler=self.scheduler,
            pool=self.pool,
            base_fits=self.base_fits,
        )
        self.done.update(zip(order, outs))
        self.seconds.update((s.effects[-1], o.seconds) for s, o in zip(order, outs) if s.effects)
        self.count += len(order)
        return [self.done[s] for s in specs]


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
) -> Ladder:
    """Climb the ladder; returns its steps (0 = base), the ranking round of each step and
    why it stopped (:class:`Ladder`).

    At every step each remaining effect is added to the current model and each law of
    ``laws`` replaces the current law (same effects); all are scored by the same
    identification on the same held-out runs and judged by the same rule.  The best
    significant candidate — an effect or a law — is taken."""
    files = tuple(str(f) for f in effects_files)
    floors = [heldout_floor(r) for r in held]
    floor = float(np.mean(floors)) if floors else float("nan")
    # one excitation frequency in the identification runs: rate-dependent effects are then
    # not identifiable apart (ranking.judge)
    single = one_frequency(train) is not None
    if jobs > 1 and not scheduler:
        # the workers start from this process (forked: they inherit the laws' compiled code
        # loaded here; spawned: they load what this process compiled and cached) instead of
        # each compiling the same kernels on a new numba cache
        for name in dict.fromkeys((law, *laws)):
            cls = LAWS.get(name)
            if cls is not None:
                cls().load_compiled()
    scorer = Scorer(train, held, jobs, progress, scheduler)
    # identifications made in this process (one job) filter and differentiate each run once,
    # as a worker does (the runs are this ladder's own until it returns)
    keep_run_signals([*scorer.train, *scorer.held])
    try:
        base_spec = ModelSpec(law, (), files)
        steps: list[LadderStep] = []
        rounds: list[Round] = []
        current: tuple[str, ...] = ()
        cur_law = law
        tried = {law}
        stop = "max steps"
        while True:
            remaining = [e for e in effect_ids if e not in current]
            others = [lw for lw in laws if lw not in tried]
            specs: list[ModelSpec] = []
            if steps and len(steps) > max_steps:
                break
            if steps and not remaining and not others:
                stop = "every candidate in"
                break
            if len(steps) > 1 and steps[-1].nrmse < AT_FLOOR_RATIO * floor:
                stop = "at the noise floor"
                break
            if max_steps >= 1:
                specs = [ModelSpec(cur_law, (*current, e), files) for e in remaining]
                specs += [ModelSpec(lw, current, files) for lw in others]
            # the base model is identified with the first round (one batch for the workers),
            # first: its per-run fits of the base law are where every candidate with effects
            # starts, and the candidates handed out after it get them (Scorer.base_fits)
            outs = scorer(
                [*specs, *([] if steps else [base_spec])],
                f"step {max(len(steps), 1)}: {len(remaining)} effects, {len(others)} laws",
                first=None if steps else base_spec,
            )
            if not steps:
                steps.append(LadderStep(0, [], None, outs.pop(), law))
                if steps[0].scored.error:  # nothing to score the candidates against
                    raise LadderError(
                        f"the base {law} model's identification raised "
                        f"{steps[0].scored.error}: nothing to diagnose against"
                    )
            if not specs:
                if max_steps >= 1:
                    stop = "every candidate in"
                break
            prev = steps[-1].scored
            cands, amb = judge(
                [Candidate(e, prev, o, floors=floors) for e, o in zip(remaining, outs)],
                single_frequency=single,
            )
            law_cands, _ = judge(
                [
                    Candidate(lw, prev, o, floors=floors)
                    for lw, o in zip(others, outs[len(remaining) :])
                ]
            )
            rounds.append(Round(len(steps), cands, amb, law_cands))
            pool = [c for c in [*cands, *law_cands] if c.significant]
            if not pool:
                stop = "nothing significant"
                break
            best = max(pool, key=lambda c: c.fall)
            if best in law_cands:
                cur_law = best.effect
                tried.add(cur_law)
                steps.append(
                    LadderStep(len(steps), list(current), None, best.after, cur_law, cur_law)
                )
            else:
                current = (*current, best.effect)
                steps.append(
                    LadderStep(len(steps), list(current), best.effect, best.after, cur_law)
                )
        return Ladder(steps, rounds, stop, scorer.count)
    finally:
        scorer.close()  # the workers kept across the rounds
        keep_run_signals([])
