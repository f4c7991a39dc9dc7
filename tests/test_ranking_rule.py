"""The judging rule on scored candidates (no fitting): significance, and when two
significant effects are ambiguous — by their falls, or because the identification runs
share one frequency and both effects grow with the rate of motion."""

from __future__ import annotations

import pytest

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


def test_a_diverged_candidate_fit_is_failed_never_ranked():
    # the real cylinder records' X-ring case: 0.1082 -> 0.2760, -155 % +- 273: per-run errors
    # all over the place (one run 6x worse), so not a fall a user could rank
    base = Scored(effects=(), nrmse=[0.10, 0.11, 0.115])
    wild = Scored(effects=("asymmetric-hysteresis",), nrmse=[0.09, 0.70, 0.04])
    good = Scored(effects=("viscous-friction",), nrmse=[0.095, 0.10, 0.11])
    cands, _ = judge(
        [
            Candidate("asymmetric-hysteresis", base, wild, floors=[0.004] * 3),
            Candidate("viscous-friction", base, good, floors=[0.004] * 3),
        ]
    )
    failed = cands[-1]
    assert failed.effect == "asymmetric-hysteresis" and failed.failed
    assert not failed.significant
    j = failed.as_json()
    assert j["status"] == "failed" and "rose" in j["reason"]
    assert j["fall_percent"] is None and j["gain_x_floor"] is None
    assert cands[0].as_json()["status"] == "ok" and cands[0].significant


def test_diverged_prediction_and_bound_hits_are_failures_with_their_reason():
    base = Scored(effects=(), nrmse=[0.05, 0.06], param_names=frozenset({"k"}), n_runs=4)
    div = Scored(effects=("inertia",), nrmse=[10.0, 0.05], diverged=["run-a"])
    assert "diverged on run-a" in Candidate("inertia", base, div, floors=FLOORS).failure()
    # a rise with the new parameter on its (non-zero) bound on 3 of 4 runs
    hit = Scored(
        effects=("sensor-delay",),
        nrmse=[0.052, 0.061],
        param_names=frozenset({"k", "delay_tau"}),
        at_bounds={"delay_tau": 3},
        n_runs=4,
    )
    why = Candidate("sensor-delay", base, hit, floors=FLOORS).failure()
    assert "delay_tau on 3 of 4 runs" in why
    # the same small rise without bound hits is an ordinary (not significant) result
    ok = Scored(effects=("sensor-delay",), nrmse=[0.052, 0.061], n_runs=4)
    c = Candidate("sensor-delay", base, ok, floors=FLOORS)
    assert c.failure() == "" and not judge([c])[0][0].significant


def test_a_held_out_run_at_its_noise_floor_is_no_evidence_either_way():
    # the tared drift of the subtle suite, seed 203: the 0.5 Hz held-out run falls from 3.8x
    # to 1.0x its floor; the 1 s run at 2 Hz (its last 0.5 s scored) is at its floor with and
    # without the drift (the zero moved less than the noise there): 1.13x -> 1.14x
    floors = [0.0224, 0.0194]
    base = Scored(effects=(), nrmse=[0.0845, 0.0219])
    drift = Candidate(
        "sensor-drift", base, Scored(("sensor-drift",), [0.0229, 0.0221]), floors=floors
    )
    assert drift.at_floor == [False, True] and drift.runs_improved == 0.5
    assert drift.every_run and judge([drift])[0][0].significant
    assert drift.as_json()["runs_at_floor"] == 1
    # a run above its floor before must fall: 1.5x its floor, slightly worse after -> not
    base = Scored(effects=(), nrmse=[0.0845, 1.5 * 0.0194])
    worse = Scored(("sensor-drift",), [0.0229, 1.5 * 0.0194 + 0.0002])
    c = Candidate("sensor-drift", base, worse, floors=floors)
    assert c.at_floor == [False, False] and not c.every_run and not judge([c])[0][0].significant
    # ... and so must one that the candidate pushes off the floor (1.1x -> 1.3x)
    base = Scored(effects=(), nrmse=[0.0845, 1.1 * 0.0194])
    off = Scored(("sensor-drift",), [0.0229, 1.3 * 0.0194])
    assert not Candidate("sensor-drift", base, off, floors=floors).every_run
    # every run at its floor: nothing fell beyond noise, nothing is claimed
    base = Scored(effects=(), nrmse=[1.2 * 0.0224, 1.2 * 0.0194])
    tiny = Scored(("sensor-drift",), [1.1 * 0.0224, 1.21 * 0.0194])
    c = Candidate("sensor-drift", base, tiny, floors=floors)
    assert c.every_run and not judge([c])[0][0].significant  # the gain is under 0.25 floors


