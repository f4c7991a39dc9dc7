"""TDMS and MATLAB (.mat v5 and v7.3) exports import to the exact values.

Each file is written by its real library (npTDMS's TdmsWriter, scipy.io.savemat, h5py with
MATLAB's 512-byte header and MATLAB_class attributes, as MATLAB's ``-v7.3`` writes), then
``pmalab import`` reads it; the run file holds the same numbers in canonical units.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from pmalab.cli import main as pmalab_main
from pmalab.identify.api import load

N = 500


def _cli(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def _signals(bar: float, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 0.002  # s
    x = 15.0 * np.sin(2 * np.pi * 1.0 * t) + rng.normal(0, 0.01, N)  # mm contraction
    return {"time": t, "position": x, "force": 300 + 8 * x + 200 * bar,
            "muscle_pressure": np.full(N, bar / 10) + rng.normal(0, 1e-4, N)}


# ----------------------------------------------------------------------------- TDMS
def _tdms(path: Path, groups: dict[str, dict[str, np.ndarray]], units: dict[str, str],
          waveform: bool = False) -> None:
    objs = [RootObject({"author": "test"})]
    for g, sig in groups.items():
        objs.append(GroupObject(g))
        for name, v in sig.items():
            if waveform and name == "time":
                continue
            props = {"unit_string": units[name]} if name in units else {}
            if waveform:
                props.update({"wf_start_offset": 0.5, "wf_increment": 0.002})
            objs.append(ChannelObject(g, name, v, properties=props))
    with TdmsWriter(str(path)) as w:
        w.write_segment(objs)


def test_tdms_groups_are_runs_and_unit_strings_are_honoured(tmp_path):
    a, b = _signals(3.0, 1), _signals(5.0, 2)
    # the file holds force in kN, pressure in bar, position in m, time in s
    conv = lambda s: {"time": s["time"], "position": s["position"] / 1000,  # noqa: E731
                      "force": s["force"] / 1000, "muscle_pressure": s["muscle_pressure"] * 10}
    path = tmp_path / "campaign.tdms"
    _tdms(path, {"p3": conv(a), "p5": conv(b)},
          {"time": "s", "position": "m", "force": "kN", "muscle_pressure": "bar"})
    out = tmp_path / "c.h5"
    code, _text, err = _cli(["import", path, "--out", out])
    assert code == 0, err
    runs = {r.name: r for r in load(out)}
    assert sorted(runs) == ["p3", "p5"]
    for name, sig in (("p3", a), ("p5", b)):
        r = runs[name]
        np.testing.assert_allclose(r.time, sig["time"], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(r.position, sig["position"], rtol=1e-12)
        np.testing.assert_allclose(r.force, sig["force"], rtol=1e-12)
        np.testing.assert_allclose(r.muscle_pressure, sig["muscle_pressure"], rtol=1e-12)


def test_tdms_waveform_timing_gives_time_when_there_is_no_time_channel(tmp_path):
    sig = _signals(3.0)
    path = tmp_path / "wave.tdms"
    _tdms(path, {"Untitled": sig}, {}, waveform=True)
    out = tmp_path / "w.h5"
    code, _, err = _cli(["import", path, "--out", out])
    assert code == 0, err
    (r,) = load(out)
    np.testing.assert_allclose(r.time, 0.5 + 0.002 * np.arange(N), rtol=1e-12)
    np.testing.assert_allclose(r.force, sig["force"], rtol=1e-12)


@pytest.mark.parametrize("mutate,needle", [
    (lambda s: s.pop("force"), "group 'g': channel for 'force': no channel 'force'"),
    (lambda s: s.update(position=s["position"][:-3]), "channels of different lengths"),
    (lambda s: s.update(force=s["force"] * np.nan), "force"),
])
def test_tdms_mistakes_name_file_group_and_channel(tmp_path, mutate, needle):
    sig = _signals(3.0)
    mutate(sig)
    path = tmp_path / "bad.tdms"
    _tdms(path, {"g": sig}, {})
    out = tmp_path / "b.h5"
    code, _, err = _cli(["import", path, "--out", out])
    assert code == 2 and needle in err and "bad.tdms" in err and err.count("\n") == 1, err
    assert not out.exists()


def test_tdms_without_time_or_waveform_timing_is_refused(tmp_path):
    sig = _signals(3.0)
    sig.pop("time")
    path = tmp_path / "notime.tdms"
    _tdms(path, {"g": sig}, {})
    code, _, err = _cli(["import", path, "--out", tmp_path / "x.h5"])
    assert code == 2 and "no time channel and no waveform timing" in err, err


# ----------------------------------------------------------------------------- MATLAB
def _v73(path: Path, variables: dict[str, object]) -> None:
    """A MATLAB -v7.3 file: 512-byte text header (userblock), then HDF5; arrays transposed."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in variables.items():
            if isinstance(v, dict):
                g = f.create_group(k)
                g.attrs["MATLAB_class"] = np.bytes_("struct")
                for fk, fv in v.items():
                    d = g.create_dataset(fk, data=np.atleast_2d(fv))  # 1×N on disk: N×1 in MATLAB
                    d.attrs["MATLAB_class"] = np.bytes_("double")
            else:
                d = f.create_dataset(k, data=np.asarray(v).T)
                d.attrs["MATLAB_class"] = np.bytes_("double")
    with path.open("r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Tue Nov 24 2026 "
                 b"HDF5 schema 1.00 .".ljust(116) + b"\x00" * 8 + b"\x00\x02IM")


