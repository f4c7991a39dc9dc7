"""Sorting identification messages into `note:` and `warning:` lines, and the headline
figures (error fall, worst runs) shared by the CLI, the demo and the report."""

from __future__ import annotations

import math

import pytest

from pmalab.identify.headline import error_fall, worst_runs
from pmalab.identify.messages import (
    Message,
    as_message,
    detail,
    is_note,
    note,
    read_messages,
    sort_messages,
    warn,
)

CAMPAIGN: list[str] = [
    note("default-fix", "n fixed at 1 (default): n trades off against beta/gamma; free it "
         "with --free n", name="n", value=1.0),
    note("joint-refined", "pressure laws refined jointly on all 7 runs (free-run error, "
         "per-run h0): mean nrmse 0.0357 with the per-run quadratics -> 0.0303; orders in p: k 2"),
    detail("joint-order", "joint fit: pressure order lowered where the joint data do not "
           "support it (Wald/BIC): A 2->1"),
    detail("pressure-order", "beta: pressure order 1 (BIC over its per-run values; order 2 "
           "not supported)", name="beta", order=1),
    warn("optimizer", "joint refinement stopped early: The maximum number of function "
         "evaluations is exceeded."),
    "only 2 pressure level(s) (0.3, 0.4 MPa): quadratics reduced to degree 1",
    "an unknown new message nobody classified",
]


def _coll(a: str, b: str, rho: float) -> Message:
    return warn("collinear", f"rho({a},{b})={rho:+.3f}: |rho| > 0.95; these parameters "
                "trade off", a=a, b=b, rho=rho, limit=0.95)


def test_information_is_a_note_and_problems_are_warnings_in_full():
    m = sort_messages(CAMPAIGN, [
        ("f.h5:r1", ["beta = 0.5 is at its bound [0, 0.5]",
                     "measured loop runs anti-physically (tension 3 N lower while stretching): "
                     "check the position sign / channel mapping",
                     _coll("A", "h0", 0.988), _coll("beta", "gamma", -0.976)],
         [detail("c0-extrapolated", "rho(k,c0)=-0.989 only because c0 is extrapolated to x = 0")]),
        ("f.h5:r2", [_coll("A", "h0", 0.994)], []),
        ("f.h5:r3", [], []),
    ])
    assert all(is_note(n) for n in CAMPAIGN[:4])
    assert m.notes == [CAMPAIGN[0], CAMPAIGN[1]]
    assert CAMPAIGN[2] in m.details and CAMPAIGN[3] in m.details  # the method's details: -v
    assert "f.h5:r1: beta = 0.5 is at its bound [0, 0.5]" in m.warnings
    assert any(w.startswith("f.h5:r1: measured loop runs anti-physically") and
               w.endswith("check the position sign / channel mapping") for w in m.warnings)
    assert CAMPAIGN[4] in m.warnings and CAMPAIGN[5] in m.warnings
    assert CAMPAIGN[6] in m.warnings  # unknown messages are shown, never hidden
    # collinearity: one campaign line naming the pairs and their run counts, from the data
    coll = [w for w in m.warnings if w.startswith("parameters trade off")]
    assert len(coll) == 1
    assert "on 2 of 3 runs" in coll[0] and "A/h0 (2 runs)" in coll[0]
    assert "beta/gamma (1 run)" in coll[0]
    assert "f.h5:r1: |rho| > 0.95: A/h0 +0.988, beta/gamma -0.976" in m.details
    assert any("only because c0 is extrapolated" in d for d in m.details)


def test_a_sentence_decides_nothing_the_type_does():
    # the same words as a note, but untyped: a warning (no regex reads sentences)
    assert not is_note("n fixed at 1 (default): n trades off against beta/gamma")
    assert is_note(note("x", "anything at all"))
    assert not is_note(warn("x", "pressure laws refined jointly"))