def test_a_fall_the_effects_own_force_does_not_carry_is_no_evidence():
    # break-away spikes (look-alike), seed 301: inertia cuts both held-out runs (0.30 floors)
    # but without its m·ẍ the identified model predicts the 0.5 Hz run as well (0.0341)
    floors = [0.0217, 0.0227]
    base = Scored(effects=(), nrmse=[0.0430, 0.0518])
    spikes = Scored(("inertia",), [0.0342, 0.0475], without_last=[0.0341, 0.0491])
    c = Candidate("inertia", base, spikes, floors=floors)
    assert c.every_run and c.gain_x_floor >= 0.25  # the fall alone passed the rule
    assert c.carried is not None and c.carried[0] < 0 < c.carried[1]
    assert c.gain_carried_x_floor < 0.1
    assert not judge([c])[0][0].significant
    j = c.as_json()
    assert j["gain_carried_x_floor"] < 0.1 and j["per_run_without_effect"] == [0.0341, 0.0491]
    # a true 25 kg mass (subtle suite, seed 201): without its force the 2 Hz run is 4x worse
    base = Scored(effects=(), nrmse=[0.0355, 0.0941])
    mass = Scored(("inertia",), [0.0241, 0.0281], without_last=[0.0257, 0.1218])
    c = Candidate("inertia", base, mass, floors=floors)
    assert c.gain_carried_x_floor == pytest.approx((0.0016 + 0.0660) / 2 / 0.0222, rel=1e-6)
    assert judge([c])[0][0].significant
    # the removal is of the candidate's own (last) effect only; none measured: the fall alone
    other = Scored(("viscous-friction", "inertia"), [0.0342, 0.0475], without_last=[0.0341, 0.0491])
    c = Candidate("viscous-friction", base, other, floors=floors)
    assert c.carried is None and c.gain_carried_x_floor == c.gain_x_floor
    assert c.as_json()["gain_carried_x_floor"] is None


def test_an_effect_the_ladder_added_is_never_called_not_claimed():
    # the "carries too little" sentence is for effects left out; an effect the ladder added
    # at a later step (its round-1 row may carry little) is claimed, not explained away
    from pmalab.identify.diagnosis.diagnose import _not_carried

    row = {"effect": "viscous-friction", "significant_alone": False, "significant": True,
           "ladder_step": 2, "gain_x_floor": 0.6, "gain_carried_x_floor": 0.1}
    assert _not_carried([row]) == []
    left_out = {**row, "significant": False, "ladder_step": None}
    (words,) = _not_carried([left_out])
    assert words.startswith("viscous-friction cut the validation error by 0.60 noise floors")


