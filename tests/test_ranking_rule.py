"""The judging rule on scored candidates (no fitting): significance, and when two
significant effects are ambiguous — by their falls, or because the identification runs
share one frequency and both effects grow with the rate of motion."""

from __future__ import annotations

from pmalab.identify.diagnosis.ranking import Candidate, Scored, judge

FLOORS = [0.0035, 0.0035]
BASE = Scored(effects=(), nrmse=[0.040, 0.047])


def _cands(*pairs: tuple[str, list[float]]) -> list[Candidate]:
    return [Candidate(e, BASE, Scored(effects=(e,), nrmse=a), floors=FLOORS) for e, a in pairs]


def test_one_frequency_makes_rate_dependent_winners_ambiguous():
    # the seed campaign with hidden viscous friction: a delay falls 67 %, viscous 51 %
    pairs = (("sensor-delay", [0.013, 0.016]), ("viscous-friction", [0.019, 0.024]))
    cands, amb = judge(_cands(*pairs))
    assert [c.effect for c in cands] == ["sensor-delay", "viscous-friction"]
    assert all(c.significant for c in cands)
    assert amb == []  # 51/67 < 85 %: apart by their falls ...
    _, amb = judge(_cands(*pairs), single_frequency=True)
    # ... but one training frequency cannot tell a viscous force from a delay
    assert amb == ["sensor-delay", "viscous-friction"]


def test_one_frequency_leaves_other_effects_alone():
    pairs = (("sensor-delay", [0.013, 0.016]), ("nonlinear-stiffness", [0.019, 0.024]))
    _, amb = judge(_cands(*pairs), single_frequency=True)
    assert amb == []
    # and a rate-dependent runner-up that is not significant stays out of it
    pairs = (("sensor-delay", [0.013, 0.016]), ("inertia", [0.039, 0.048]))
    cands, amb = judge(_cands(*pairs), single_frequency=True)
    assert not cands[1].significant and amb == []
