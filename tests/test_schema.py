"""The result files' schema (pmalab.identify.schema): every writer's output reads back
equal through its typed reader, and a damaged copy is refused with one line naming the
key path."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
from identify_synth import make_run

from pmalab.cli import main
from pmalab.errors import PmalabError
from pmalab.identify import schema
from pmalab.identify.api import diagnose, identify
from pmalab.identify.outputs import identification_dict
from pmalab.identify.schema import (
    ResultFileError,
    check,
    read_control_summary,
    read_diagnosis,
    read_identification,
    read_predictions,
)
from pmalab.reports.control import load_control_file
from pmalab.runfile import read_runs


def _json(obj):
    """What a writer's dict becomes in the file (strict JSON)."""
    return json.loads(json.dumps(obj, allow_nan=False))


def _damage(src, dst, fn):
    obj = json.loads(src.read_text())
    fn(obj)
    dst.write_text(json.dumps(obj))
    return dst


def _refused(read, path, needle):
    with pytest.raises(ResultFileError) as ei:
        read(path)
    msg = str(ei.value)
    assert isinstance(ei.value, PmalabError)
    assert "\n" not in msg and msg.startswith(str(path)), msg
    assert needle in msg, msg
    return msg


# --------------------------------------------------------------------------- identify
@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    runs = [
        make_run("bouc-wen", p, seed=i, n=3000, f=0.3, name=f"p{int(p * 1000)}")[0]
        for i, p in enumerate((0.2, 0.4, 0.6))
    ]
    val = make_run("bouc-wen", 0.5, seed=9, n=3000, f=0.3, name="val500")[0]
    res = identify(runs, model="bouc-wen", validate=[val], jobs=1)
    d = tmp_path_factory.mktemp("ident")
    res.save(d)
    return res, d


def test_identification_round_trip(identified, tmp_path):
    res, d = identified
    doc = read_identification(d / "identification.json")
    written = _json(identification_dict(res))
    written.pop("created")  # the time stamp of the call
    doc_cmp = dict(doc)
    doc_cmp.pop("created")
    assert doc_cmp == written
    assert len(doc["runs"]) == 3 and len(doc.get("validation", [])) == 1
    assert doc["validation"][0]["run"] == "val500"


@pytest.mark.parametrize(
    "fn, needle",
    [
        (lambda o: o.pop("model"), ": model: missing key"),
        (lambda o: o["runs"][1].pop("parameters"), ": runs[1].parameters: missing key"),
        (
            lambda o: o["validation"][0].__setitem__("nrmse", "x"),
            ': validation[0].nrmse: expected a number, got "x"',
        ),
        (lambda o: o.__setitem__("runs", {}), ": runs: expected a list, got an object"),
        (
            lambda o: o["runs"][0]["messages"].append({"kind": "note", "text": "t", "data": {}}),
            ": runs[0].messages[",
        ),
        (
            lambda o: o["runs"][0]["branch_rmse"].__setitem__("stretch", [1]),
            ": runs[0].branch_rmse.stretch: expected a number or null, got a list",
        ),
        (
            lambda o: o.__setitem__("joint_fit", 3),
            ": joint_fit: expected an object or null, got 3",
        ),
    ],
)
def test_identification_damaged(identified, tmp_path, fn, needle):
    _, d = identified
    bad = _damage(d / "identification.json", tmp_path / "identification.json", fn)
    msg = _refused(read_identification, bad, needle)
    if "messages[" in needle:
        assert msg.endswith(".code: missing key")


def test_identification_optional_and_extra_keys(identified, tmp_path):
    _, d = identified
    obj = json.loads((d / "identification.json").read_text())
    for k in ("joint_fit", "output_error", "validation", "messages"):
        obj.pop(k, None)
    obj["a_key_from_a_newer_pmalab"] = {"anything": [1, "two"]}
    obj["runs"][0]["rmse_position_mm"] = 0.1  # an output-error fit's position keys
    obj["runs"][0]["nrmse_position"] = None
    p = tmp_path / "identification.json"
    p.write_text(json.dumps(obj))
    assert read_identification(p) == obj
    obj["runs"][0]["fit_percent_position"] = "high"
    p.write_text(json.dumps(obj))
    _refused(read_identification, p, "runs[0].fit_percent_position: expected a number or null")


