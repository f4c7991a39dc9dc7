"""The notebook views: diagnosis ranking and ladder as DataFrames (JSON unchanged), and
plot_loops drawing the measurement visible under a thinner model line."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import reports_fixtures as rf
from identify_synth import make_run

from pmalab.identify import DiagnosisResult, identify
from pmalab.identify.diagnosis import Diagnosis


def _diagnosis() -> Diagnosis:
    doc = rf.diagnosis_doc()
    ranking = [{**r, "fall_percent": 100 * (1 - r["nrmse_after"] / r["nrmse_before"]),
                "fall_se_percent": 2.0} for r in doc["ranking"]]
    return Diagnosis(model="bouc-wen", ranking=ranking, ambiguous=["sensor-delay"],
                     suggested_experiment="two frequencies", ladder=doc["ladder"],
                     diagnostics=doc["diagnostics"], campaign=doc["campaign_diagnostics"],
                     summary=doc["summary"])


def test_ranking_and_ladder_are_dataframes_and_the_json_is_unchanged(tmp_path):
    raw = _diagnosis()
    before = json.dumps(raw.to_json(), sort_keys=True)
    d = DiagnosisResult(raw)
    assert isinstance(d.ranking, pd.DataFrame) and isinstance(d.ladder, pd.DataFrame)
    assert list(d.ranking.index) == ["viscous-friction", "asymmetric-hysteresis", "sensor-delay"]
    np.testing.assert_allclose(d.ranking["nrmse_after"], [0.04, 0.11, 0.118])
    assert d.ranking["significant"].tolist() == [True, False, False]
    assert d.ranking["ambiguous"].tolist() == [False, False, True]
    assert d.ladder["model"].tolist() == ["bouc-wen", "bouc-wen+viscous-friction",
                                          "bouc-wen+viscous-friction+asymmetric-hysteresis"]
    np.testing.assert_allclose(d.ladder["nrmse"], [0.12, 0.04, 0.037])
    assert list(d.worst.index) == ["ident.h5:p3102", "ident.h5:p4762"]  # larger rmse first
    assert d.summary == raw.summary and "viscous-friction" in d.ranking_table()
    assert "Ladder:" in repr(d)
    # the files are the CLI's: ranking and ladder stay lists of dicts in diagnosis.json
    d.save(tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert isinstance(doc["ranking"], list) and doc["ranking"][0]["effect"] == "viscous-friction"
    assert json.dumps(raw.to_json(), sort_keys=True) == before


def test_plot_loops_draws_the_measurement_under_a_thinner_model():
    runs = []
    for i, p in enumerate((0.3, 0.5)):
        r, _ = make_run("duhem", p, seed=i, n=2500, f=0.3, name=f"p{i}")
        runs.append(r)
    res = identify(runs, model="duhem", jobs=1, pressure_model="per-run")
    fig = res.plot_loops(which="identification")
    for ax in fig.axes[:2]:
        measured, model = ax.lines[:2]
        assert measured.get_label() == "measured"
        assert measured.get_zorder() < model.get_zorder()  # the model on top
        assert model.get_linewidth() < measured.get_linewidth()  # ... and thinner
