"""The ladder's bookkeeping (no fitting: identifications replaced by a table of held-out
errors): every model is identified once, the base with the first round, and no round is
scored once the model is within the significance rule's reach of the noise floor."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from pmalab.identify.campaign import ModelSpec
from pmalab.identify.diagnosis import ladder
from pmalab.identify.diagnosis.ranking import Scored

FLOOR = 0.004


def _fake(table: dict[tuple[str, tuple[str, ...]], list[float]], calls: list):
    """A stand-in for ``score_all``: each spec's held-out nrmse per run from ``table``
    (default: a little worse than the base); records the batches it was asked for."""

    def score_all(train, held, specs, jobs=1, progress=False, desc="", scheduler=None, pool=None,
                  base_fits=None):
        calls.append(list(specs))
        base = table[("bouc-wen", ())]
        return [
            Scored(s.effects, list(table.get((s.law, s.effects), [b * 1.01 for b in base])))
            for s in specs
        ]

    return score_all


@pytest.fixture
def climb(monkeypatch):
    def run(table, **kw):
        calls: list = []
        monkeypatch.setattr(ladder, "score_all", _fake(table, calls))
        monkeypatch.setattr(ladder, "heldout_floor", lambda r: FLOOR)
        out = ladder.run_ladder(
            [SimpleNamespace(frequency=0.25)],  # pyright: ignore[reportArgumentType]
            ["held-a", "held-b"],  # pyright: ignore[reportArgumentType]  (never read)
            "bouc-wen",
            ["viscous-friction", "sensor-drift"],
            laws=["duhem", "maxwell-slip"],
            **kw,
        )
        return out, calls

    return run


def test_each_model_is_identified_once_and_the_base_with_round_one(climb):
    # step 1 switches the law: the next round's other laws (with the same, empty, effects)
    # are the first round's models again and are not identified twice
    table = {
        ("bouc-wen", ()): [0.040, 0.047],
        ("maxwell-slip", ()): [0.020, 0.024],
        ("duhem", ()): [0.041, 0.046],
    }
    out, calls = climb(table)
    assert [s.switched for s in out.steps] == [None, "maxwell-slip"]
    assert out.stop == "nothing significant"
    # round 1 holds the base, handed out first (its base-law fits serve the candidates
    # after it); then the dearest (a law with pressure structures)
    assert calls[0][:2] == [ModelSpec("bouc-wen"), ModelSpec("maxwell-slip")]
    assert ModelSpec("duhem") not in calls[1]  # scored in round 1, same model
    made = [s for batch in calls for s in batch]
    assert len(made) == len(set(made)) == out.identifications
    # the round after the switch still lists duhem, with round 1's numbers
    r2 = {c.effect: c for c in out.rounds[1].laws}
    assert r2["duhem"].after.nrmse == table[("duhem", ())]


def test_no_round_is_scored_at_the_noise_floor(climb):
    # viscous friction takes the model to 1.2x the floor: no candidate could cut another
    # 0.25 floors without predicting below the noise, so the ladder stops unscored
    table = {
        ("bouc-wen", ()): [0.040, 0.047],
        ("bouc-wen", ("viscous-friction",)): [1.2 * FLOOR, 1.2 * FLOOR],
    }
    out, calls = climb(table)
    assert [s.added for s in out.steps] == [None, "viscous-friction"]
    assert out.stop == "at the noise floor" and len(calls) == len(out.rounds) == 1
    # just above 1.25x the floor the next round is scored
    table[("bouc-wen", ("viscous-friction",))] = [1.3 * FLOOR, 1.3 * FLOOR]
    out, calls = climb(table)
    assert len(out.rounds) == 2 and out.stop == "nothing significant"


def test_max_steps_zero_identifies_the_base_only(climb):
    out, calls = climb({("bouc-wen", ()): [0.040, 0.047]}, max_steps=0)
    assert calls == [[ModelSpec("bouc-wen")]]
    assert len(out.steps) == 1 and out.rounds == []


def test_a_row_added_at_a_later_step_is_all_from_that_round(monkeypatch):
    # sensor-drift fails alone (round 1: the error rises 130 %) but, once viscous friction
    # is in, cuts the error by 2.75 floors (round 2) and is added: its ranking row must not
    # say "failed" (round 1) beside round 2's fall, nor round 1's floors beside round 2's
    from pmalab.identify.diagnosis.diagnose import _ranking_json

    nrmse = {
        (): [0.040, 0.047],
        ("viscous-friction",): [0.020, 0.024],
        ("sensor-drift",): [0.090, 0.110],
        ("viscous-friction", "sensor-drift"): [0.010, 0.012],
    }
    without = {("viscous-friction", "sensor-drift"): [0.015, 0.020]}

    def score_all(train, held, specs, jobs=1, progress=False, desc="", scheduler=None, pool=None,
                  base_fits=None):
        return [Scored(s.effects, nrmse[s.effects], without_last=without.get(s.effects))
                for s in specs]

    monkeypatch.setattr(ladder, "score_all", score_all)
    monkeypatch.setattr(ladder, "heldout_floor", lambda r: FLOOR)
    climbed = ladder.run_ladder(
        [SimpleNamespace(frequency=None)],  # pyright: ignore[reportArgumentType]
        ["held-a", "held-b"],  # pyright: ignore[reportArgumentType]  (never read)
        "bouc-wen",
        ["viscous-friction", "sensor-drift"],
    )
    steps, rounds = climbed.steps, climbed.rounds
    assert [s.added for s in steps] == [None, "viscous-friction", "sensor-drift"]
    rows = {r["effect"]: r for r in _ranking_json(rounds, steps, [])}
    drift = rows["sensor-drift"]
    at = next(c for c in rounds[1].candidates if c.effect == "sensor-drift").as_json()
    # (the old row: status "failed" from round 1 beside round 2's fall)
    assert drift["status"] == "ok" and "reason" not in drift
    assert drift["round"] == 2 and drift["ladder_step"] == 2 and drift["significant"]
    assert drift["scored_against"] == "viscous-friction"
    assert not drift["significant_alone"]  # round 1's verdict, named as such
    for key in ("nrmse_before", "nrmse_after", "fall_percent", "gain_x_floor",
                "gain_carried_x_floor", "per_run_without_effect", "block_t", "runs_at_floor"):
        assert drift[key] == at[key], key
    assert drift["gain_x_floor"] == pytest.approx(2.75)
    assert drift["gain_carried_x_floor"] == pytest.approx((0.005 + 0.008) / 2 / FLOOR)
    first = rows["viscous-friction"]
    assert first["round"] == 1 and first["scored_against"] == "base"


def test_the_ladders_runs_have_their_signals_kept_while_it_climbs(monkeypatch):
    """Identifications made in the ladder's own process (one job) filter each run once: the
    ladder's runs are kept (pmalab.identify.signals.keep_run_signals) while it climbs and
    forgotten when it returns, also when a round raises."""
    from pmalab.identify import signals

    train = [SimpleNamespace(frequency=0.25)]
    held = ["held-a", "held-b"]
    seen: list = []
    table = {("bouc-wen", ()): [0.040, 0.047]}
    fake = _fake(table, [])

    def recording(*a, **k):
        kept = {id(r) for r in signals._KEPT_RUNS.values()}
        seen.append(kept == {id(r) for r in [*train, *held]})
        return fake(*a, **k)

    monkeypatch.setattr(ladder, "score_all", recording)
    monkeypatch.setattr(ladder, "heldout_floor", lambda r: FLOOR)
    ladder.run_ladder(train, held, "bouc-wen", ["viscous-friction"])  # pyright: ignore[reportArgumentType]
    assert seen and all(seen)
    assert not signals._KEPT_RUNS and not signals._RUN_SIGNALS

    def raising(*a, **k):
        raise RuntimeError("a round failed")

    monkeypatch.setattr(ladder, "score_all", raising)
    with pytest.raises(RuntimeError):
        ladder.run_ladder(train, held, "bouc-wen", ["viscous-friction"])  # pyright: ignore[reportArgumentType]
    assert not signals._KEPT_RUNS


def test_a_base_that_diverged_on_a_run_claims_nothing_there_and_says_so(monkeypatch):
    # the base identification fails on the 2 Hz held-out run (its prediction diverges,
    # counted at 10); inertia and the duhem law predict it and change the other run by
    # 1-2 %: neither is claimed, the ladder's base step and the summary name the run
    from pmalab.identify.diagnosis.diagnose import _summary

    labels = ["hold-0.5Hz", "hold-2Hz"]
    nrmse = {
        ("bouc-wen", ()): ([0.130, 10.0], ["hold-2Hz"]),
        ("bouc-wen", ("inertia",)): ([0.128, 0.05], []),
        ("duhem", ()): ([0.129, 0.04], []),
    }

    def score_all(train, held, specs, jobs=1, progress=False, desc="", scheduler=None, pool=None,
                  base_fits=None):
        return [Scored(s.effects, nrmse[(s.law, s.effects)][0],
                       diverged=nrmse[(s.law, s.effects)][1], labels=labels) for s in specs]

    monkeypatch.setattr(ladder, "score_all", score_all)
    monkeypatch.setattr(ladder, "heldout_floor", lambda r: 0.022)
    climbed = ladder.run_ladder(
        [SimpleNamespace(frequency=None)],  # pyright: ignore[reportArgumentType]
        labels,  # pyright: ignore[reportArgumentType]  (never read)
        "bouc-wen",
        ["inertia"],
        laws=["duhem"],
    )
    assert climbed.stop == "nothing significant" and len(climbed.steps) == 1
    (r,) = climbed.rounds
    assert not r.candidates[0].significant and not r.laws[0].significant
    assert r.candidates[0].as_json()["left_out"] == ["hold-2Hz"]
    base = climbed.steps[0].as_json()
    assert base["diverged"] == ["hold-2Hz"]
    text, verdict = _summary("bouc-wen", [base], [r.candidates[0].as_json()], [], 0.022, None,
                             "", "given", [0.022, 0.022])
    assert "diverged or ran off on hold-2Hz" in text and "no evidence for any candidate" in text
    assert verdict == "unexplained"


def test_a_run_the_base_ran_off_on_with_a_finite_prediction_is_named():
    # a finite held-out prediction at nrmse >= DIVERGED_NRMSE (12.5, counted at 10) is left
    # out of every candidate's evidence like a diverged one; the ladder step names it too
    labels = ["hold-0.5Hz", "hold-2Hz"]
    scored = Scored((), [0.130, 10.0], labels=labels)  # 10.0: capped, not diverged
    assert scored.diverged == [] and scored.unjudged == ["hold-2Hz"]
    step = ladder.LadderStep(0, [], None, scored, law="bouc-wen").as_json()
    assert step["diverged"] == ["hold-2Hz"]
    fine = ladder.LadderStep(0, [], None, Scored((), [0.130, 9.9], labels=labels)).as_json()
    assert "diverged" not in fine


def test_the_summary_says_a_candidate_diverging_where_the_base_did_is_a_failed_fit():
    # the left-out run is no evidence, but a candidate whose own prediction diverges there
    # as well is listed as a failed fit (not judged on the other runs): the summary says so
    from pmalab.identify.diagnosis.diagnose import _summary
    from pmalab.identify.diagnosis.ranking import Candidate

    labels = ["hold-0.5Hz", "hold-2Hz"]
    base = Scored((), [0.130, 10.0], diverged=["hold-2Hz"], labels=labels)
    mass = Scored(("inertia",), [0.100, 10.0], diverged=["hold-2Hz"], labels=labels)
    c = Candidate("inertia", base, mass, floors=[0.022, 0.022])
    assert c.failed and c.left_out == ["hold-2Hz"]
    step = {"nrmse": 5.065, "per_run": [0.130, 10.0], "diverged": ["hold-2Hz"]}
    text, _ = _summary("bouc-wen", [step], [c.as_json()], [], 0.022, None, "", "given")
    assert "Fit failed (not ranked): inertia: the held-out prediction diverged on hold-2Hz" in text
    assert "one whose own prediction diverges there too is a failed fit" in text


def _climb(monkeypatch, nrmse, effects, laws, labels):
    def score_all(train, held, specs, jobs=1, progress=False, desc="", scheduler=None, pool=None,
                  base_fits=None):
        return [Scored(s.effects, nrmse[(s.law, s.effects)], labels=labels) for s in specs]

    monkeypatch.setattr(ladder, "score_all", score_all)
    monkeypatch.setattr(ladder, "heldout_floor", lambda r: 0.02)
    return ladder.run_ladder(
        [SimpleNamespace(frequency=None)],  # pyright: ignore[reportArgumentType]
        labels,  # pyright: ignore[reportArgumentType]  (never read)
        "bouc-wen",
        effects,
        laws=laws,
    )


def test_a_law_significant_only_against_the_base_model_is_not_claimed(monkeypatch):
    # a true sensor drift on the held-out records: against the base model alone any law's
    # refit lowers the error (the drift-linear look-alike: Maxwell-slip -37 %), but the drift
    # explains that fall; once the ladder has added it the law gains nothing.  Judged as the
    # effects are, the law is not claimed, and the summary says why
    from pmalab.identify.diagnosis.diagnose import _laws_json, _summary

    labels = ["a", "b", "c", "d"]
    nrmse = {
        ("bouc-wen", ()): [0.090, 0.100, 0.095, 0.092],
        ("bouc-wen", ("sensor-drift",)): [0.040, 0.042, 0.041, 0.040],
        ("maxwell-slip", ()): [0.060, 0.065, 0.062, 0.060],
        ("maxwell-slip", ("sensor-drift",)): [0.039, 0.043, 0.040, 0.040],
    }
    climbed = _climb(monkeypatch, nrmse, ["sensor-drift"], ["maxwell-slip"], labels)
    assert [s.added for s in climbed.steps] == [None, "sensor-drift"]
    assert climbed.stop == "nothing significant"
    assert climbed.rounds[0].laws[0].significant  # alone, against the base model
    assert not climbed.rounds[1].laws[0].significant  # against base + drift
    (row,) = _laws_json(climbed.rounds, climbed.steps)
    assert not row["significant"] and row["significant_alone"]
    assert row["significant_last"] is False and row["round"] == 1
    ladder_json = [s.as_json() for s in climbed.steps]
    text, _ = _summary("bouc-wen", ladder_json, [], [], 0.02, None, "", "given", laws=[row],
                       stop=climbed.stop)
    assert "Also significant" not in text
    assert "but not against the model with sensor-drift" in text and "not claimed" in text


def test_a_law_the_ladder_switched_to_is_claimed_from_the_round_it_won(monkeypatch):
    # the law wins round 2 (against base + viscous friction): its row is that round's, as an
    # effect's row is the round that added it; round 1's verdict stays as significant_alone
    from pmalab.identify.diagnosis.diagnose import _laws_json

    labels = ["a", "b", "c", "d"]
    nrmse = {
        ("bouc-wen", ()): [0.090, 0.100, 0.095, 0.092],
        ("bouc-wen", ("viscous-friction",)): [0.060, 0.062, 0.061, 0.060],
        ("maxwell-slip", ()): [0.085, 0.099, 0.094, 0.091],
        ("maxwell-slip", ("viscous-friction",)): [0.030, 0.031, 0.030, 0.032],
    }
    climbed = _climb(monkeypatch, nrmse, ["viscous-friction"], ["maxwell-slip"], labels)
    assert [s.switched for s in climbed.steps] == [None, None, "maxwell-slip"]
    (row,) = _laws_json(climbed.rounds, climbed.steps)
    assert row["significant"] and not row["significant_alone"]
    assert row["ladder_step"] == 2 and row["round"] == 2
    assert row["scored_against"] == "viscous-friction"
    assert row["nrmse_before"] == pytest.approx(0.06075)


def test_a_law_the_ladder_switched_away_from_is_not_the_one_the_summary_recommends(monkeypatch):
    # step 1 switches to Maxwell-slip, step 2 adds viscous friction, step 3 switches again,
    # to Prandtl-Ishlinskii (it beats maxwell-slip+viscous-friction on every run): the final
    # model's law is prandtl-ishlinskii, and that is the law the summary recommends; the
    # laws the runs cannot tell apart are those of the round it won (duhem there)
    from pmalab.identify.diagnosis.diagnose import _alike_rows, _laws_json, _summary, laws_alike

    labels = ["a", "b", "c", "d"]
    nrmse = {
        ("bouc-wen", ()): [0.200, 0.210, 0.205, 0.202],
        ("bouc-wen", ("viscous-friction",)): [0.150, 0.155, 0.152, 0.151],
        ("maxwell-slip", ()): [0.120, 0.125, 0.122, 0.121],
        ("maxwell-slip", ("viscous-friction",)): [0.060, 0.062, 0.061, 0.060],
        ("prandtl-ishlinskii", ()): [0.130, 0.135, 0.132, 0.131],
        ("prandtl-ishlinskii", ("viscous-friction",)): [0.040, 0.041, 0.040, 0.041],
        ("duhem", ()): [0.190, 0.200, 0.195, 0.192],
        ("duhem", ("viscous-friction",)): [0.041, 0.040, 0.041, 0.040],
    }
    climbed = _climb(monkeypatch, nrmse, ["viscous-friction"],
                     ["maxwell-slip", "prandtl-ishlinskii", "duhem"], labels)
    assert [s.switched for s in climbed.steps] == [None, "maxwell-slip", None,
                                                   "prandtl-ishlinskii"]
    assert climbed.steps[-1].law == "prandtl-ishlinskii"
    rows = _laws_json(climbed.rounds, climbed.steps)
    ladder_json = [s.as_json() for s in climbed.steps]
    text, _ = _summary("bouc-wen", ladder_json, [], [], 0.02, None, "", "given", laws=rows,
                       stop=climbed.stop)
    assert "try `--model prandtl-ishlinskii`" in text, text
    assert "try `--model maxwell-slip`" not in text, text
    # the law the ladder took and then replaced is not claimed (the final model's law is)
    claimed = {r["law"]: (r["significant"], r["ladder_step"]) for r in rows}
    assert claimed == {"maxwell-slip": (False, 1), "prandtl-ishlinskii": (True, 3),
                       "duhem": (False, None)}
    assert laws_alike(_alike_rows(climbed.rounds, climbed.steps)) == ["prandtl-ishlinskii",
                                                                      "duhem"]


def test_laws_alike_is_judged_against_the_final_model_not_one_the_ladder_moved_past(monkeypatch):
    # two laws about equally good against the base model alone; the ladder adds a drift and
    # stops at the noise floor without scoring the laws again: "these runs cannot tell them
    # apart" would be a statement about a model the diagnosis no longer recommends
    from pmalab.identify.diagnosis.diagnose import _alike_rows, laws_alike

    labels = ["a", "b", "c", "d"]
    nrmse = {
        ("bouc-wen", ()): [0.090, 0.100, 0.095, 0.092],
        ("bouc-wen", ("sensor-drift",)): [0.024, 0.024, 0.024, 0.024],
        ("maxwell-slip", ()): [0.060, 0.065, 0.062, 0.060],
        ("prandtl-ishlinskii", ()): [0.061, 0.064, 0.063, 0.060],
    }
    climbed = _climb(monkeypatch, nrmse, ["sensor-drift"], ["maxwell-slip", "prandtl-ishlinskii"],
                     labels)
    assert climbed.stop == "at the noise floor" and len(climbed.rounds) == 1
    from pmalab.identify.diagnosis.diagnose import _law_row

    round1 = [_law_row(c) for c in climbed.rounds[0].laws]
    assert laws_alike(round1) == ["maxwell-slip", "prandtl-ishlinskii"]  # round 1 alone
    assert _alike_rows(climbed.rounds, climbed.steps) == []
    assert laws_alike(_alike_rows(climbed.rounds, climbed.steps)) == []


def test_the_tables_say_what_each_row_was_scored_against():
    # the CLI's ranking and laws tables mix rows from different rounds (an effect or law
    # the ladder took is shown from the round it won): the "against" column names the model
    from pmalab.identify.diagnosis.diagnose import against_words

    assert against_words("base") == "base" and against_words(None) == "base"
    assert against_words("viscous-friction") == "base+viscous-friction"
    assert against_words("viscous-friction+sensor-drift") == "base+viscous-friction+sensor-drift"
    assert against_words("maxwell-slip+viscous-friction") == "maxwell-slip+viscous-friction"
    from pmalab.identify.diagnosis.diagnose import Diagnosis

    rows = [{"effect": "viscous-friction", "scored_against": "base", "status": "ok",
             "nrmse_before": 0.2, "nrmse_after": 0.02, "fall_percent": 90.0,
             "fall_se_percent": 1.0, "n_params": 1, "significant": True},
            {"effect": "sensor-drift", "scored_against": "viscous-friction", "status": "ok",
             "nrmse_before": 0.02, "nrmse_after": 0.015, "fall_percent": 25.0,
             "fall_se_percent": 1.0, "n_params": 1, "significant": True}]
    table = Diagnosis("bouc-wen", rows, [], "", [], {}, {}, "").ranking_table().splitlines()
    assert table[0].split()[:2] == ["effect", "against"]
    assert table[2].split()[:2] == ["viscous-friction", "base"]
    assert table[3].split()[:2] == ["sensor-drift", "base+viscous-friction"]
