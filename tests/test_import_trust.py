"""Imports that cannot be silently wrong: repeated time stamps, ..."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest

from pmalab.cli import main as pmalab_main
from pmalab.runfile import read_runs


def _cli(args) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def _export(path: Path, *, n: int = 5000, p: float = 0.4, seed: int = 0,
            repeat: tuple[int, ...] = ()) -> Path:
    """A clean isobaric export (0.5 Hz sine, 500 Hz), rows in ``repeat`` written twice."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.002
    x = 12.0 + 8.0 * np.sin(2 * np.pi * 0.5 * t)
    f = 300.0 - 10.0 * x + rng.normal(0.0, 1.0, n)
    pm = p + rng.normal(0.0, 0.001, n)
    rows = [f"{a:.3f},{b:.4f},{c:.3f},{d:.4f}" for a, b, c, d in zip(t, x, f, pm)]
    for k in sorted(repeat, reverse=True):
        rows.insert(k + 1, rows[k])
    path.write_text("time,position,force,muscle_pressure\n" + "\n".join(rows) + "\n")
    return path


def test_repeated_stamp_refused_with_the_option_named(tmp_path):
    src = _export(tmp_path / "rec.csv", repeat=(8,))
    code, _, err = _cli(["import", src, "--out", tmp_path / "o.h5"])
    assert code == 2 and err.count("\n") == 1
    assert "sample 9" in err and "--drop-duplicate-times" in err
    assert not (tmp_path / "o.h5").exists()


def test_drop_duplicate_times_counts_and_keeps_the_rest(tmp_path):
    src = _export(tmp_path / "rec.csv", n=5000, repeat=(8, 1000, 4000))
    code, out, err = _cli(["import", src, "--drop-duplicate-times", "--out", tmp_path / "o.h5"])
    assert code == 0, err
    assert "3 duplicate time stamps dropped" in out
    (run,) = read_runs(tmp_path / "o.h5")
    assert len(run) == 5000  # the original samples, each once
    assert np.all(np.diff(run.time) > 0)
    assert run.attrs["dropped_duplicate_times"] == 3


def test_drop_duplicate_times_campaign_count(tmp_path):
    a = _export(tmp_path / "a_3bar.csv", p=0.3, repeat=(8,))
    b = _export(tmp_path / "b_5bar.csv", p=0.5, seed=1, repeat=(20,))
    code, out, err = _cli(["import", a, b, "--split-halves", "--drop-duplicate-times",
                           "--out", tmp_path / "o.h5"])
    assert code == 0, err
    assert "4 runs" in out and "2 duplicate time stamps dropped" in out


def test_time_going_back_is_never_repaired(tmp_path):
    src = _export(tmp_path / "rec.csv")
    lines = src.read_text().splitlines()
    lines[50], lines[51] = lines[51], lines[50]
    src.write_text("\n".join(lines) + "\n")
    code, _, err = _cli(["import", src, "--drop-duplicate-times", "--out", tmp_path / "o.h5"])
    assert code == 2 and "not strictly increasing" in err and err.count("\n") == 1


@pytest.mark.parametrize("fmt", ["tdms", "mat"])
def test_drop_duplicate_times_other_formats(tmp_path, fmt):
    n = 3000
    t = np.arange(n) * 0.002
    t[100] = t[99]
    x = 12.0 + 8.0 * np.sin(2 * np.pi * 0.5 * t)
    chans = {"time": t, "position": x, "force": 300.0 - 10.0 * x,
             "muscle_pressure": np.full(n, 0.4)}
    if fmt == "tdms":
        from nptdms import ChannelObject, GroupObject, TdmsWriter

        src = tmp_path / "rec.tdms"
        with TdmsWriter(src) as w:
            w.write_segment([GroupObject("g")]
                            + [ChannelObject("g", k, v) for k, v in chans.items()])
    else:
        import scipy.io

        src = tmp_path / "rec.mat"
        scipy.io.savemat(src, chans)
    code, _, err = _cli(["import", src, "--out", tmp_path / "a.h5"])
    assert code == 2 and "--drop-duplicate-times" in err
    code, out, err = _cli(["import", src, "--drop-duplicate-times", "--out", tmp_path / "b.h5"])
    assert code == 0, err
    assert "1 duplicate time stamps dropped" in out
    assert len(read_runs(tmp_path / "b.h5")[0]) == n - 1