def test_a_run_the_current_model_diverged_on_is_no_evidence_for_any_candidate():
    # the break-away look-alike with a failed base fit: the base model predicts the 0.5 Hz
    # run at 0.130 and diverges on the 2 Hz run (counted at DIVERGED_NRMSE = 10).  Any
    # candidate that predicts the 2 Hz run at all then "falls" by ~10 there — credited as
    # its own, that claimed inertia.  Judged on the run the base did predict, a 1 % change
    # is no effect.
    base = Scored(effects=(), nrmse=[0.130, 10.0], diverged=["hold-2Hz"],
                  labels=["hold-0.5Hz", "hold-2Hz"])
    mass = Scored(("inertia",), [0.1287, 0.05], labels=["hold-0.5Hz", "hold-2Hz"])
    floors = [0.022, 0.022]
    c = Candidate("inertia", base, mass, floors=floors)
    assert c.evidence == [0] and c.left_out == ["hold-2Hz"]
    assert c.nrmse_before == pytest.approx(0.130) and c.nrmse_after == pytest.approx(0.1287)
    assert c.fall == pytest.approx(0.01, abs=1e-9)
    assert c.gain_x_floor == pytest.approx(0.0013 / 0.022)
    assert not judge([c])[0][0].significant
    assert c.as_json()["left_out"] == ["hold-2Hz"]
    # the same numbers with the base predicting the 2 Hz run (not diverged) are a claim:
    # the rule itself is unchanged
    fine = Scored(effects=(), nrmse=[0.130, 0.10], labels=["hold-0.5Hz", "hold-2Hz"])
    d = Candidate("inertia", fine, mass, floors=floors)
    assert d.evidence == [0, 1] and judge([d])[0][0].significant
    assert "left_out" not in d.as_json()


def test_a_real_fall_on_the_runs_the_base_predicted_is_still_claimed():
    # three held-out runs, the base diverges on one: a candidate that falls well on both
    # others is judged on those two, by the same rule
    base = Scored(effects=(), nrmse=[0.040, 10.0, 0.047], diverged=["b"], labels=["a", "b", "c"])
    good = Scored(("viscous-friction",), [0.020, 0.03, 0.024])
    weak = Scored(("sensor-delay",), [0.021, 0.03, 0.048])  # rises on run c
    floors = [0.0035] * 3
    cands, _ = judge([Candidate(e.effects[0], base, e, floors=floors) for e in (good, weak)])
    assert [c.effect for c in cands] == ["viscous-friction", "sensor-delay"]
    assert cands[0].significant and not cands[1].significant
    assert cands[0].fall == pytest.approx(1 - (0.020 + 0.024) / (0.040 + 0.047))
    # a base that diverged on every held-out run leaves nothing to judge on
    lost = Scored(effects=(), nrmse=[10.0, 10.0, 10.0], diverged=["a", "b", "c"])
    c = Candidate("viscous-friction", lost, good, floors=floors)
    assert c.evidence == [] and c.fall == 0.0 and not judge([c])[0][0].significant


def test_a_base_that_diverged_on_every_held_out_run_writes_null_not_nan(tmp_path):
    # no evidence run is left: a candidate's mean held-out nrmse over them is undefined.
    # diagnosis.json is written with allow_nan=False, so it must be null there (not NaN,
    # which made writing the diagnosis raise), and every reader of the row must take it
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pmalab.identify.diagnosis.diagnose import Diagnosis, _summary, closest_law_phrase
    from pmalab.reports.figures_diagnosis import plot_ranking

    base = Scored(effects=(), nrmse=[10.0, 10.0], diverged=["a", "b"], labels=["a", "b"])
    good = Scored(("viscous-friction",), [0.020, 0.024], labels=["a", "b"])
    c = Candidate("viscous-friction", base, good, floors=[0.0035, 0.0035])
    row = c.as_json()
    json.dumps(row, allow_nan=False)
    assert row["nrmse_before"] is None and row["nrmse_after"] is None
    assert row["left_out"] == ["a", "b"] and not row["significant"]
    law = {"law": "duhem", "status": "ok", "nrmse_before": None, "nrmse_after": None,
           "fall_percent": 0.0, "gain_x_floor": 0.0, "significant": False}
    assert closest_law_phrase("bouc-wen", [law]) == ""
    step = {"step": 0, "effects": [], "added": None, "nrmse": 10.0, "fit_percent": -900.0,
            "per_run": [10.0, 10.0], "diverged": ["a", "b"]}
    text, _ = _summary("bouc-wen", [step], [row], [], 0.0035, None, "", "given", laws=[law])
    assert "no held-out run is left to judge a candidate on" in text
    d = Diagnosis("bouc-wen", [row], [], "", [step], {}, {}, text, laws=[law])
    assert "viscous-friction" in d.ranking_table()
    fig, ax = plt.subplots()
    plot_ranking(ax, [row])
    fig.savefig(tmp_path / "ranking.png")
    d.plot(tmp_path / "plot.png")
    plt.close("all")


