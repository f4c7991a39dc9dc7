"""What the run-file reader refuses or leaves out before anything is fitted: aborted and
interrupted runs, implausible values (with the unit they probably are in), a reversed
steady window, a file given twice; and what a failed command leaves behind (nothing)."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
from identify_synth import make_run

from pmalab.cli import main
from pmalab.errors import RunFileError, RunFileWarning
from pmalab.identify.api import load
from pmalab.runfile import (
    Run,
    check_distinct,
    likely_unit,
    normalize_unit,
    read_many,
    read_runs,
    run_state,
    write_runs,
)

REPO = Path(__file__).resolve().parent.parent


def _run(name: str, status: str | None = None, **attrs) -> Run:
    t = np.arange(1000) * 0.002
    a = {"muscle_pressure_MPa": 0.4, **attrs}
    if status is not None:
        a["status"] = status
    return Run(name, t, 10 + 5 * np.sin(t), 500 - 20 * np.sin(t), np.full_like(t, 0.4), attrs=a)


# --------------------------------------------------------------------------- item 2
@pytest.mark.parametrize("status, state", [
    (None, "completed"), ("completed", "completed"), ("aborted: interrupted (Ctrl-C)", "aborted"),
    ("aborted: recording interrupted (writer killed; recovered)", "aborted"),
    ("running", "interrupted"), ("pending", "not run"), ("not run: campaign aborted", "not run"),
])
def test_run_state_reads_the_recorded_status(status, state):
    assert run_state(status) == state


def test_analysis_skips_aborted_runs_with_one_warning_each(tmp_path):
    f = write_runs(tmp_path / "mixed.h5", [
        _run("ok"), _run("cut", "aborted: limit tripped: force 1600 N > 1500 N"),
        _run("killed", "running")])
    # the raw reader gives what the file holds (write_runs stores runs alphabetically)
    assert [r.name for r in read_runs(f)] == ["cut", "killed", "ok"]
    with pytest.warns(RunFileWarning) as rec:
        runs = read_many([f])
    assert [r.name for r in runs] == ["ok"]
    msgs = [str(w.message) for w in rec]
    assert len(msgs) == 2
    assert f"{f}: run 'cut' skipped: aborted: limit tripped" in msgs[0]
    assert "run 'killed' skipped: interrupted (its recording was killed" in msgs[1]
    assert all("--include-aborted" in m and "\n" not in m for m in msgs)
    # explicitly included: all of them, no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(read_many([f], include_aborted=True)) == 3
        assert len(load(f, include_aborted=True)) == 3
        assert [r.name for r in load(f, runs=["cut"])] == ["cut"]  # named: included
    with pytest.warns(RunFileWarning):
        assert [r.name for r in load(f)] == ["ok"]


def test_a_file_of_aborted_runs_only_is_one_error_line(tmp_path, capsys):
    f = write_runs(tmp_path / "frag.h5", [_run("settle", "aborted: terminated (SIGTERM)")])
    rc = main(["identify", str(f), "--model", "duhem", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1, err
    assert (f"{f}: no complete run (run 'settle' aborted: terminated (SIGTERM)); "
            "--include-aborted uses it anyway") in err
    assert not (tmp_path / "o").exists()


def test_identify_cli_prints_the_skip_warning_and_fits_the_rest(tmp_path, capsys):
    runs = []
    for i, p in enumerate((0.2, 0.4, 0.6)):
        r, _ = make_run("duhem", p, seed=i, n=2000, f=0.5, name=f"p{i}")
        runs.append(r)
    frag, _ = make_run("duhem", 0.5, seed=5, n=400, f=0.5, name="frag")
    frag.attrs["status"] = "aborted: interrupted (Ctrl-C)"
    f = write_runs(tmp_path / "c.h5", [*runs, frag])
    rc = main(["identify", str(f), "--model", "duhem", "--out", str(tmp_path / "o"),
               "--jobs", "1"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert (f"pmalab identify: warning: {f}: run 'frag' skipped: aborted: interrupted "
            "(Ctrl-C)") in err
    assert "frag" not in out and out.count("  identify  ") == 3


KILLED = """
import os, sys
import numpy as np
from pmalab.acquisition.recorder import Recorder
rec = Recorder(sys.argv[1], [("a", {"muscle_pressure_MPa": 0.4}), ("b", {})], {})
w = rec.writer("a")
w.set_status("running")
for i in range(300):
    w.add(i * 0.002, 10.0, 400.0, 0.4, 0.1, 0.1, 0.0)