def test_no_test_turns_a_broken_pmalab_module_into_a_skip():
    """``pytest.importorskip`` of pmalab's own modules hides a broken module as skips."""
    import re

    here = Path(__file__).parent
    hits = [f"{p.name}:{i + 1}" for p in sorted(here.glob("*.py"))
            for i, line in enumerate(p.read_text().splitlines())
            if re.search(r"importorskip\(\s*['\"]pmalab", line)]
    assert hits == []


def _rows(n: int = 5000, *, t_scale: float = 1.0, x_scale: float = 1.0, f_scale: float = 1.0,
          force=None, gap_at: int | None = None) -> str:
    t = np.arange(n) * 0.002
    if gap_at is not None:
        t[gap_at:] += 100.0
    x = 12.0 + 8.0 * np.sin(2 * np.pi * 0.5 * np.arange(n) * 0.002)
    f = 300.0 - 10.0 * x if force is None else np.full(n, force)
    return "time,position,force,muscle_pressure\n" + "\n".join(
        f"{a * t_scale:.6g},{b * x_scale:.6g},{c * f_scale:.6g},0.4" for a, b, c in zip(t, x, f))


@pytest.mark.parametrize(("text", "expect"), [
    (_rows(x_scale=1e-3) + "\n", "metres? add --units position=m"),
    (_rows(f_scale=1e-3) + "\n", "kilonewtons? add --units force=kN"),
    (_rows(t_scale=1e3) + "\n", "milliseconds? add --units time=ms"),
    (_rows(force=0.0) + "\n", "channel 'force': constant (0 N in every sample)"),
    (_rows(force=250.0) + "\n", "channel 'force': constant (250 N"),
    (_rows(gap_at=2500) + "\n", "jumps 100 s at sample 2500"),
    (_rows(n=2) + "\n", "only 2 samples: too short"),
    (_rows(n=10) + "\n", "only 10 samples: too short"),
    (_rows()[:-2], "cut off mid-number"),
    (_rows().replace("muscle_pressure\n", "force\n", 1) + "\n", "column 'force' appears 2 times"),
])
def test_unit_mixups_and_broken_exports_are_refused_with_the_fix(tmp_path, text, expect):
    src = tmp_path / "rec.csv"
    src.write_text(text)
    code, _, err = _cli(["import", src, "--out", tmp_path / "o.h5"])
    assert code == 2 and err.count("\n") == 1, err
    assert expect in err
    assert not (tmp_path / "o.h5").exists()


def test_tdms_unit_string_contradicting_the_values_is_refused(tmp_path):
    from nptdms import ChannelObject, GroupObject, TdmsWriter

    n = 3000
    t = np.arange(n) * 0.002
    x = 12.0 + 8.0 * np.sin(2 * np.pi * 0.5 * t)
    p = 0.4 + 0.01 * np.sin(2 * np.pi * 0.5 * t)  # MPa values ...
    src = tmp_path / "rec.tdms"
    with TdmsWriter(src) as w:
        w.write_segment([GroupObject("g"), ChannelObject("g", "time", t),
                         ChannelObject("g", "position", x),
                         ChannelObject("g", "force", 300.0 - 10.0 * x),
                         ChannelObject("g", "muscle_pressure", p,
                                       properties={"unit_string": "kPa"})])  # ... said kPa
    code, _, err = _cli(["import", src, "--out", tmp_path / "o.h5"])
    assert code == 2 and "channel 'muscle_pressure'" in err and "look like MPa" in err


def test_a_clean_export_without_a_final_line_end_imports(tmp_path):
    src = tmp_path / "rec.csv"
    src.write_text(_rows())  # no trailing newline, last row whole
    code, _, err = _cli(["import", src, "--out", tmp_path / "o.h5"])
    assert code == 0, err
