"""Test types as data: the run file's ``test_type`` attr, and import recognising it."""

from __future__ import annotations

import contextlib
import io
import json

import h5py
import numpy as np
import pytest

from pmalab.acquisition.csv_import import detect_test_type
from pmalab.cli import main as pmalab_main
from pmalab.errors import RunFileError
from pmalab.runfile import Run, read_runs, write_runs


def _run(name: str, **attrs) -> Run:
    n = 200
    t = np.arange(n) * 0.002
    return Run(
        name=name,
        time=t,
        position=5.0 + np.sin(t),
        force=300.0 + 10 * np.sin(t),
        muscle_pressure=np.full(n, 0.4),
        attrs=dict(attrs),
    )


def test_files_without_the_attr_are_isobaric_and_the_attr_round_trips(tmp_path):
    write_runs(tmp_path / "a.h5", [_run("old"), _run("iso", test_type="isometric")])
    got = {r.name: r.test_type for r in read_runs(tmp_path / "a.h5")}
    assert got == {"old": "isobaric", "iso": "isometric"}


def test_an_unknown_test_type_is_refused_naming_the_run(tmp_path):
    write_runs(tmp_path / "a.h5", [_run("r1", test_type="isobaric")])
    with h5py.File(tmp_path / "a.h5", "a") as f:
        f["runs/r1"].attrs["test_type"] = "isokinetic"
        del f["runs/r1"].attrs["attrs_sha256"]  # edited by another tool: no digest
    with pytest.raises(RunFileError, match=r"run 'r1'.*unknown test_type 'isokinetic'"):
        read_runs(tmp_path / "a.h5")


@pytest.mark.parametrize(
    ("x_span", "p_span", "kw", "expect"),
    [
        (10.0, 0.0, {}, "isobaric"),
        (0.05, 0.6, {}, "isometric"),
        (0.0, 0.6, {"held_position": True}, "isometric"),
        (10.0, 0.6, {}, "free"),
        (10.0, 0.6, {"load_N": 200.0}, "isotonic"),
    ],
)
def test_detect_test_type(x_span, p_span, kw, expect):
    u = np.sin(np.linspace(0, 6, 500))
    got, why = detect_test_type(5 + x_span / 2 * u, 0.3 + p_span / 2 * u, **kw)
    assert got == expect, why


def _cli(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main(args)
    return code, out.getvalue(), err.getvalue()


def _headerless(path, held_mm: float, dup: bool = False) -> None:
    """force N, pressure kPa, time s, state (1 pressurising, 2 venting), no header."""
    n = 1000
    t = np.arange(n) * 0.002
    p = np.concatenate([np.linspace(0, 620, n // 2), np.linspace(620, 0, n // 2)])
    f = p * (0.6 - 0.02 * held_mm)
    st = np.where(np.arange(n) < n // 2, 1, 2)
    np.savetxt(path, np.c_[f, p, t, st], delimiter="\t", fmt="%.5f")


def test_isometric_records_import_with_the_held_contraction_from_the_name(tmp_path):
    files = []
    for pct in (0, 25, 50):
        files.append(tmp_path / f"m10_{pct}pct.txt")
        _headerless(files[-1], pct)
    out = tmp_path / "iso.h5"
    cmd = ["import", *map(str, files), "--no-header"]
    cmd += ["--delimiter", "\\t", "--columns", "force,pressure,time,state"]
    cmd += ["--units", "pressure=kPa", "--position-from-name", r"_(\d+)pct"]
    code, _, err = _cli([*cmd, "--out", str(out)])
    assert code != 0 and "--max-contraction" in err
    assert "Traceback" not in err and not out.exists()
    code, stdout, err = _cli([*cmd, "--max-contraction", "16", "--out", str(out)])
    assert code == 0, err
    assert "isometric" in stdout and "contractions held at 0, 4, 8 mm" in stdout
    runs = read_runs(out)
    assert [r.test_type for r in runs] == ["isometric"] * 3
    assert [r.attrs["held_position_mm"] for r in runs] == [0.0, 4.0, 8.0]
    assert all(np.all(r.position == r.attrs["held_position_mm"]) for r in runs)
    assert runs[0].branch is not None and set(np.unique(runs[0].branch)) == {1.0, 2.0}
    assert runs[1].muscle_pressure.max() == pytest.approx(0.62)


def test_a_headerless_record_without_position_asks_for_the_held_contraction(tmp_path):
    _headerless(tmp_path / "a.txt", 0)
    cmd = ["import", str(tmp_path / "a.txt"), "--no-header", "--delimiter", "\\t"]
    code, _, err = _cli(
        [*cmd, "--columns", "force,pressure,time,-", "--out", str(tmp_path / "a.h5")]
    )
    assert code != 0 and "--position MM" in err and "Traceback" not in err


def test_real_shaped_isometric_records_import_and_identify_in_one_command_each(tmp_path):
    """The simulated stand-in of the real isometric records: no header; force N, pressure
    kPa, time s in whole ms with one repeated stamp, state 1/2; one file per held
    contraction (0/25/50/75 % of the maximum).  Import in one command, identify with the
    geometric map and a pressure-domain law, validated on a held-out length."""
    from pmalab.rig.sim.static_stand import load_static_truth, run_test, write_headerless

    truth = load_static_truth("geometric")
    files = []
    for i, pct in enumerate((0, 25, 50, 75)):
        rec = run_test(truth, "isometric", held_mm=pct / 100 * 48.0, period_s=6.0, seed=i)
        files.append(write_headerless(rec, tmp_path / f"festo10_{pct}pct.txt"))
    out = tmp_path / "iso.h5"
    cmd = ["import", *map(str, files), "--no-header", "--delimiter", "\\t"]
    cmd += ["--columns", "force,pressure,time,state", "--units", "pressure=kPa"]
    cmd += ["--position-from-name", r"_(\d+)pct", "--max-contraction", "48"]
    code, _, err = _cli([*cmd, "--out", str(out)])
    assert code != 0 and "--drop-duplicate-times" in err and not out.exists()
    code, stdout, err = _cli([*cmd, "--drop-duplicate-times", "--out", str(out)])
    assert code == 0, err
    assert "contractions held at 0, 12, 24, 36 mm" in stdout and "isometric" in stdout
    runs = read_runs(out)
    assert [r.attrs["dropped_duplicate_times"] for r in runs] == [1, 1, 1, 1]
    assert all(r.branch is not None for r in runs)
    code, stdout, err = _cli(
        [
            "identify",
            str(out),
            "--static",
            "chou-hannaford",
            "--length",
            "200",
            "--model",
            "duhem",
            "--hold-out",
            "festo10_50pct",
            "--out",
            str(tmp_path / "id"),
        ]
    )
    assert code == 0, err
    doc = json.loads((tmp_path / "id" / "identification.json").read_text())
    assert [v["run"] for v in doc["validation"]] == ["festo10_50pct"]
    v = doc["validation"][0]
    assert v["held_position_mm"] == 24.0 and v["nrmse"] < 2 * v["noise_floor_nrmse"]
    theta = doc["static_map"]["parameters"]["theta0_deg"]["value"]
    assert theta == pytest.approx(truth.braid_angle_deg, rel=0.03)