def test_malformed_json_and_top_level(tmp_path):
    p = tmp_path / "identification.json"
    p.write_text("[1, 2]")
    _refused(read_identification, p, "expected a JSON object at the top level, got a list")
    p.write_text('{"model": ')
    _refused(read_identification, p, "malformed JSON at line 1")


# --------------------------------------------------------------------------- predictions
def test_predictions_round_trip(identified, tmp_path):
    res, d = identified
    doc = read_predictions(d / "predictions.h5")
    assert doc.model == res.model.name and doc.format_version == 1
    runs = [*res.runs, *(v.run for v in res.validation)]
    assert [r.role for r in doc.runs] == ["identification"] * 3 + ["validation"]
    for pr, run in zip(doc.runs, runs):
        assert pr.attrs["run"] == run.name
        assert pr.attrs["muscle_pressure_MPa"] == pytest.approx(run.nominal_pressure)
        for ch in ("time", "position", "muscle_pressure", "force"):
            np.testing.assert_array_equal(pr.arrays[ch], getattr(run, ch))
        assert pr.units["force"] == "N" and pr.units["position"] == "mm"
    for pr, rf, run in zip(doc.runs, res.campaign.runs, res.runs):
        np.testing.assert_array_equal(pr.arrays["force_model"], rf.result.predict(run))
        assert "force_model_quadratic" in pr.arrays
    np.testing.assert_array_equal(doc.runs[3].arrays["force_model"], res.validation[0].force_model)

    bad = tmp_path / "predictions.h5"
    shutil.copy(d / "predictions.h5", bad)
    with h5py.File(bad, "a") as f:
        key = next(iter(f["runs"]))
        del f[f"runs/{key}/force_model"]
    _refused(read_predictions, bad, f": /runs/{key}/force_model: missing dataset")
    shutil.copy(d / "predictions.h5", bad)
    with h5py.File(bad, "a") as f:
        f["runs"][key].attrs["role"] = 3
    _refused(read_predictions, bad, f": /runs/{key}: attr 'role': expected a string")


# --------------------------------------------------------------------------- diagnose
@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    runs = [
        make_run("bouc-wen", p, seed=i, n=3000, f=0.3, name=f"p{int(p * 1000)}")[0]
        for i, p in enumerate((0.2, 0.4, 0.6))
    ]
    val = make_run("bouc-wen", 0.5, seed=9, n=3000, f=0.3, name="val500")[0]
    res = diagnose(
        runs, "bouc-wen", validate=[val], effects=["viscous-friction"], laws=(), max_steps=1
    )
    d = tmp_path_factory.mktemp("diag")
    res.save(d)
    return res, d


def test_diagnosis_round_trip(diagnosed):
    res, d = diagnosed
    doc = read_diagnosis(d / "diagnosis.json")
    assert doc == _json(res.raw.to_json())
    assert [r["effect"] for r in doc["ranking"]] == ["viscous-friction"]
    assert doc.get("noise_floor", {}).get("mean_nrmse") is not None


@pytest.mark.parametrize(
    "fn, needle",
    [
        (lambda o: o["ranking"][0].pop("significant"), ": ranking[0].significant: missing key"),
        (
            lambda o: o["ladder"][0].__setitem__("nrmse", None),
            ": ladder[0].nrmse: expected a number, got null",
        ),
        (
            lambda o: o["noise_floor"].__setitem__("per_run", []),
            ": noise_floor.per_run: expected an object, got a list",
        ),
        (lambda o: o["rounds"][0].pop("step"), ": rounds[0].step: missing key"),
        (
            lambda o: o["ladder"][0].__setitem__("step", 0.5),
            ": ladder[0].step: expected an integer, got 0.5",
        ),
    ],
)
def test_diagnosis_damaged(diagnosed, tmp_path, fn, needle):
    _, d = diagnosed
    bad = _damage(d / "diagnosis.json", tmp_path / "diagnosis.json", fn)
    _refused(read_diagnosis, bad, needle)