w.commit()
os._exit(0)  # like kill -9: the file keeps its SWMR "open for write" flag
"""


def test_an_interrupted_file_names_recover_and_h5clear(tmp_path):
    out = tmp_path / "killed.h5"
    subprocess.run([sys.executable, "-c", KILLED, str(out)], check=True, cwd=REPO,
                   env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=120)
    with pytest.raises(OSError):
        h5py.File(out, "r")  # what h5dump/HDFView meet
    with pytest.raises(RunFileError) as ei:
        read_many([out])
    msg = str(ei.value)
    assert "run 'a' interrupted (its recording was killed mid-run)" in msg
    assert f"h5dump/HDFView cannot open this file until 'pmalab recover {out}'" in msg
    assert f"'h5clear -s {out}'" in msg
    with pytest.warns(RunFileWarning, match="did not close the file .*pmalab recover"):
        (r,) = read_runs(out)  # readers keep working as today (and still say what opens it)
    assert len(r) == 300 and r.state == "interrupted"
    assert main(["recover", str(out)]) == 0
    with h5py.File(out, "r"):
        pass


KILLED_BETWEEN_RUNS = """
import os, sys
from pmalab.acquisition.recorder import Recorder
rec = Recorder(sys.argv[1], [("a", {"muscle_pressure_MPa": 0.4}), ("b", {})], {})
w = rec.writer("a")
w.set_status("running")
for i in range(300):
    w.add(i * 0.002, 10.0, 400.0, 0.4, 0.1, 0.1, 0.0)
w.finish("completed")
os._exit(0)  # killed while run 'b' waited for its pressure: no run is cut mid-recording
"""


def test_a_file_killed_between_runs_still_names_recover(tmp_path):
    """No cut run carries the recover hint, yet h5dump cannot open the file: one warning
    says so and names the runs never recorded."""
    out = tmp_path / "between.h5"
    subprocess.run([sys.executable, "-c", KILLED_BETWEEN_RUNS, str(out)], check=True, cwd=REPO,
                   env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=120)
    with pytest.warns(RunFileWarning) as rec:
        (r,) = read_many([out])
    assert r.name == "a" and len(r) == 300
    (msg,) = [str(w.message) for w in rec]
    assert msg == (f"{out}: its recording did not close the file (killed, or still running) (1 run(s) "
                   f"never recorded: b); h5dump/HDFView cannot open this file until "
                   f"'pmalab recover {out}' (or 'h5clear -s {out}')")
    assert main(["recover", str(out)]) == 0
    with warnings.catch_warnings():  # a recovered file reads without a word
        warnings.simplefilter("error")
        assert [r.name for r in read_many([out])] == ["a"]


# --------------------------------------------------------------------------- item 4
@pytest.mark.parametrize("channel, values, units, likely", [
    ("muscle_pressure", np.full(50, 400.0), "MPa", "kPa"),
    ("muscle_pressure", np.full(50, 4.5), "MPa", "bar"),
    ("position", np.linspace(5000, 25000, 50), "mm", "um"),
    ("force", np.linspace(200, 800, 50), "kN", "N"),
])
def test_implausible_values_are_refused_with_the_likely_unit(tmp_path, channel, values, units,
                                                             likely):
    assert likely_unit(channel, values) == likely
    r = _run("r")
    setattr(r, channel, np.resize(values, len(r)))
    f = write_runs(tmp_path / "x.h5", [r])
    with h5py.File(f, "a") as h:
        h[f"runs/r/{channel}"].attrs["units"] = units
        del h["runs/r"].attrs["attrs_sha256"]  # edited by another tool: no digest
    with pytest.raises(RunFileError) as ei:
        read_runs(f)
    msg = str(ei.value)
    assert msg.startswith(f"{f}: run 'r': channel '{channel}': reaches ")
    assert f"looks like {likely}: its 'units' attribute says '{units}'" in msg


@pytest.mark.parametrize("channel, value", [("muscle_pressure", -0.2), ("force", -25e3),
                                            ("position", 600.0), ("muscle_pressure", 1.3)])
def test_each_limit_is_enforced(tmp_path, channel, value):
    r = _run("r")
    getattr(r, channel)[100] = value
    f = write_runs(tmp_path / "x.h5", [r])
    with pytest.raises(RunFileError, match=rf"channel '{channel}': reaches .* at sample 100"):
        read_runs(f)


def test_an_aborted_run_keeps_the_implausible_reading_that_tripped_it(tmp_path):
    """A disconnected 4-20 mA gauge reads -0.25 MPa: the runner trips and keeps that sample
    as the run's last; the file must stay readable (the rest of the run is still checked)."""
    r = _run("r", "aborted: muscle pressure -0.250 MPa below the limit at t=1.998 s")
    r.muscle_pressure[-1] = -0.25
    f = write_runs(tmp_path / "trip.h5", [r])
    (back,) = read_runs(f)
    assert back.muscle_pressure[-1] == -0.25 and back.state == "aborted"
    r.muscle_pressure[-2] = -0.25
    with pytest.raises(RunFileError, match="at sample 998"):
        read_runs(write_runs(tmp_path / "two.h5", [r]))
    r = _run("r")  # a completed run has no such excuse
    r.muscle_pressure[-1] = -0.25
    with pytest.raises(RunFileError, match="at sample 999"):
        read_runs(write_runs(tmp_path / "done.h5", [r]))


