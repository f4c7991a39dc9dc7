"""``pmalab control``: run files, experiments, user errors (short virtual-clock runs)."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from pmalab.cli import main
from pmalab.control.experiments import SEED_EXPERIMENTS, load_experiments
from pmalab.errors import ConfigError
from pmalab.runfile import decode_attr, read_runs


def test_one_run_writes_a_contract_run_file_with_units_gains_and_metrics(tmp_path, capsys):
    out = tmp_path / "c.h5"
    rc = main(["control", "--controller", "sn-pid", "--reference", "square:0.5Hz:10mm",
               "--duration", "2", "--out", str(out)])
    assert rc == 0
    assert "overshoot" in capsys.readouterr().out
    run = read_runs(out)[0]  # the run-file contract's reader opens it
    assert run.name == "sn-pid" and len(run) == 1001
    assert run.attrs["status"] == "completed"
    with h5py.File(out) as f:
        g = f["runs/sn-pid"]
        # text attrs are fixed-length UTF-8 (inside checksummed headers): decode_attr reads them
        units = {k: decode_attr(g[k].attrs["units"]) for k in ("time", "position", "position_reference",
                                                   "muscle_pressure", "muscle_pressure_command")}
        assert units == {"time": "s", "position": "mm", "position_reference": "mm",
                         "muscle_pressure": "MPa", "muscle_pressure_command": "MPa"}
        assert set(g["gains"]) == {"outer_kp", "outer_ki", "outer_kd", "inner_kp", "inner_ki",
                                   "inner_kd"}
        assert decode_attr(g["gains/outer_kp"].attrs["units"]) == "N/mm"
        assert decode_attr(g.attrs["controller"]) == "sn-pid"
        assert decode_attr(g.attrs["loop"]) == "position"
        settings = json.loads(decode_attr(g.attrs["settings"]))
        assert g["status"][()].rstrip(b"\x00") == b"completed"
    metrics = run.attrs["metrics"]  # the run's summary (written at its end), as attrs
    assert run.attrs["vent_confirmed"] is True and run.attrs["n_samples"] == 1001
    assert metrics["kind"] == "square" and len(metrics["steps"]) == 2
    assert settings["outer"]["kp"] > 0
    ref = np.asarray(h5py.File(out)["runs/sn-pid/position_reference"])
    assert set(np.unique(ref)) == {0.0, 10.0}


def test_pressure_loop_records_its_reference(tmp_path):
    out = tmp_path / "p.h5"
    assert main(["control", "--controller", "pid", "--reference", "square:0.5Hz:0.4MPa",
                 "--duration", "1", "--out", str(out)]) == 0
    with h5py.File(out) as f:
        g = f["runs/pid"]
        assert decode_attr(g.attrs["loop"]) == "pressure"
        assert decode_attr(g["muscle_pressure_reference"].attrs["units"]) == "MPa"
        assert float(np.max(g["muscle_pressure_reference"])) == pytest.approx(0.4)


@pytest.mark.parametrize("argv,needle", [
    (["--reference", "square:0.1Hz:15mm", "--duration", "1"], "--controller: required"),
    (["--controller", "pid", "--reference", "triangle:0.1Hz:15mm", "--duration", "1"],
     "expected KIND:FREQHz:MAGNITUDE"),
    (["--controller", "pid", "--reference", "square:0.1Hz:40mm", "--duration", "1"],
     "magnitude must be in (0, 25]"),
    (["--controller", "pid", "--reference", "square:0.1Hz:15mm", "--duration", "-1"],
     "--duration: must be a number of seconds"),
    (["--controller", "pid", "--reference", "square:0.1Hz:15mm", "--loop", "pressure",
      "--duration", "1"], "the pressure loop needs a magnitude in MPa"),
    (["--controller", "pid", "--reference", "square:0.1Hz:15mm", "--duration", "1",
      "--model", "nope.json"], "nope.json: no such file"),
])
def test_user_errors_are_one_line_and_leave_nothing(tmp_path, capsys, argv, needle):
    out = tmp_path / "x.h5"
    rc = main(["control", *argv, "--out", str(out)])
    err = capsys.readouterr().err
    assert rc != 0
    assert needle in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not list(tmp_path.iterdir())


def test_an_identification_without_pressure_fits_is_refused(tmp_path, capsys):
    bad = tmp_path / "identification.json"
    bad.write_text(json.dumps({"model": "bouc-wen", "pressure_fits": {"k": [1, 2]}}))
    rc = main(["control", "--controller", "pid", "--reference", "square:0.1Hz:15mm",
               "--duration", "1", "--model", str(bad), "--out", str(tmp_path / "x.h5")])
    assert rc != 0
    assert "pressure_fits.k" in capsys.readouterr().err


def test_never_overwrites_without_force(tmp_path, capsys):
    out = tmp_path / "c.h5"
    out.write_text("keep me")
    rc = main(["control", "--controller", "pid", "--reference", "square:0.1Hz:15mm",
               "--duration", "1", "--out", str(out)])
    assert rc != 0 and "already exists" in capsys.readouterr().err
    assert out.read_text() == "keep me"


def test_experiments_run_every_controller_and_write_metrics(tmp_path):
    exp = tmp_path / "e.toml"
    exp.write_text(
        '[experiments]\ncontrollers = ["pid", "rbf-pid"]\nduration_s = 2.0\n'
        '[[experiment]]\nname = "sq"\nreference = "square:0.5Hz:10mm"\n'
        '[experiment.seeds]\nS1 = { classic_overshoot_pct = 31.0 }\n'
        '[[experiment]]\nname = "p"\nreference = "square:0.5Hz:0.5MPa"\nduration_s = 1.0\n')
    out = tmp_path / "out"
    assert main(["control", "--experiments", str(exp), "--out", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {"sq.h5", "p.h5", "metrics.json"}
    assert [r.name for r in read_runs(out / "sq.h5")] == ["pid", "rbf-pid"]
    doc = json.loads((out / "metrics.json").read_text())
    assert [(r["experiment"], r["controller"]) for r in doc["results"]] == [
        ("sq", "pid"), ("sq", "rbf-pid"), ("p", "pid"), ("p", "rbf-pid")]
    assert doc["results"][0]["seeds"]["S1"]["classic_overshoot_pct"] == 31.0
    # a second run refuses to overwrite, before running anything
    assert main(["control", "--experiments", str(exp), "--out", str(out)]) != 0


def test_the_shipped_seed_experiments_file_holds_the_seeds_set():
    es = load_experiments(SEED_EXPERIMENTS)
    refs = {e.reference.text for e in es.experiments}
    assert refs == {"square:0.1Hz:0.5MPa", "square:0.1Hz:10mm", "square:0.1Hz:15mm",
                    "square:0.1Hz:20mm", "sine:0.1Hz:15mm", "sine:0.1Hz:20mm"}
    assert es.controllers == ["pid", "sn-pid", "rbf-pid"]


def test_an_experiments_file_mistake_names_the_field(tmp_path):
    exp = tmp_path / "e.toml"
    exp.write_text('[[experiment]]\nname = "a"\nreference = "square:0.1Hz:15mm"\nspeed = 2\n')
    with pytest.raises(ConfigError, match=r"experiment\[0\]\.speed: unknown key"):
        load_experiments(exp)


def test_an_identification_missing_a_law_parameter_is_refused(tmp_path, capsys):
    doc = json.loads((SEED_EXPERIMENTS.parent / "identification-bouc-wen.json").read_text())
    del doc["pressure_fits"]["beta"]
    bad = tmp_path / "identification.json"
    bad.write_text(json.dumps(doc))
    rc = main(["control", "--controller", "pid", "--reference", "square:0.1Hz:15mm",
               "--duration", "1", "--model", str(bad), "--out", str(tmp_path / "x.h5")])
    assert rc != 0
    err = capsys.readouterr().err
    assert "pressure_fits.beta': missing (the bouc-wen law needs it)" in err
