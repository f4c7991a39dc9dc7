"""The diagnosis summary on the laws when none is significant: the best one is named with its
gain against the rule's threshold, never claimed; nothing is said when no law beats the base."""

from __future__ import annotations

from pmalab.identify.diagnosis.diagnose import closest_law_phrase
from pmalab.identify.diagnosis.ranking import MIN_GAIN_X_FLOOR


def _row(law: str, after: float, gain: float, **kw) -> dict:
    return {
        "law": law,
        "nrmse_before": 0.0230,
        "nrmse_after": after,
        "gain_x_floor": gain,
        "significant": False,
        **kw,
    }


def test_best_law_below_the_threshold_is_named_not_claimed():
    laws = [
        _row("maxwell-slip", 0.0226, 0.08),
        _row("prandtl-ishlinskii", 0.0222, 0.16, structure="scaled"),
        _row("duhem", 0.0240, -0.5),
    ]
    text = closest_law_phrase("bouc-wen", laws)
    assert "prandtl-ishlinskii" in text and "maxwell-slip" not in text
    assert "0.0230 → 0.0222" in text and "0.16 noise floors" in text
    assert f"≥ {MIN_GAIN_X_FLOOR:g}" in text and "not claimed" in text
    assert "(−3 %," in text  # 1 − 0.0222 / 0.0230 = 3.5 %


def test_a_large_gain_not_claimed_says_which_part_of_the_rule_it_fails():
    # a real O-ring campaign: 3.85 floors gained, but one of the four held-out runs got worse
    runs = {"per_run_before": [0.12, 0.13, 0.14, 0.12], "runs_at_floor": 0}
    worse = _row("maxwell-slip", 0.0150, 3.85, per_run_after=[0.10, 0.11, 0.12, 0.13],
                 block_t=35.6, **runs)
    text = closest_law_phrase("bouc-wen", [worse])
    assert "only 3 of 4 held-out runs" in text and "within what noise gives" not in text
    # the same run at its noise floor both times is no evidence either way
    floor = {**worse, "runs_at_floor": 1}
    assert "of 4 held-out runs" not in closest_law_phrase("bouc-wen", [floor])
    # every run lower, but the cycles disagree
    cycles = _row("maxwell-slip", 0.0150, 0.9, per_run_after=[0.10, 0.11, 0.12, 0.11],
                  block_t=0.8, **runs)
    text = closest_law_phrase("bouc-wen", [cycles])
    assert "cycle by cycle (block t 0.8 < 1.5)" in text and "noise gives" not in text
    # below the threshold: the gain is what the sentence names, whatever else fails
    small = {**worse, "gain_x_floor": 0.2}
    assert "within what noise gives" in closest_law_phrase("bouc-wen", [small])


def test_no_law_better_than_the_base_says_nothing():
    laws = [
        _row("duhem", 0.0240, -0.5),
        _row("maxwell-slip", 0.0231, -0.05),
        {
            "law": "prandtl-ishlinskii",
            "status": "failed",
            "reason": "x",
            "nrmse_before": 0.023,
            "nrmse_after": 0.01,
            "gain_x_floor": None,
        },
    ]
    assert closest_law_phrase("bouc-wen", laws) == ""


def test_structure_margin_in_words_says_behind_when_the_simpler_was_kept():
    """A structure kept as the simpler one within 1 % of a better-scoring candidate has a
    negative margin: the summary says it is behind (it used to print "-0 % ahead")."""
    from pmalab.identify.campaign.structure import SIMPLER_WITHIN, margin_words
    from pmalab.identify.diagnosis.diagnose import structure_phrase

    behind = structure_phrase(
        {"structure": "scaled-thresholds", "structure_margin_percent": -0.026}
    )
    assert "ahead" not in behind and "-0" not in behind
    assert "kept as the simpler, 0.026 % behind the best" in behind
    assert f"{100 * SIMPLER_WITHIN:g} % allowed" in behind
    ahead = structure_phrase({"structure": "scaled", "structure_margin_percent": 2.6055})
    assert "2.6 % ahead" in ahead and "behind" not in ahead
    assert margin_words(12.3) == "12 % ahead" and margin_words(0.4) == "0.4 % ahead"
    assert margin_words(float("nan")) == "" and margin_words(None) == ""
    assert "held-out error)" in structure_phrase(
        {"structure": "scaled", "structure_margin_percent": None}
    )


def _law(law: str, fall: float, runs: list[float]) -> dict:
    return {
        "law": law,
        "status": "ok",
        "nrmse_before": 0.0300,
        "nrmse_after": 0.0300 * (1.0 - fall / 100.0),
        "fall_percent": fall,
        "gain_x_floor": 0.2,
        "significant": False,
        "per_run_after": runs,
    }


def test_two_element_laws_no_run_tells_apart_are_said_alike():
    """Maxwell-slip cuts the base model's error by 15 %, Prandtl-Ishlinskii by 14 % (≥ 85 %
    of it) and is lower on one of the four held-out runs: the runs cannot tell them apart,
    and the summary says so; Duhem (5 %) is not alike."""
    from pmalab.identify.diagnosis.diagnose import alike_phrase, laws_alike
    from pmalab.identify.diagnosis.ranking import AMBIGUITY_RATIO

    ms = _law("maxwell-slip", 15.0, [0.024, 0.025, 0.027, 0.026])
    pi = _law("prandtl-ishlinskii", 14.0, [0.0225, 0.026, 0.028, 0.027])
    du = _law("duhem", 5.0, [0.028, 0.028, 0.029, 0.029])
    assert 14.0 >= AMBIGUITY_RATIO * 15.0 and 5.0 < AMBIGUITY_RATIO * 15.0
    got = laws_alike([du, pi, ms])
    assert got == ["maxwell-slip", "prandtl-ishlinskii"]
    text = alike_phrase(got)
    assert text.startswith("The prandtl-ishlinskii law predicts the held-out runs about as well")
    assert "maxwell-slip" in text and "cannot tell them apart" in text
    assert "elasto-slide" in text and "duhem" not in text


def test_a_law_the_best_beats_on_every_run_or_by_far_is_not_alike():
    from pmalab.identify.diagnosis.diagnose import alike_phrase, laws_alike

    ms = _law("maxwell-slip", 15.0, [0.024, 0.025, 0.027, 0.026])
    # ≥ 85 % of the fall, but higher on every one of four runs: a sign test, p = 1/16
    pi = _law("prandtl-ishlinskii", 14.0, [0.0241, 0.0255, 0.0272, 0.0262])
    assert laws_alike([ms, pi]) == [] and alike_phrase([]) == ""
    # lower on one run, but 70 % of the fall
    pi_far = _law("prandtl-ishlinskii", 10.5, [0.0238, 0.027, 0.029, 0.028])
    assert laws_alike([ms, pi_far]) == []
    # no law cut the base model's error: nothing to share
    assert laws_alike([_law("maxwell-slip", -2.0, [0.03] * 4), _law("duhem", -3.0, [0.03] * 4)]) == []
    # a failed law is never alike
    failed = {**pi, "status": "failed", "fall_percent": None}
    assert laws_alike([ms, failed]) == []