def test_values_within_noise_of_the_limits_pass(tmp_path):
    r = _run("r")
    r.muscle_pressure[:10] = -0.01  # a gauge's zero offset at vent
    r.cylinder_pressure = np.full(len(r), 0.9)
    r.force[5:15] = -19e3  # a stretch, not a one-sample spike (channel health refuses those)
    (back,) = read_runs(write_runs(tmp_path / "x.h5", [r]))
    assert back.muscle_pressure.min() == -0.01


@pytest.mark.parametrize("text, unit", [
    ("mm", "mm"), ("[mm]", "mm"), ("(mm)", "mm"), (" [ mm ] ", "mm"), ("\u00b5m", "µm"),
    ("\u03bcm", "um"), ("um", "um"), ("[µm]", "µm"), ("micron", "um"), ("MM", "mm"),
])
def test_units_written_like_exports_are_understood(text, unit):
    assert normalize_unit("position", text) == unit


def test_pressure_and_time_spellings():
    assert normalize_unit("muscle_pressure", "kpa") == "kPa"
    assert normalize_unit("muscle_pressure", "[bar]") == "bar"
    assert normalize_unit("force", "KN") == "kN"
    assert normalize_unit("time", "sec") == "s"
    assert normalize_unit("time", "(ms)") == "ms"
    assert normalize_unit("force", "lbf") is None


# --------------------------------------------------------------------------- item 5
def test_a_reversed_steady_window_is_refused(tmp_path):
    f = write_runs(tmp_path / "w.h5", [_run("r", steady_start_s=1.5, steady_end_s=0.5)])
    with pytest.raises(RunFileError) as ei:
        read_runs(f)
    assert str(ei.value) == (f"{f}: run 'r': field 'steady_end_s' = 0.5 s is not after "
                             "'steady_start_s' = 1.5 s (a reversed window)")


@pytest.mark.parametrize("attrs, needle", [
    ({"steady_start_s": 0.2}, "field 'steady_end_s' missing"),
    ({"steady_start_s": -1.0, "steady_end_s": 1.0}, "field 'steady_start_s' = -1.0: must be"),
    ({"steady_start_s": 50.0, "steady_end_s": 60.0}, "beyond the run's end"),
])
def test_other_bad_windows_are_refused(tmp_path, attrs, needle):
    f = write_runs(tmp_path / "w.h5", [_run("r", **attrs)])
    with pytest.raises(RunFileError, match=needle):
        read_runs(f)