def test_held_out_runs_are_one_note():
    m = sort_messages([note("held-out", "f.h5:v1: role 'validation' in the run file, held out "
                            "for validation", run="f.h5:v1"),
                       note("held-out", "whatever the wording", run="f.h5:v2")], [])
    assert m.notes == ["2 run(s) with role 'validation' in the run file held out for "
                       "validation: f.h5:v1, f.h5:v2"]
    assert not m.warnings


def test_messages_round_trip_through_json_and_pickle():
    import json
    import pickle

    ms = [as_message(m) for m in CAMPAIGN] + [_coll("A", "h0", 0.988)]
    back = read_messages(json.loads(json.dumps([m.to_dict() for m in ms])))
    assert all(a.same(b) for a, b in zip(ms, back, strict=True))
    assert all(a.same(b) for a, b in zip(ms, pickle.loads(pickle.dumps(ms)), strict=True))
    assert json.dumps(ms[0]) == json.dumps(ms[0].text)  # still reads as its sentence


def test_identification_json_carries_the_typed_messages(tmp_path):
    import json

    from identify_synth import make_run

    from pmalab.identify.api import identify

    runs = [make_run("bouc-wen", p, n=3000, f=0.5, seed=i, name=f"r{i}")[0]
            for i, p in enumerate((0.2, 0.4, 0.6))]
    res = identify(runs, "bouc-wen")
    res.save(tmp_path / "o")
    doc = json.loads((tmp_path / "o" / "identification.json").read_text())
    msgs = read_messages(doc["messages"])
    codes = {m.code: m for m in msgs}
    assert codes["default-fix"].kind == "note" and codes["default-fix"].data["name"] == "n"
    assert "joint-refined" in codes


def _doc(model, effects, nrmse):
    return {"model": model, "effects": effects,
            "validation": [{"file": f"/x/{i}/c.h5", "run": r, "muscle_pressure_MPa": p,
                            "nrmse": v} for i, (r, p, v) in enumerate(nrmse)]}


def test_error_fall_is_the_mean_validation_nrmse_before_and_after():
    base = _doc("bouc-wen", [], [("a", 0.5, 0.04), ("b", 0.3, 0.02), ("c", 0.4, 0.03)])
    imp = _doc("bouc-wen", ["asymmetric-hysteresis"],
               [("a", 0.5, 0.01), ("b", 0.3, 0.01), ("c", 0.4, None)])
    f = error_fall(base, imp)
    assert [r.run for r in f.compared] == ["a", "b"]  # c diverged under the improved model
    assert f.before == pytest.approx(0.03) and f.after == pytest.approx(0.01)
    assert f.fall_percent == pytest.approx(100 * (1 - 0.01 / 0.03))
    s = f.sentence()
    assert s.startswith("validation error falls 66.7 % (mean nrmse 0.0300 → 0.0100")
    assert "on 2 validation runs, predicted through the pressure laws" in s
    assert "1 run(s) left out" in s
    assert f.improved_model == "bouc-wen + asymmetric-hysteresis"
    # a rise is called a rise
    worse = error_fall(imp, base)
    assert worse.fall_percent < 0 and "RISES" in worse.sentence()
    assert error_fall(base, _doc("bouc-wen", [], [("z", 0.1, 0.1)])) is None
    assert math.isnan(error_fall(base, _doc("m", [], [("a", 0.5, None)])).before)


def test_worst_runs_by_base_rmse_missing_last():
    diags = {"a": {"rmse": 3.0, "nrmse": 0.09}, "b": {"rmse": 7.5, "nrmse": 0.03},
             "c": {"nrmse": 0.5}, "d": {"rmse": 5.0}}
    assert worst_runs(diags) == ["b", "d", "a", "c"]
    assert worst_runs(diags, 2) == ["b", "d"]


def test_a_prefix_keeps_the_type_of_a_message():
    from pmalab.identify.messages import prefixed

    m = prefixed("run 1: ", detail("auto-fix", "fixed gamma = 0", name="gamma"))
    assert isinstance(m, Message) and m.kind == "detail" and m.data == {"name": "gamma"}
    assert m == "run 1: fixed gamma = 0"
    assert prefixed("run 1: ", "plain") == "run 1: plain" and not is_note(prefixed("a", "b"))
