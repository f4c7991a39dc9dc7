"""``pmalab run`` end to end on the simulated rig: contract file, physical loop direction,
provenance, --force, one-line errors and non-zero exits."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from pmalab.cli import main
from pmalab.errors import SafetyAbort
from pmalab.paths import PROTOCOLS_DIR
from pmalab.rig import sim as _sim  # noqa: F401 - a broken simulator fails here, never skips
from pmalab.runfile import FORMAT, decode_attr, read_runs


def _loop_direction(r) -> tuple[float, float]:
    """(mean tension stretching − contracting at mid-stroke (N), corr(x, F)) in the steady
    window.  Physical: positive friction gap (tension higher while the muscle is being
    stretched, x decreasing) and tension falling with contraction (negative correlation)."""
    s = (r.time >= r.attrs["steady_start_s"]) & (r.time <= r.attrs["steady_end_s"])
    x, f = r.position[s], r.force[s]
    # velocity from a centred difference over 50 samples (0.1 s): noise-robust at < 1 Hz
    v = np.zeros_like(x)
    v[25:-25] = x[50:] - x[:-50]
    lo, hi = np.percentile(x, [30, 70])
    mid = (x > lo) & (x < hi)
    gap = f[mid & (v < 0)].mean() - f[mid & (v > 0)].mean()
    return float(gap), float(np.corrcoef(x, f)[0, 1])


def test_run_seed_bouc_wen_end_to_end(tmp_path, capsys):
    out = tmp_path / "x.h5"
    rc = main(["run", "--rig", "sim", "--protocol", str(PROTOCOLS_DIR / "seed-bouc-wen.toml"),
               "--out", str(out)])
    assert rc == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 11 and "ident-476kPa: completed" in lines[0] and "force" in lines[0]
    assert lines[-2] == f"{out}: 9 runs, {sum(len(r) for r in read_runs(out))} samples"
    assert lines[-1] == ("regulators: cylinder regulator vented (confirmed: simulated regulator "
                         "commanded to 0 MPa); muscle regulator vented (confirmed: simulated "
                         "regulator commanded to 0 MPa)")
    runs = read_runs(out)
    assert len(runs) == 9
    with h5py.File(out, "r") as f:  # closed cleanly: plain open works; provenance present
        assert decode_attr(f.attrs["format"]) == FORMAT  # fixed-length UTF-8 text
        for key in ("protocol_text", "rig", "calibration", "software_version", "created_utc",
                    "limits", "command_line"):
            assert key in f.attrs, key
        assert json.loads(f.attrs["rig"])["kind"] == "sim"
    roles = {r.name: r.attrs["role"] for r in runs}
    assert roles["ident-476kPa"] == "identification"
    assert roles["valid-304kPa-0.3Hz"] == "validation"
    for r in runs:
        assert r.attrs["status"] == "completed"
        assert r.attrs["sample_rate_Hz"] == 500.0 and r.attrs["waveform"] == "sine"
        assert r.attrs["protocol"]["muscle_pressure_MPa"] == r.attrs["muscle_pressure_MPa"]
        assert r.attrs["timing"]["missed"] == 0
        # isobaric: the measured muscle pressure sits on the nominal one
        p = r.muscle_pressure[r.time > r.attrs["steady_start_s"]]
        assert abs(p.mean() - r.attrs["muscle_pressure_MPa"]) < 0.01
        assert r.cylinder_pressure_command.max() == pytest.approx(
            r.attrs["offset_MPa"] + r.attrs["amplitude_MPa"], abs=1e-3)
        gap, corr = _loop_direction(r)
        assert gap > 5.0, f"{r.name}: loop runs the unphysical way (gap {gap:.1f} N)"
        assert corr < -0.5, f"{r.name}: tension does not fall with contraction ({corr:.2f})"
    ident = runs[0]
    # a DMSP-20 at ~0.48 MPa: tens to hundreds of newtons, contraction within ~0..30 mm
    assert 200 < ident.force.max() < 1500 and -5 < ident.position.min() < ident.position.max() < 32


def test_run_refuses_to_overwrite_without_force(tmp_path, capsys):
    out = tmp_path / "q.h5"
    out.write_bytes(b"old")
    args = ["run", "--rig", "sim", "--protocol", "quick", "--out", str(out), "--quiet"]
    rc = main(args)
    err = capsys.readouterr().err.strip()
    assert rc != 0 and out.read_bytes() == b"old"
    assert err.count("\n") == 0 and "already exists (use --force" in err
    assert main([*args[:-1], "-q", "--force"]) == 0  # -q as for every long verb
    (r,) = read_runs(out)
    assert r.name == "quick-400kPa" and len(r) == int(r.attrs["protocol"]["cycles"] / 0.5
                                                       * 500 + 1.5 * 500) + 1


def test_limit_trip_via_rig_file_exits_nonzero_with_one_line(tmp_path, capsys):
    rig = tmp_path / "weak-cell.toml"
    rig.write_text('[rig]\nkind = "sim"\n[limits]\nmax_force_N = 300\n')
    out = tmp_path / "trip.h5"
    rc = main(["run", "--rig", str(rig), "--protocol", "quick", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == SafetyAbort.exit_code
    assert err.count("\n") == 0 and "aborted: force" in err
    assert "cylinder regulator vented (confirmed" in err and "muscle regulator vented (confirmed" in err
    (r,) = read_runs(out)
    assert r.attrs["status"].startswith("aborted: force")
    assert abs(r.force[-1]) > 300 and np.all(np.abs(r.force[:-1]) <= 300)


def test_refused_protocol_exits_nonzero_and_writes_nothing(tmp_path, capsys):
    proto = tmp_path / "hot.toml"
    proto.write_text('[[run]]\nname = "hot"\nmuscle_pressure_MPa = 0.7\nfrequency_Hz = 0.2\n'
                     "magnitude_MPa = 0.3\n")
    out = tmp_path / "hot.h5"
    rc = main(["run", "--rig", "sim", "--protocol", str(proto), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and "refused" in err and "0.7 MPa exceeds" in err and err.count("\n") == 0
    assert not out.exists()


def test_bad_protocol_and_rig_are_one_line(tmp_path, capsys):
    proto = tmp_path / "bad.toml"
    proto.write_text('[[run]]\nname = "x"\nmuscle_pressure_MPa = 0.3\nfrequency_Hz = 0\n'
                     "magnitude_MPa = 0.3\n")
    rc = main(["run", "--rig", "sim", "--protocol", str(proto), "--out",
               str(tmp_path / "o.h5")])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and err.count("\n") == 0 and "field 'frequency_Hz'" in err and "bad.toml" in err
    rc = main(["run", "--rig", str(tmp_path / "missing.toml"), "--protocol", "quick", "--out",
               str(tmp_path / "o.h5")])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and err.count("\n") == 0 and "missing.toml" in err


def test_only_selects_runs_by_role(tmp_path):
    out = tmp_path / "v.h5"
    assert main(["run", "--rig", "sim", "--protocol", "seed-bouc-wen", "--out", str(out),
                 "--quiet", "--only", "validation"]) == 0
    assert [r.name for r in read_runs(out)] == ["valid-498kPa-0.1Hz", "valid-304kPa-0.3Hz"]


def test_quiet_run_prints_only_the_line_naming_its_output(tmp_path, capsys):
    """``run --quiet`` is what its help says: the one line naming the output file (no
    per-run lines, no vent confirmation); nothing on stderr when nothing went wrong."""
    out = tmp_path / "q.h5"
    assert main(["run", "--rig", "sim", "--protocol", "quick", "--out", str(out), "-q"]) == 0
    text = capsys.readouterr()
    assert text.out.splitlines() == [f"{out}: 1 runs, {len(read_runs(out)[0])} samples"]
    assert text.err == ""
    from pmalab.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    quiet = next(a for a in sub.choices["run"]._actions if "--quiet" in a.option_strings)
    assert "only the line naming the output" in quiet.help and "no per-run lines" in quiet.help


def test_manual_muscle_regulator_prompts_operator(tmp_path, capsys):
    rig = tmp_path / "manual.toml"
    rig.write_text('[rig]\nkind = "sim"\nmanual_muscle_regulator = true\n')
    out = tmp_path / "m.h5"
    assert main(["run", "--rig", str(rig), "--protocol", "quick", "--out", str(out),
                 "--quiet"]) == 0
    text = capsys.readouterr()
    err = text.err
    assert "run 'quick-400kPa': Set the muscle regulator to 0.4 MPa" in err
    # --quiet never hides a regulator the software did not vent
    assert "warning: regulators: " in err and "muscle regulator is manual and NOT vented" in err
    assert text.out.splitlines() == [f"{out}: 1 runs, {len(read_runs(out)[0])} samples"]
    (r,) = read_runs(out)
    assert abs(r.muscle_pressure.mean() - 0.4) < 0.01  # recording waited for the operator


def test_run_seed_duhem_triangles_have_the_physical_loop_direction(tmp_path):
    out = tmp_path / "d.h5"
    assert main(["run", "--rig", "sim", "--protocol", "seed-duhem", "--out", str(out),
                 "--quiet", "--seed", "3"]) == 0
    runs = read_runs(out)
    assert len(runs) == 9
    assert runs[0].attrs["waveform"] == "triangle" and runs[0].attrs["frequency_Hz"] == 0.1
    for r in runs:
        gap, corr = _loop_direction(r)
        assert gap > 3.0 and corr < -0.5, (r.name, gap, corr)
