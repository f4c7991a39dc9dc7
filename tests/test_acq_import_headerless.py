"""Headerless exports (LabVIEW's "write to spreadsheet": tab, CRLF, numbers from line 1)
and a folder of per-pressure files imported as one campaign in one command."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest

from pmalab.cli import main as pmalab_main
from pmalab.identify.api import load


def _cli(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main(args)
    return code, out.getvalue(), err.getvalue()


def _write(path: Path, bar: float, sep: str = "\t", eol: str = "\r\n", n: int = 600) -> np.ndarray:
    t = np.arange(n) * 10.0  # ms
    x = 20.0 * np.sin(2 * np.pi * 0.5 * t / 1000.0)  # mm, elongation
    f = 100.0 + 3.0 * x + 40.0 * bar
    rows = np.column_stack([t, x / 10, np.full(n, bar / 2), f / 100, x, np.full(n, bar), f])
    path.write_text(eol.join(sep.join(f"{v:.3f}" for v in r) for r in rows) + eol)
    return rows


LAYOUT = ["--no-header", "--columns", "time,-,-,-,position,pressure,force",
          "--units", "time=ms,pressure=bar", "--negate", "position"]


@pytest.mark.parametrize("sep,typed", [("\t", "\\t"), (" ", "space"), (";", ";")])
def test_headerless_text_imports_to_the_exact_values(tmp_path, sep, typed):
    f = tmp_path / "run_3bar.txt"
    rows = _write(f, 3.0, sep=sep)
    out = tmp_path / "x.h5"
    code, _, err = _cli(["import", str(f), *LAYOUT, "--delimiter", typed, "--out", str(out)])
    assert code == 0, err
    (run,) = load(out)
    rows = np.round(rows, 3)
    np.testing.assert_allclose(run.time, rows[:, 0] / 1000, atol=1e-12, rtol=0)
    np.testing.assert_allclose(run.position, -rows[:, 4], atol=1e-12, rtol=0)
    np.testing.assert_allclose(run.force, rows[:, 6], atol=1e-12, rtol=0)
    np.testing.assert_allclose(run.muscle_pressure, rows[:, 5] / 10, rtol=1e-12)


def test_a_headerless_file_read_as_named_gets_one_line_saying_what_to_do(tmp_path):
    f = tmp_path / "labview.txt"
    _write(f, 1.0)
    code, _, err = _cli(["import", str(f), "--out", str(tmp_path / "x.h5")])
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert "first row is numbers" in err and "--no-header --delimiter '\\t'" in err
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("args,needle", [
    (["--no-header"], "--no-header: give the fields' meaning with --columns"),
    (["--columns", "time,-,force"], "--columns: no field for position"),
    (["--columns", "time,position,force,bogus"], "--columns: unknown field 'bogus'"),
    (["--columns", "t,x,f,x"], "names position twice"),
    (["--no-header", "--columns", "time,position,force", "--delimiter", "\\t"],
     "not in --columns (time, position, force); name the pressure field"),
    (["--no-header", "--columns", "time,position,force,p", "--delimiter", "\\t"],
     "7 fields but --columns names 4"),
    (["--no-header", "--columns", "time,-,-,-,position,pressure,force", "--delimiter", "\\t",
      "--pressure-from-name", "(\\d+)psi_x"], "does not match the file name"),
    (["--no-header", "--columns", "time,-,-,-,position,pressure,force", "--delimiter", "\\t",
      "--frequency", "fast"], "--frequency: 'fast' is not a number"),
])
def test_layout_mistakes_are_one_line(tmp_path, args, needle):
    f = tmp_path / "r_2bar.txt"
    _write(f, 2.0)
    code, _, err = _cli(["import", str(f), *args, "--out", str(tmp_path / "x.h5")])
    assert code == 2, err
    assert needle in err and err.count("\n") == 1, err
    assert not (tmp_path / "x.h5").exists()


def test_a_folder_of_pressures_becomes_one_campaign_split_in_halves(tmp_path):
    files = []
    for bar in (1, 3, 5):
        f = tmp_path / f"muscle_{bar}bar.txt"
        _write(f, float(bar))
        files.append(str(f))
    out = tmp_path / "campaign.h5"
    code, text, err = _cli(["import", *files, *LAYOUT, "--delimiter", "\\t",
                            "--pressure-from-name", r"(\d+)bar", "--split-halves",
                            "--frequency", "auto", "--out", str(out)])
    assert code == 0, err
    assert "6 runs from 3 file(s)" in text and "3 held out for validation" in text
    runs = load(out)
    assert [r.name for r in runs] == [f"muscle_{b}bar-{h}" for b in (1, 3, 5) for h in "ab"]
    for r in runs:
        assert r.attrs["role"] == ("identification" if r.name.endswith("-a") else "validation")
        assert r.frequency == pytest.approx(0.5, rel=0.02)  # read off the position
    assert runs[2].nominal_pressure == pytest.approx(0.3)
    assert sum(len(r) for r in runs) == 3 * 600  # every sample in exactly one half


def test_a_bad_last_file_leaves_no_campaign_behind(tmp_path):
    good = tmp_path / "a_1bar.txt"
    _write(good, 1.0)
    bad = tmp_path / "b_3bar.txt"
    rows = _write(bad, 3.0).copy()
    text = bad.read_text().splitlines()
    text[300] = text[300].replace(text[300].split("\t")[6], "overload")
    bad.write_text("\r\n".join(text) + "\r\n")
    out = tmp_path / "campaign.h5"
    code, _, err = _cli(["import", str(good), str(bad), *LAYOUT, "--delimiter", "\\t",
                         "--pressure-from-name", r"(\d+)bar", "--out", str(out)])
    assert code == 2 and "b_3bar.txt" in err and "row 301" in err and "'overload'" in err, err
    assert not out.exists()
    assert rows.shape == (600, 7)
