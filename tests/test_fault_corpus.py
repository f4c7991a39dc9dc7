"""The fault corpus: bad inputs (CSV, HDF5, TOML, command-line arguments), one line each.

Every case runs ``pmalab`` (in process: the same ``main`` the console script calls; one
test below checks that a subprocess says the same) in a fresh copy of the corpus
directory and asserts the quality bar: exit ≠ 0, exactly one line on stderr, no traceback,
the line names the file/run/channel/field at fault, and nothing was overwritten or left
behind (every file byte-identical, no new file or directory — not even an empty ``--out``).

``{d}`` in an argument is the case's directory.  Adding a case is adding one line.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from pmalab.cli import main
from pmalab.runfile import Run, write_runs

REPO = Path(__file__).resolve().parent.parent

# ---------------------------------------------------------------------------- the inputs
PROTOCOL = """
[[run]]
name = "a"
muscle_pressure_MPa = {p}
frequency_Hz = 1.0
magnitude_MPa = 0.3
cycles = 1
ramp_s = 0.2
settle_s = 0.1
pressure_stable_s = 0.1
{extra}
"""
GOOD_CSV_HEAD = "time,position,force,muscle_pressure\n"


def _run(name: str = "r", n: int = 2000, **attrs) -> Run:
    t = np.arange(n) * 0.002
    return Run(name, t, 12 + 5 * np.sin(t), 500 - 20 * np.sin(t), np.full(n, 0.4),
               attrs={"muscle_pressure_MPa": 0.4, **attrs})


def _csv(rows: int = 300, p_scale: float = 1.0, x_scale: float = 1.0, p_off: float = 0.0):
    t = np.arange(rows) * 0.002
    lines = [f"{a:.3f},{(12 + 5 * np.sin(a)) * x_scale:.4f},{500 - 20 * np.sin(a):.3f},"
             f"{0.4 * p_scale + p_off:.4f}" for a in t]
    return GOOD_CSV_HEAD + "\n".join(lines) + "\n"


def _h5_edit(path: Path, fn) -> None:
    with h5py.File(path, "a") as f:
        fn(f)
        for g in f["runs"].values() if isinstance(f.get("runs"), h5py.Group) else ():
            g.attrs.pop("attrs_sha256", None)  # edited by another tool: no digest


def build_corpus(d: Path) -> None:
    """Write every input of the corpus into ``d`` (once per module)."""
    good = write_runs(d / "good.h5", [_run()])
    write_runs(d / "other.h5", [_run("o")])
    data = good.read_bytes()
    (d / "copy.h5").write_bytes(data)
    (d / "trunc.h5").write_bytes(data[: len(data) // 3])
    with h5py.File(d / "foreign.h5", "w") as f:
        f["x"] = np.arange(3)
    write_runs(d / "kpa.h5", [_run()])
    _h5_edit(d / "kpa.h5", lambda f: f["runs/r/muscle_pressure"].__setitem__(
        slice(None), 400.0))
    write_runs(d / "um.h5", [_run()])
    _h5_edit(d / "um.h5", lambda f: f["runs/r/position"].__setitem__(slice(None), 15000.0))
    write_runs(d / "aborted.h5", [_run("settle", status="aborted: terminated (SIGTERM)")])
    write_runs(d / "reversed.h5", [_run(steady_start_s=3.0, steady_end_s=1.0)])
    nan = _run()
    nan.force[700] = np.nan
    write_runs(d / "nan.h5", [nan])
    write_runs(d / "noforce.h5", [_run()])
    _h5_edit(d / "noforce.h5", lambda f: f["runs/r"].__delitem__("force"))
    write_runs(d / "furlong.h5", [_run()])
    _h5_edit(d / "furlong.h5", lambda f: f["runs/r/position"].attrs.__setitem__("units",
                                                                                  "furlong"))
    shortr = _run()
    write_runs(d / "short.h5", [shortr])
    _h5_edit(d / "short.h5", lambda f: (f["runs/r"].__delitem__("time"),
                                        f["runs/r"].create_dataset("time", data=shortr.time[:10])
                                        .attrs.__setitem__("units", "s")))
    (d / "done").mkdir()
    (d / "done" / "identification.json").write_text('{"model": "duhem"}\n')
    (d / "emptydir").mkdir()

    (d / "kpa.csv").write_text(_csv(p_scale=1e3))
    (d / "um.csv").write_text(_csv(x_scale=1e3))
    (d / "negp.csv").write_text(_csv(p_off=-0.5))
    (d / "empty.csv").write_text("")
    (d / "comma.csv").write_text(_csv().replace(",", ";").replace(".", ","))
    (d / "units.csv").write_text(_csv().replace(GOOD_CSV_HEAD, GOOD_CSV_HEAD
                                                + "[s],[mm],[N],[MPa]\n"))
    (d / "ansi.csv").write_bytes(_csv().replace(GOOD_CSV_HEAD, GOOD_CSV_HEAD.replace(
        "position", "position \u00b5m")).encode("cp1252"))
    lines = _csv().splitlines()
    lines[40] += ",7"
    (d / "ragged.csv").write_text("\n".join(lines) + "\n")
    (d / "good.csv").write_text(_csv())

    (d / "unknown_key.toml").write_text(PROTOCOL.format(p=0.4, extra="frequncy = 2"))
    (d / "too_high.toml").write_text(PROTOCOL.format(p=0.9, extra=""))
    (d / "broken.toml").write_text("[[run]\nname = 'a'\n")
    (d / "rig_kind.toml").write_text("[rig]\nkind = 'warp-drive'\n")
    (d / "p.toml").write_text(PROTOCOL.format(p=0.4, extra=""))


# ------------------------------------------------------------------------------ the table
ID = ["--model", "duhem", "--out", "{d}/new/id"]
DG = ["--model", "duhem", "--out", "{d}/new/dg"]
CASES = [
    # (pmalab arguments, text the one stderr line must hold)
    # --- HDF5 run files given to identify / diagnose
    (["identify", "{d}/kpa.h5", *ID], "kpa.h5: run 'r': channel 'muscle_pressure': reaches 400 "
     "MPa at sample 0, which no PMA test produces (gauge pressure between -0.05 and 1.2 MPa) — "
     "looks like kPa: its 'units' attribute says 'MPa'"),
    (["diagnose", "{d}/um.h5", *DG], "um.h5: run 'r': channel 'position': reaches 1.5e+04 mm"),
    (["identify", "{d}/aborted.h5", *ID], "aborted.h5: no complete run (run 'settle' aborted: "
     "terminated (SIGTERM)); --include-aborted uses it anyway"),
    (["identify", "{d}/reversed.h5", *ID], "reversed.h5: run 'r': field 'steady_end_s' = 1 s is "
     "not after 'steady_start_s' = 3 s (a reversed window)"),
    (["identify", "{d}/good.h5", "{d}/good.h5", *ID], "good.h5: file given twice"),
    (["diagnose", "{d}/good.h5", "--validate", "{d}/good.h5", *DG],
     "good.h5: file given both as input and to --validate"),
    (["identify", "{d}/good.h5", "--validate", "{d}/copy.h5", *ID],
     "copy.h5: run 'r': the same recording as good.h5:r (a copy of one file?)"),
    (["identify", "{d}/nan.h5", *ID], "nan.h5: run 'r': channel 'force': NaN or infinite value "
     "at sample 700"),
    (["identify", "{d}/noforce.h5", *ID], "noforce.h5: run 'r': channel 'force': missing channel"),
    (["identify", "{d}/furlong.h5", *ID], "furlong.h5: run 'r': channel 'position': unknown "
     "unit 'furlong'"),
    (["identify", "{d}/short.h5", *ID], "short.h5: run 'r': channel 'time': channels have "
     "unequal lengths"),
    (["identify", "{d}/trunc.h5", *ID], "trunc.h5: not a readable HDF5 file"),
    (["identify", "{d}/good.csv", *ID], "(file signature not found)); it is text: a CSV "
     "export? convert it with 'pmalab import {d}/good.csv --out RUN.h5'"),
    (["diagnose", "{d}/foreign.h5", *DG], "foreign.h5: not a pmalab run file"),
    (["identify", "{d}/missing.h5", *ID], "missing.h5: no such file"),
    (["identify", "{d}/good.h5", "--model", "duhem", "--out", "{d}/done"],
     "done/identification.json: already exists (use --force to overwrite)"),
    (["identify", "{d}/good.h5", "--jobs", "0", *ID], "--jobs 0: must be at least 1"),
    (["identify", "{d}/good.h5", "--fix", "k", *ID], "--fix 'k': expected NAME=VALUE"),
    (["recover", "{d}/foreign.h5"], "foreign.h5: not a pmalab run file"),
    (["recover", "{d}/good.h5", "--out", "{d}/other.h5", "--force"], None),  # see below
    # --- CSV imports
    (["import", "{d}/kpa.csv", "--out", "{d}/new/k.h5"], "kpa.csv: run 'kpa': channel "
     "'muscle_pressure': reaches 400 MPa at sample 0, which no PMA test produces (gauge "
     "pressure between -0.05 and 1.2 MPa) — looks like kPa: use --units muscle_pressure=kPa"),
    (["import", "{d}/um.csv", "--out", "{d}/new/u.h5"], "um.csv: run 'um': channel 'position': "
     "reaches 1.481e+04 mm at sample 299, which no PMA test produces (|position| ≤ 500 mm) — "
     "looks like um: use --units position=um"),
    (["import", "{d}/good.csv", "--out", "{d}/new/u.h5", "--units", "force=kN"],
     "good.csv: run 'good': channel 'force': reaches 5e+05 N at sample 0, which no PMA test "
     "produces (|force| ≤ 20 kN) — looks like N: use --units force=N"),
    (["import", "{d}/negp.csv", "--out", "{d}/new/n.h5"], "negp.csv: run 'negp': channel "
     "'muscle_pressure': reaches -0.1 MPa at sample 0"),
    (["import", "{d}/empty.csv", "--out", "{d}/new/e.h5"], "empty.csv: --header-rows 0: the "
     "file has only 0 line(s)"),
    (["import", "{d}/comma.csv", "--out", "{d}/new/c.h5", "--delimiter", ";"],
     "comma.csv: run 'comma': channel 'time': column 'time' row 2 is not a number ('0,000'): a "
     "decimal comma? use --decimal ,"),
    (["import", "{d}/units.csv", "--out", "{d}/new/c.h5"], "units.csv: run 'units': channel "
     "'time': column 'time' row 2 is not a number ('[s]'): a units row? use --units-row"),
    (["import", "{d}/ansi.csv", "--out", "{d}/new/a.h5"], "ansi.csv: line 1: not utf-8 text "
     "(byte 0xb5); give --encoding (cp1252 for most Windows exports)"),
    (["import", "{d}/ragged.csv", "--out", "{d}/new/r.h5"], "ragged.csv: line 41: 5 fields "
     "where the rows before have 4; wrong --delimiter or --header-rows?"),
    (["import", "{d}/good.csv", "--out", "{d}/new/g.h5", "--delimiter", "\\t"],
     "good.csv: run 'good': channel 'time': no column 'time' (columns: "
     "time,position,force,muscle_pressure); the names are separated by ',': use "
     "--delimiter ','"),
    (["import", "{d}/comma.csv", "--out", "{d}/new/c.h5", "--decimal", "."],
     "comma.csv: run 'comma': channel 'time': no column 'time' (columns: "
     "time;position;force;muscle_pressure); the names are separated by ';': use "
     "--delimiter ';'"),
    (["import", "{d}/good.csv", "--out", "{d}/new/g.h5", "--delimiter", "ab"],
     "--delimiter: 'ab' is not one character"),
    (["import", "{d}/good.csv", "--out", "{d}/new/g.h5", "--encoding", "klingon"],
     "--encoding: unknown encoding 'klingon'"),
    (["import", "{d}/good.csv", "--out", "{d}/new/g.h5", "--header-rows", "-2"],
     "--header-rows: must be ≥ 0, got -2"),
    (["import", "{d}/good.csv", "--out", "{d}/good.h5"], "good.h5: already exists (use --force"),
    (["import", "{d}/good.csv", "--out", "{d}/good.csv", "--force"],
     "good.csv: is the input CSV itself (--force would replace your data"),
    (["import", "{d}/good.csv", "--out", "{d}/new/g.h5", "--decimal", ";"],
     "pmalab import: error: argument --decimal: invalid choice: ';'"),
    (["identify", "{d}/good.h5", "--out", "{d}/new/id"],
     "pmalab identify: error: the following arguments are required: --model (see pmalab "
     "identify --help)"),
    (["diagnose", "{d}/good.h5", *DG, "--jobs", "two"],
     "argument --jobs: invalid int value: 'two'"),
    # an option the verb does not have: the verb's --help, not pmalab's
    (["diagnose", "{d}/good.h5", *DG, "--free", "n"],
     "pmalab diagnose: error: unrecognized arguments: --free n (see pmalab diagnose --help)"),
    # --- TOML protocol and rig files
    (["run", "--rig", "sim", "--protocol", "{d}/unknown_key.toml", "--out", "{d}/new/o.h5"],
     "unknown_key.toml: run[0] 'a': unknown field 'frequncy'"),
    (["run", "--rig", "sim", "--protocol", "{d}/too_high.toml", "--out", "{d}/new/o.h5"],
     "too_high.toml: run 'a': refused"),
    (["run", "--rig", "sim", "--protocol", "{d}/broken.toml", "--out", "{d}/new/o.h5"],
     "broken.toml: not valid TOML at line 1"),
    (["run", "--rig", "{d}/rig_kind.toml", "--protocol", "{d}/p.toml", "--out", "{d}/new/o.h5"],
     "rig_kind.toml: rig.kind"),
    (["run", "--rig", "sim", "--protocol", "{d}/p.toml", "--out", "{d}/good.h5"],
     "good.h5: already exists (use --force to overwrite)"),
    # --- reports of result directories
    (["report", "{d}/emptydir", "--out", "{d}/new/r.pdf"], "emptydir"),
    (["report", "{d}/done", "--out", "{d}/new/r.pdf", "--png", "{d}/new/png"],
     "done/identification.json"),
]
CASES = [c for c in CASES if c[1] is not None]


def _snapshot(d: Path) -> dict[str, str]:
    """Every file and directory below ``d``: its content hash (or "dir")."""
    out = {}
    for p in sorted(d.rglob("*")):
        rel = str(p.relative_to(d))
        out[rel] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("corpus")
    build_corpus(d)
    return d


def _case_dir(corpus: Path, tmp_path: Path) -> Path:
    d = tmp_path / "c"
    shutil.copytree(corpus, d)
    return d


@pytest.mark.parametrize("args, needle", CASES,
                         ids=[f"{i:02d}-{c[0][0]}-{Path(c[0][1]).name}" for i, c in
                              enumerate(CASES)])
def test_bad_input_is_one_line_and_leaves_everything_as_it_was(corpus, tmp_path, capsys,
                                                                args, needle):
    d = _case_dir(corpus, tmp_path)
    before = _snapshot(d)
    rc = main([a.replace("{d}", str(d)) for a in args])
    err = capsys.readouterr().err
    assert rc != 0
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert needle.replace("{d}", str(d)) in err, err
    assert _snapshot(d) == before  # nothing overwritten, nothing (not even a dir) left behind


def test_the_corpus_holds_at_least_20_cases_and_every_kind_of_input():
    kinds = {"h5": 0, "csv": 0, "toml": 0}
    for args, _ in CASES:
        inputs = [a.rsplit(".", 1)[-1] for a in args if a.startswith("{d}/")]
        kind = next((k for k in inputs if k in kinds), None)
        if kind is not None:
            kinds[kind] += 1
    assert len(CASES) >= 20 and all(n >= 4 for n in kinds.values()), kinds


@pytest.mark.parametrize("verb, source", [("identify", "{d}/kpa.h5"), ("import", "{d}/kpa.csv")])
def test_a_subprocess_says_the_same_as_in_process(corpus, tmp_path, capsys, verb, source):
    """In-process ``main`` is faithful: the console entry point prints the same line."""
    args = next(a for a, _ in CASES if a[:2] == [verb, source])
    d = _case_dir(corpus, tmp_path)
    argv = [a.replace("{d}", str(d)) for a in args]
    rc = main(argv)
    err = capsys.readouterr().err
    proc = subprocess.run([sys.executable, "-m", "pmalab.cli", *argv], capture_output=True,
                          text=True, timeout=120, cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert (proc.returncode, proc.stderr) == (rc, err)