def test_a_run_the_base_diverged_on_does_not_decide_between_two_candidates():
    # two significant effects, the winner lower on each of the four runs the base predicted
    # (a sign test: clearly better, not ambiguous).  On the run the base diverged on, the
    # other one happens to predict better: compared there too, the winner would no longer be
    # clearly better and the two would be called ambiguous — on the base's failure
    labels = ["a", "b", "c", "d", "e"]
    base = Scored((), [0.040, 0.047, 0.045, 0.050, 10.0], diverged=["e"], labels=labels)
    x = Scored(("viscous-friction",), [0.020, 0.024, 0.022, 0.025, 0.300], labels=labels)
    y = Scored(("sensor-delay",), [0.022, 0.026, 0.024, 0.027, 0.295], labels=labels)
    floors = [0.0035] * 5
    cands, amb = judge([Candidate(s.effects[0], base, s, floors=floors) for s in (x, y)])
    assert [c.significant for c in cands] == [True, True]
    assert cands[1].fall >= 0.85 * cands[0].fall
    assert amb == []
    # the same numbers with the base predicting run e: compared over all five runs, the
    # winner is not clearly lower there, so the two are ambiguous (the rule is unchanged)
    fine = Scored((), [0.040, 0.047, 0.045, 0.050, 0.6], labels=labels)
    cands, amb = judge([Candidate(s.effects[0], fine, s, floors=floors) for s in (x, y)])
    assert cands[0].effect == "viscous-friction"
    assert amb == ["viscous-friction", "sensor-delay"]


def test_laws_alike_compares_laws_on_the_runs_the_base_predicted():
    # the laws rows carry the base's per-run nrmse: a run it diverged on (10) is no
    # evidence for telling two laws apart either
    from pmalab.identify.diagnosis.diagnose import laws_alike

    before = [0.040, 0.047, 0.045, 0.050, 10.0]

    def row(law: str, after: list[float]) -> dict:
        b = sum(before[:4]) / 4
        return {"law": law, "status": "ok", "significant": True, "per_run_before": before,
                "per_run_after": after, "fall_percent": 100 * (1 - sum(after[:4]) / 4 / b)}

    best = row("maxwell-slip", [0.020, 0.024, 0.022, 0.025, 0.300])
    other = row("prandtl-ishlinskii", [0.022, 0.026, 0.024, 0.027, 0.295])
    assert laws_alike([best, other]) == []
    # with the base predicting run e the five runs cannot tell them apart
    seen = [{**r, "per_run_before": [*before[:4], 0.6]} for r in (best, other)]
    assert laws_alike(seen) == ["maxwell-slip", "prandtl-ishlinskii"]


def test_why_a_law_is_not_claimed_counts_the_runs_the_base_predicted():
    # a law row that rises on one of the four runs the base predicted: the summary says
    # "3 of 4"; the run the base diverged on (its fall of ~10 is no evidence) is not counted
    from pmalab.identify.diagnosis.diagnose import closest_law_phrase

    law = {"law": "maxwell-slip", "status": "ok", "significant": False, "gain_x_floor": 1.2,
           "nrmse_before": 0.0455, "nrmse_after": 0.02875, "fall_percent": 36.8,
           "per_run_before": [0.040, 0.047, 0.045, 0.050, 10.0],
           "per_run_after": [0.020, 0.024, 0.046, 0.025, 0.3], "runs_at_floor": 0}
    text = closest_law_phrase("bouc-wen", [law])
    assert "it lowers the error on only 3 of 4 held-out runs" in text