def test_the_same_file_twice_is_refused(tmp_path):
    f = write_runs(tmp_path / "a.h5", [_run("r")])
    link = tmp_path / "alias.h5"
    link.symlink_to(f)
    with pytest.raises(RunFileError, match=r"a\.h5: file given twice: use each file once"):
        read_many([f, f])
    with pytest.raises(RunFileError, match=r"alias\.h5: file given twice \(the same file as "):
        load(f, link)
    with pytest.raises(RunFileError, match="given both as input and to --validate"):
        check_distinct([f], [link])
    check_distinct([f], [])  # once is fine


def test_a_copied_file_is_the_same_recording(tmp_path):
    f = write_runs(tmp_path / "a.h5", [_run("r")])
    copy = tmp_path / "b.h5"
    copy.write_bytes(f.read_bytes())
    with pytest.raises(RunFileError) as ei:
        read_many([f, copy])
    assert str(ei.value) == (f"{copy}: run 'r': the same recording as a.h5:r (a copy of one "
                             "file?): use each recording once")
    other = _run("r")
    other.force[3] += 0.5  # one sample differs: another recording
    assert len(read_many([f, write_runs(tmp_path / "c.h5", [other])])) == 2


def test_identify_refuses_a_file_given_twice_and_leaves_no_directory(tmp_path, capsys):
    f = write_runs(tmp_path / "a.h5", [_run("r")])
    out = tmp_path / "new" / "deeper"
    rc = main(["identify", str(f), str(f), "--model", "duhem", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "file given twice" in err
    assert not (tmp_path / "new").exists()


def test_recover_leaves_a_healthy_file_alone(tmp_path, capsys):
    f = write_runs(tmp_path / "ok.h5", [_run("r")])
    before = (f.read_bytes(), f.stat().st_mtime_ns)
    assert main(["recover", str(f)]) == 0
    assert "nothing to recover" in capsys.readouterr().out
    assert (f.read_bytes(), f.stat().st_mtime_ns) == before
    assert main(["recover", str(f), "--out", str(tmp_path / "copy.h5")]) == 0
    assert not (tmp_path / "copy.h5").exists()
    assert main(["recover", str(f), "--force"]) == 0  # rewritten on request
    assert "closed" in capsys.readouterr().out
    assert len(read_runs(f)[0]) == 1000


def test_recover_still_marks_a_cleared_but_cut_run(tmp_path, capsys):
    """A file whose flag was cleared by h5clear still holds a run with status 'running'."""
    f = write_runs(tmp_path / "cut.h5", [_run("r")])
    with h5py.File(f, "a") as h:
        h["runs/r"].create_dataset("status", data=np.bytes_(b"running"), dtype="S256")
    assert main(["recover", str(f)]) == 0
    assert "marked aborted: r" in capsys.readouterr().out
    assert read_runs(f)[0].state == "aborted"


def test_an_unclosable_recording_says_how_to_open_it_elsewhere(tmp_path, capsys, monkeypatch):
    """When the run file could not be closed (a full disk), the process ends with os._exit
    and the file keeps its "open for write" flag: the abort line says what opens it."""
    import pmalab.acquisition.runner as runner
    import pmalab.cli as cli
    from pmalab.errors import SafetyAbort

    out = tmp_path / "o.h5"

    def fake_run(rig, protocol, path, **kw):
        Path(path).write_bytes(b"kept")
        exc = SafetyAbort(f"{path}: run 'a' aborted: exception: disk full; the file could not "
                          "be finished")
        exc.hard_exit = True
        raise exc

    def fake_exit(code):
        raise SystemExit(code)

    monkeypatch.setattr(runner, "run_protocol", fake_run)
    monkeypatch.setattr(cli.os, "_exit", fake_exit)
    with pytest.raises(SystemExit) as ei:
        main(["run", "--rig", "sim", "--protocol", "quick", "--out", str(out), "--quiet"])
    assert ei.value.code == 4
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"h5dump/HDFView cannot open this file until 'pmalab recover {out}'" in err
