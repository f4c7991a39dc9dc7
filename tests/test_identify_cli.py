"""`pmalab identify`: output contract, role handling, refusals and one-line errors."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from identify_synth import make_run

from pmalab.cli import main
from pmalab.runfile import Run, write_runs

RUN_KEYS = {"file", "run", "role", "muscle_pressure_MPa", "frequency_Hz", "waveform", "parameters",
            "stderr", "correlation", "fixed", "warnings", "rmse", "nrmse", "fit_percent",
            "max_error", "energy_error_percent", "branch_rmse"}
VAL_KEYS = {"file", "run", "muscle_pressure_MPa", "frequency_Hz", "rmse", "nrmse", "fit_percent",
            "max_error", "energy_error_percent", "branch_rmse"}
TOP_KEYS = {"model", "effects", "pmalab_version", "created", "inputs", "parameter_names", "runs",
            "pressure_fits", "pressure_fit_stats", "validation", "warnings"}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("idcli")
    runs = []
    for i, p in enumerate((0.2, 0.4, 0.6)):
        r, _ = make_run("duhem", p, seed=i, n=3000, f=0.3, name=f"p{i}")
        r.attrs["role"] = "identification"
        runs.append(r)
    held, _ = make_run("duhem", 0.5, seed=9, n=3000, f=0.3, name="held")
    held.attrs["role"] = "validation"
    ident = write_runs(d / "ident.h5", [*runs, held])
    v, _ = make_run("duhem", 0.3, seed=7, n=3000, f=0.2, waveform="triangle", name="v1")
    val = write_runs(d / "val.h5", [v])
    return d, ident, val


def _err_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


def test_identify_writes_the_contract(files, capsys) -> None:
    d, ident, val = files
    out = d / "out"
    rc = main(["identify", str(ident), "--model", "duhem", "--validate", str(val), "--out",
               str(out), "--jobs", "1"])
    assert rc == 0
    stdout = capsys.readouterr().out
    assert stdout.count("identify ") == 3 and stdout.count("validate ") == 2
    assert "fit" in stdout and "%" in stdout
    doc = json.loads((out / "identification.json").read_text())
    assert TOP_KEYS <= set(doc)
    assert doc["model"] == "duhem" and doc["effects"] == []
    # the method block names the solver that ran (pmalab's trf loop, not SciPy's least_squares)
    assert "pmalab.identify.estimation.trust_region" in doc["method"]["fit"]
    assert len(doc["runs"]) == 3 and len(doc["validation"]) == 2
    for r in doc["runs"]:
        assert RUN_KEYS <= set(r) and r["role"] == "identification"
        assert set(r["parameters"]) == set(doc["parameter_names"])
        assert set(r["branch_rmse"]) == {"stretch", "release"}
        assert len(r["correlation"]["matrix"]) == len(r["correlation"]["names"])
        assert r["fit_percent"] > 95.0
        assert "a" in r["fixed"] and r["stderr"]["a"] is None
    for v in doc["validation"]:
        assert VAL_KEYS <= set(v)
        assert v["fit_percent"] > 95.0
    assert {v["run"] for v in doc["validation"]} == {"held", "v1"}
    for name in doc["parameter_names"]:
        assert len(doc["pressure_fits"][name]) == 3
        st = doc["pressure_fit_stats"][name]
        assert {"r2", "residuals", "pressures", "values", "stderr"} <= set(st)
    assert {i["file"] for i in doc["inputs"]} == {str(ident), str(val)}
    assert all("sha256" in i["provenance"] for i in doc["inputs"])
    with h5py.File(out / "predictions.h5", "r") as f:
        assert f.attrs["format"] == "pmalab.predictions"
        roles = []
        for g in f["runs"].values():
            assert {"time", "position", "muscle_pressure", "force", "force_model"} <= set(g)
            for a in ("role", "file", "run", "muscle_pressure_MPa", "frequency_Hz", "waveform", "model"):
                assert a in g.attrs
            roles.append(g.attrs["role"])
            assert g["force_model"].shape == g["force"].shape
        assert sorted(roles) == ["identification"] * 3 + ["validation"] * 2
    # never overwrite without --force
    rc = main(["identify", str(ident), "--model", "duhem", "--out", str(out), "--quiet"])
    assert rc != 0 and "--force" in _err_line(capsys)


@pytest.mark.parametrize(
    "argv_tail, needle",
    [
        (["--fix", "k"], "NAME=VALUE"),
        (["--fix", "nosuch=1"], "nosuch"),
        # a typo or an already fitted parameter is refused, not ignored
        (["--free", "nosuch"], "--free nosuch: model duhem fixes only a by default"),
        (["--free", "k"], "--free k: model duhem fixes only a by default"),
        (["--jobs", "0"], "--jobs"),
        (["--add", "no-such-effect"], "no-such-effect"),
        (["--effects", "/nonexistent/eff.py"], "eff.py"),
        (["--scheduler", "tcp://127.0.0.1:9"], "scheduler"),
    ],
)
def test_bad_options_give_one_line(files, capsys, monkeypatch, argv_tail, needle) -> None:
    import pmalab.identify.campaign.batch as batch

    monkeypatch.setattr(batch, "SCHEDULER_TIMEOUT_S", 1.0)
    d, ident, _ = files
    rc = main(["identify", str(ident), "--model", "duhem", "--out", str(d / "bad"), "--quiet",
               "--jobs", "1", *argv_tail])
    assert rc != 0
    line = _err_line(capsys)
    assert needle in line, line


def test_malformed_inputs_give_one_line(files, capsys, tmp_path) -> None:
    rc = main(["identify", str(tmp_path / "missing.h5"), "--model", "bouc-wen", "--out",
               str(tmp_path / "o")])
    assert rc != 0 and "missing.h5" in _err_line(capsys)
    n = 500
    flat = Run(name="flat", time=np.arange(n) / 500.0, position=np.full(n, 3.0),
               force=np.linspace(0, 10, n), muscle_pressure=np.full(n, 0.3),
               attrs={"muscle_pressure_MPa": 0.3})
    path = write_runs(tmp_path / "flat.h5", [flat])
    rc = main(["identify", str(path), "--model", "bouc-wen", "--out", str(tmp_path / "o"),
               "--jobs", "1", "--quiet"])
    line = _err_line(capsys)
    assert rc != 0 and "flat" in line and "position" in line
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    rc = main(["identify", str(bad), "--model", "duhem", "--out", str(tmp_path / "o")])
    assert rc != 0 and "bad.h5" in _err_line(capsys)


def test_api_reads_well(files) -> None:
    from pmalab.identify import identify, load

    _, ident, val = files
    runs = load(ident)
    res = identify(runs, model="duhem", validate=load(val), jobs=1)
    assert len(res.validation) == 2 and res.validation_table.shape[0] == 2
    assert res.parameters.shape[0] == 3 and "b_stderr" in res.parameters
    assert res.pressure_table.loc["b", "degree"] == 2
    f = res.predict(runs["held"])
    assert f.shape == runs["held"].force.shape
    fig = res.plot_loops()
    assert len([a for a in fig.axes if a.get_visible()]) == 5
    res.plot_parameters()
    assert "validate" in repr(res)


def test_sim_rig_run_fits_base_model(tmp_path, capsys) -> None:
    """A simulated-rig run (every effect off) is fitted by the base model above 90 %."""
    from pmalab.identify.estimation.single import fit_run
    from pmalab.runfile import read_runs

    path = tmp_path / "sim.h5"
    rc = main(["run", "--rig", "sim", "--protocol", "seed-bouc-wen", "--only", "ident-476kPa",
               "--out", str(path), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    run = read_runs(path)[0]
    for law in ("bouc-wen", "duhem"):
        res = fit_run(run, law)
        assert res.fit_percent > 90.0, (law, res.fit_percent)
        # the physical loop direction: A < 0 (Bouc-Wen) / b < 0 (Duhem, a = 0)
        assert res.values["A" if law == "bouc-wen" else "b"] < 0


def test_information_is_a_note_and_quiet_prints_warnings_only(files, capsys) -> None:
    """The joint refinement and the held-out runs are information (`note:`); with -q only
    `warning:` lines remain; nothing says `free=[...]` (the CLI flag is --free)."""
    d, ident, _ = files
    assert main(["identify", str(ident), "--model", "duhem", "--out", str(d / "n1"),
                 "--jobs", "1"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert any(ln.startswith("note: 1 run(s) with role 'validation'") and
               ln.endswith("held out for validation: ident.h5:held") for ln in err)
    assert any(ln.startswith("note: pressure laws refined jointly") for ln in err)
    assert not any(ln.startswith("warning: pressure laws refined") for ln in err)
    assert all(ln.startswith(("note: ", "warning: ")) for ln in err if ln.strip())
    assert not any("free=[" in ln for ln in err)
    assert main(["identify", str(ident), "--model", "duhem", "--out", str(d / "n2"),
                 "--jobs", "1", "-q"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert not any(ln.startswith("note:") for ln in err)
