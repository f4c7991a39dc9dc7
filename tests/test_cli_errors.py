"""Bad input to every acquisition/rig/report verb: one line on stderr, non-zero exit, no
traceback (the quality bar), and the config-file helpers behind those lines.

Each case of ``CASES`` writes what it needs into ``tmp_path`` and runs ``pmalab`` in
process; ``{d}`` in an argument is the case's directory.
"""

from __future__ import annotations

import errno
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from pmalab.cli import main
from pmalab.config import check_keys, load_json, load_toml
from pmalab.errors import ConfigError, RunFileError
from pmalab.rig.drivers.rigfile import read_modbus_rig_file
from pmalab.runfile import Run, read_runs, write_runs

PROTOCOL = """
[[run]]
name = "a"
muscle_pressure_MPa = 0.4
frequency_Hz = 1.0
magnitude_MPa = 0.3
cycles = 1
ramp_s = 0.2
settle_s = 0.1
pressure_stable_s = 0.1
"""


def _run_file(path: Path) -> Path:
    t = np.arange(2000) * 0.002
    run = Run("a", t, 10 + 5 * np.sin(t), 500 - 20 * np.sin(t), np.full_like(t, 0.4),
              attrs={"muscle_pressure_MPa": 0.4})
    return write_runs(path, [run])