@pytest.mark.parametrize("version", ["5", "7.3"])
def test_mat_structs_are_runs(tmp_path, version):
    a, b = _signals(3.0, 1), _signals(5.0, 2)
    path = tmp_path / f"runs{version}.mat"
    if version == "5":
        scipy.io.savemat(path, {"run3bar": a, "run5bar": b})
    else:
        _v73(path, {"run3bar": a, "run5bar": b})
    out = tmp_path / "m.h5"
    code, _, err = _cli(["import", path, "--out", out])
    assert code == 0, err
    runs = {r.name: r for r in load(out)}
    assert sorted(runs) == ["run3bar", "run5bar"]
    for name, sig in (("run3bar", a), ("run5bar", b)):
        for ch in ("time", "position", "force", "muscle_pressure"):
            np.testing.assert_allclose(getattr(runs[name], ch), sig[ch], rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("version", ["5", "7.3"])
def test_mat_matrix_with_columns_and_units(tmp_path, version):
    s = _signals(4.0)
    m = np.column_stack([s["time"] * 1000, np.zeros(N), -s["position"], s["muscle_pressure"] * 10,
                         s["force"]])  # ms, junk, elongation mm, bar, N
    path = tmp_path / f"matrix{version}.mat"
    if version == "5":
        scipy.io.savemat(path, {"data": m})
    else:
        _v73(path, {"data": m})
    out = tmp_path / "m.h5"
    code, _, err = _cli(["import", path, "--columns", "time,-,position,pressure,force",
                         "--units", "time=ms,pressure=bar", "--negate", "position", "--out", out])
    assert code == 0, err
    (r,) = load(out)
    assert r.name == f"matrix{version}"
    for ch in ("time", "position", "force", "muscle_pressure"):
        np.testing.assert_allclose(getattr(r, ch), s[ch], rtol=1e-12, atol=1e-12)


def test_mat_vectors_by_name_and_one_line_mistakes(tmp_path):
    s = _signals(2.0)
    path = tmp_path / "vec.mat"
    scipy.io.savemat(path, {"t": s["time"], "x": s["position"], "F": s["force"],
                            "p": s["muscle_pressure"]})
    out = tmp_path / "v.h5"
    code, _, err = _cli(["import", path, "--out", out])
    assert code == 2 and "variable for 'time': no variable 'time' (variables: t, x, F, p)" in err
    assert "--time-col NAME" in err and not out.exists()
    code, _, err = _cli(["import", path, "--time-col", "t", "--position-col", "x",
                         "--force-col", "F", "--pressure-col", "p", "--out", out])
    assert code == 0, err
    (r,) = load(out)
    np.testing.assert_allclose(r.force, s["force"], rtol=1e-12)


def test_not_a_mat_file_is_one_line(tmp_path):
    path = tmp_path / "fake.mat"
    path.write_bytes(b"hello, this is not MATLAB\n" * 10)
    code, _, err = _cli(["import", path, "--out", tmp_path / "x.h5"])
    assert code == 2 and "fake.mat: not a MATLAB .mat file" in err and err.count("\n") == 1


def test_a_folder_of_tdms_files_is_one_campaign(tmp_path):
    files = []
    for bar in (1, 3, 5):
        p = tmp_path / f"m_{bar}bar.tdms"
        _tdms(p, {"Untitled": _signals(float(bar), bar)}, {})
        files.append(p)
    out = tmp_path / "c.h5"
    code, _text, err = _cli(["import", *files, "--pressure-from-name", r"(\d+)bar", "--out", out])
    assert code == 0, err
    runs = load(out)
    # several files: each run named after its file
    assert [r.name for r in runs] == ["m_1bar", "m_3bar", "m_5bar"]
    assert [round(r.nominal_pressure, 3) for r in runs] == [0.1, 0.3, 0.5]