# --------------------------------------------------------------------------- control
@pytest.fixture(scope="module")
def control_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("control") / "pid.h5"
    rc = main(
        [
            "control",
            "--controller",
            "pid",
            "--reference",
            "sine:0.2Hz:10mm",
            "--duration",
            "1",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    return out


def _raw_summary(path, run):
    with h5py.File(path, "r") as f:
        return json.loads(bytes(np.asarray(f[f"runs/{run}/summary"][()], dtype=np.uint8)))


def test_control_summary_round_trip(control_file):
    data = load_control_file(control_file)
    assert data.runs
    for r in data.runs:
        summ = read_control_summary(control_file, r.name)
        assert summ == _raw_summary(control_file, r.name)
        # the run-file readers merge the summary into the run's attrs
        for k, v in summ.items():
            assert r.attrs[k] == v, k
        assert summ["n_samples"] > 0 and summ["metrics"]["rms_error"] is not None
    names = [r.name for r in read_runs(control_file)]
    assert names == [r.name for r in data.runs]


@pytest.mark.parametrize(
    "fn, needle",
    [
        (lambda o: o.pop("n_samples"), "/summary: n_samples: missing key"),
        (
            lambda o: o["metrics"].__setitem__("rms_error", "x"),
            '/summary: metrics.rms_error: expected a number or null, got "x"',
        ),
    ],
)
def test_control_summary_damaged(control_file, tmp_path, fn, needle):
    run = load_control_file(control_file).runs[0].name
    bad = tmp_path / "pid.h5"
    shutil.copy(control_file, bad)
    obj = _raw_summary(bad, run)
    fn(obj)
    with h5py.File(bad, "a") as f:
        g = f[f"runs/{run}"]
        del g["summary"]
        g.create_dataset("summary", data=np.frombuffer(json.dumps(obj).encode(), np.uint8))
    _refused(lambda p: read_control_summary(p, run), bad, needle)


# --------------------------------------------------------------------------- the checker
def test_checker_derives_from_the_annotations():
    row = {"file": None, "run": "r", "muscle_pressure_MPa": 0.4, "nrmse": 0.1}
    assert check(row, schema.ValidationRow, "x") is row
    with pytest.raises(ResultFileError, match=r"^x: nrmse: expected a number, got true$"):
        check({**row, "nrmse": True}, schema.ValidationRow, "x")
    with pytest.raises(ResultFileError, match=r"^x: run: missing key$"):
        check({k: v for k, v in row.items() if k != "run"}, schema.ValidationRow, "x")
    long = "y" * 100
    with pytest.raises(ResultFileError, match=r'got "yyy.*\.\.\.$'):
        check({**row, "nrmse": long}, schema.ValidationRow, "x")


def test_shipped_identifications_read():
    from pathlib import Path

    import pmalab

    shipped = sorted((Path(pmalab.__file__).parent / "data" / "control").glob("identification-*.json"))
    assert shipped
    for p in shipped:
        assert read_identification(p)["runs"]


def test_diagnosis_rounds_are_ladder_rounds_or_active_rounds(tmp_path):
    """``rounds`` holds the ladder's ranking rounds, or after ``diagnose --run-suggested``
    the active rounds: the reader takes either kind and names what an entry lacks."""
    active = {"round": 1, "experiment": {"frequency_Hz": 4.0, "runs": []},
              "expected_separation": {"min_x_floor": 3.0}, "protocol": "[protocol]\n",
              "file": "c-round1.h5", "recorded_runs": ["r1"], "rig_time_s": 58.5,
              "verdict": {"first": "viscous-friction"}}
    ladder = {"step": 1, "ambiguous": [], "candidates": []}
    for rounds in ([ladder], [active]):
        p = tmp_path / "d.json"
        p.write_text(json.dumps({"model": "bouc-wen", "ranking": [], "rounds": rounds}))
        assert read_diagnosis(p)["rounds"] == rounds
    broken = {k: v for k, v in active.items() if k != "file"}
    p.write_text(json.dumps({"model": "bouc-wen", "ranking": [], "rounds": [broken]}))
    # neither kind: the first kind's missing key is named (the reader cannot guess more)
    _refused(read_diagnosis, p, "rounds[0].step: missing key")
    p.write_text(json.dumps({"model": "bouc-wen", "ranking": [],
                             "rounds": [{**active, "rig_time_s": "long"}]}))
    _refused(read_diagnosis, p, 'rounds[0].rig_time_s: expected a number, got "long"')