def _setup(d: Path) -> None:
    (d / "p.toml").write_text(PROTOCOL)
    (d / "notes.txt").write_text("just text\n")
    (d / "adir").mkdir()
    (d / "ok.csv").write_text("time,position,force,muscle_pressure\n0,1,2,0.3\n0.002,1,2,0.3\n")
    good = _run_file(d / "good.h5")
    data = good.read_bytes()
    (d / "trunc.h5").write_bytes(data[: len(data) // 3])
    (d / "rig_not_table.toml").write_text("rig = 3\n")
    (d / "bad.toml").write_text("[rig\nkind = 'sim'\n")


CASES = [
    # (verb args, text the one line must hold)
    (["run", "--rig", "sim", "--protocol", "{d}/p.toml", "--out", "{d}/adir", "--force"],
     "adir: is a directory"),
    (["run", "--rig", "sim", "--protocol", "{d}/p.toml", "--out", "{d}/notes.txt/o.h5"],
     "notes.txt is a file, not a directory"),
    (["run", "--rig", "sim", "--protocol", "{d}/p.toml", "--out", "{d}/o.h5", "--seed", "-3"],
     "--seed: must be an integer ≥ 0"),
    (["run", "--rig", "{d}/bad.toml", "--protocol", "{d}/p.toml", "--out", "{d}/o.h5"],
     "bad.toml: not valid TOML at line 1, column 5"),
    (["run", "--rig", "{d}/adir", "--protocol", "{d}/p.toml", "--out", "{d}/o.h5"],
     "adir: is a directory, not a rig file"),
    (["run", "--rig", "sim", "--protocol", "{d}/adir", "--out", "{d}/o.h5"],
     "adir: is a directory, not a protocol file"),
    (["import", "{d}/adir", "--out", "{d}/i.h5"], "adir: is a directory, not a CSV file"),
    (["import", "{d}/ok.csv", "--out", "{d}/i.h5", "--pressure", "-1"], "--pressure: must be"),
    (["import", "{d}/ok.csv", "--out", "{d}/adir", "--force"], "adir: is a directory"),
    (["import", "{d}/ok.csv", "--out", "{d}/notes.txt/i.h5"], "notes.txt is a file"),
    (["recover", "{d}/adir"], "adir: is a directory, not a run file"),
    (["recover", "{d}/good.h5", "--out", "{d}/adir", "--force"], "adir: is a directory"),
    (["emulate", "--rig", "{d}/rig_not_table.toml"], "rig: must be a [rig] table"),
    (["emulate", "--rig", "{d}/rig_not_table.toml", "--seed", "-1"], "--seed: must be"),
    (["report", "{d}/adir", "--out", "{d}/notes.txt/r.pdf"], "notes.txt is a file"),
]


@pytest.mark.parametrize("args, needle", CASES, ids=[" ".join(c[0][:2]) + f"-{i}"
                                                      for i, c in enumerate(CASES)])
def test_bad_input_gives_one_line_and_nonzero_exit(tmp_path, capsys, args, needle):
    _setup(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    rc = main([a.replace("{d}", str(tmp_path)) for a in args])
    err = capsys.readouterr().err
    assert rc != 0
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert needle in err, err
    # nothing half-written is left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_recover_of_a_truncated_file_fails_at_once_instead_of_hanging(tmp_path):
    """A damaged file opened in SWMR-read mode made HDF5 retry its reads forever."""
    _setup(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-m", "pmalab.cli", "recover", str(tmp_path / "trunc.h5")],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "trunc.h5: not a readable HDF5 file" in proc.stderr
    assert not (tmp_path / "trunc.h5.recovering").exists()


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, "Unable to synchronously create file (disk full)")


def test_recover_out_may_name_a_new_directory(tmp_path, capsys):
    """`recover --out new/dir/x.h5` creates the directory, like every other verb's --out."""
    good = _run_file(tmp_path / "good.h5")
    out = tmp_path / "new" / "dir" / "x.h5"
    assert main(["recover", str(good), "--out", str(out), "--force"]) == 0, capsys.readouterr()
    assert [r.name for r in read_runs(out)] == ["a"]


def test_run_on_a_full_disk_is_one_line_and_leaves_no_partial_file(tmp_path, capsys,
                                                                    monkeypatch):
    _setup(tmp_path)
    monkeypatch.setattr(h5py, "File", _disk_full)
    rc = main(["run", "--rig", "sim", "--protocol", str(tmp_path / "p.toml"), "--out",
               str(tmp_path / "o.h5"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    assert "o.h5: cannot create the run file (No space left on device)" in err
    assert not list(tmp_path.glob("o.h5*"))


def test_write_runs_on_a_full_disk_removes_the_half_written_file(tmp_path, monkeypatch):
    import pmalab.runfile as rf

    def fail(f, runs):
        raise OSError(errno.ENOSPC, "Can't write data")

    monkeypatch.setattr(rf, "_write_groups", fail)
    with pytest.raises(Exception, match=r"x\.h5: cannot write \(No space left on device\)"):
        _run_file(tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


def test_an_os_error_a_verb_does_not_name_is_still_one_line(capsys, monkeypatch):
    import pmalab.acquisition.cli as acli

    def boom(args):
        raise PermissionError(errno.EACCES, "Permission denied", "/somewhere/out.h5")

    monkeypatch.setattr(acli, "cmd_recover", boom)
    assert main(["recover", "x.h5"]) == 2
    err = capsys.readouterr().err
    assert err == "pmalab recover: error: /somewhere/out.h5: Permission denied\n"


def test_read_runs_names_a_directory(tmp_path):
    with pytest.raises(RunFileError, match="is a directory, not a run file"):
        read_runs(tmp_path)


# --------------------------------------------------------------------------- pmalab.config
def test_load_toml_names_file_line_and_column(tmp_path):
    p = tmp_path / "x.toml"
    p.write_text('a = 1\nb = "unterminated\n')
    with pytest.raises(ConfigError) as ei:
        load_toml(p, "rig file")
    msg = str(ei.value)
    assert msg.startswith(f"{p}: not valid TOML at line 2, column ") and "\n" not in msg


@pytest.mark.parametrize("content, needle", [
    (None, "x.toml: truth file not found (see --help)"),
    (b"\xff\xfe", "cannot read truth file (not UTF-8 text: byte 0 is 0xff)"),
    ("dir", "x.toml: is a directory, not a truth file"),
])
def test_read_errors_are_one_line(tmp_path, content, needle):
    p = tmp_path / "x.toml"
    if content == "dir":
        p.mkdir()
    elif content is not None:
        p.write_bytes(content)
    with pytest.raises(ConfigError) as ei:
        load_toml(p, "truth file", hint=" (see --help)")
    assert needle in str(ei.value) and "\n" not in str(ei.value)


def test_load_json_names_the_line(tmp_path):
    p = tmp_path / "r.json"
    p.write_text('{\n  "a": 1,\n  "b": \n}')
    with pytest.raises(ConfigError, match=r"r\.json: malformed JSON at line 4"):
        load_json(p, "result file")


def test_check_keys_reports_the_first_unknown_key_with_the_known_ones():
    with pytest.raises(ConfigError) as ei:
        check_keys({"a": 1, "zz": 2, "yy": 3}, {"b", "a"}, "{where}: t.{key}: unknown (known: {known})",
                   where="f.toml")
    assert str(ei.value) == "f.toml: t.zz: unknown (known: a, b)"
    check_keys({"a": 1}, {"a"}, "{key}")  # nothing unknown: no error


def test_modbus_rig_file_limits_are_validated_like_the_loader_does(tmp_path):
    from pmalab.paths import RIGS_DIR

    text = (RIGS_DIR / "labjack-t7.toml").read_text()
    p = tmp_path / "t7.toml"
    p.write_text(text.replace("[limits]", "[limits]\nmax_forse_N = 100", 1))
    with pytest.raises(ConfigError, match=r"t7\.toml: limits\.max_forse_N: unknown limit"):
        read_modbus_rig_file(p)
    p.write_text(text.replace("max_position_mm = 35.0", "max_position_mm = -10.0", 1))
    with pytest.raises(ConfigError, match=r"limits\.min_position_mm: must be < limits\.max"):
        read_modbus_rig_file(p)


@pytest.mark.parametrize("argv", [["--help"], ["identify", "--help"], ["run", "--help"]])
def test_cli_start_up_imports_no_numerical_library(argv):
    # every verb registers its options at start-up: none of them may pull numpy, h5py,
    # scipy or numba in before the chosen verb runs (`pmalab --help` stays ~0.1 s)
    code = (
        "import sys\n"
        "from pmalab.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        "heavy = sorted(m for m in ('numpy', 'h5py', 'scipy', 'numba', 'matplotlib') if m in sys.modules)\n"
        "print('HEAVY', ','.join(heavy))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1]).stdout
    assert out.strip().splitlines()[-1] == "HEAVY", out
