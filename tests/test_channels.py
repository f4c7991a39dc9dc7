"""Channels declared as data: the run file's declaration (version 2), version-1 files, and
one muscle's view of a multi-muscle file."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from pmalab.acquisition.recorder import Recorder
from pmalab.acquisition.safety import SafetyMonitor
from pmalab.channels import Channel, Channels, muscle_channels
from pmalab.errors import ConfigError, RunFileError
from pmalab.rig.base import SINGLE_MUSCLE_CHANNELS, Limits, sampled
from pmalab.runfile import Run, muscles_of, read_runs, write_runs


def _single(n: int = 200) -> Run:
    t = np.arange(n) * 0.002
    x = 10 + 5 * np.sin(2 * np.pi * t)
    return Run("r0", t, x, 400 - 20 * x, np.full(n, 0.4), attrs={"muscle_pressure_MPa": 0.4})


def test_a_written_file_declares_its_channels_and_reads_back(tmp_path):
    out = write_runs(tmp_path / "a.h5", [_single()])
    with h5py.File(out) as f:
        assert f.attrs["format_version"] == 2
        g = f["runs/r0"]
        decl = Channels.from_attr(g.attrs["channels"])
        assert decl.names == ("time", "position", "force", "muscle_pressure")
        # text attrs are fixed-length UTF-8 (checksummed object headers): bytes in h5py
        assert g["force"].attrs["kind"] == b"force" and g["position"].attrs["muscle"] == b"muscle"
    (r,) = read_runs(out)
    assert np.array_equal(r.force, _single().force) and "channels" not in r.attrs


def test_a_version_1_file_stays_readable(tmp_path):
    out = tmp_path / "v1.h5"
    run = _single()
    with h5py.File(out, "w") as f:  # the version-1 layout, written by hand
        f.attrs["format"], f.attrs["format_version"] = "pmalab.run", 1
        g = f.create_group("runs/r0")
        g.attrs["muscle_pressure_MPa"] = 0.4
        for ch in ("time", "position", "force", "muscle_pressure"):
            g.create_dataset(ch, data=getattr(run, ch)).attrs["units"] = "mm" if ch == "position" else {"time": "s", "force": "N", "muscle_pressure": "MPa"}[ch]
    (r,) = read_runs(out)
    assert np.allclose(r.position, run.position) and r.nominal_pressure == 0.4
    assert muscles_of(out) == ("muscle",)
    with h5py.File(out, "r+") as f:
        f.attrs["format_version"] = 3
    with pytest.raises(RunFileError, match="unsupported format_version 3"):
        read_runs(out)


def _pair_file(tmp_path) -> tuple[str, dict[str, np.ndarray]]:
    """A two-muscle file through the recorder: muscle 'a' held in run 'ha', 'b' in 'hb'."""
    decl = Channels(
        (Channel("time", "time"), Channel("angle", "angle"),
         *muscle_channels("a"), *muscle_channels("b"))
    )
    out = tmp_path / "pair.h5"
    n = 300
    t = np.arange(n) * 0.002
    cols = {"time": t, "angle": 10 * np.sin(t)}
    for m, p in (("a", 0.3), ("b", 0.5)):
        cols[f"position_{m}"] = 8 + np.sin(t) * (1 if m == "a" else -1)
        cols[f"force_{m}"] = 300 - 10 * cols[f"position_{m}"]
        cols[f"muscle_pressure_{m}"] = np.full(n, p)
        cols[f"muscle_pressure_command_{m}"] = np.full(n, p)
    runs = [("ha", {"muscle_pressure_MPa": 0.3, "held_muscle": "a"}),
            ("hb", {"muscle_pressure_MPa": 0.5, "held_muscle": "b"})]
    with Recorder(out, runs, {}, channels=decl) as rec:
        for name, _ in runs:
            w = rec.writer(name)
            for i in range(n):
                w.append(tuple(cols[c][i] for c in decl.names), 0.0)
            w.finish("completed")
    return str(out), cols


def test_one_muscle_view_of_a_two_muscle_file(tmp_path):
    out, cols = _pair_file(tmp_path)
    assert muscles_of(out) == ("a", "b")
    with pytest.raises(RunFileError, match=r"holds 2 muscles \(a, b\): choose one"):
        read_runs(out)
    with pytest.raises(RunFileError, match="no muscle 'c'"):
        read_runs(out, muscle="c")
    (ra,) = read_runs(out, muscle="a")  # only the run that held 'a' isobaric
    assert ra.name == "ha" and ra.attrs["muscle"] == "a" and ra.nominal_pressure == 0.3
    assert np.array_equal(ra.force, cols["force_a"]) and np.array_equal(ra.position, cols["position_a"])
    (rb,) = read_runs(out, muscle="b")
    assert rb.name == "hb" and np.array_equal(rb.muscle_pressure, cols["muscle_pressure_b"])
    # a run named explicitly is read whichever muscle it held
    (x,) = read_runs(out, ["hb"], muscle="a")
    assert np.array_equal(x.force, cols["force_a"])


def test_safety_limits_follow_the_declaration():
    lim = Limits(max_force_N=1000.0, max_muscle_pressure_MPa=0.6)
    chans = [Channel("angle", "angle", lo=-30.0, hi=30.0), *muscle_channels("a", command=False)]
    mon = SafetyMonitor(lim, channels=chans)
    ok = (0.0, 5.0, 100.0, 0.4)
    assert mon.check(ok) is None
    assert mon.check((31.0, 5.0, 100.0, 0.4)) == "angle 31 deg outside [-30, 30] deg"
    assert mon.check((0.0, 5.0, 1200.0, 0.4)).startswith("force (a) 1200.0 N beyond")
    assert mon.check((0.0, 5.0, 100.0, 0.7)).startswith("muscle pressure (a) 0.700 MPa above")
    assert mon.check((0.0, math.nan, 100.0, 0.4)).startswith("sensor returned NaN")
    # the single-muscle rig's messages are unchanged
    single = SafetyMonitor(lim)
    assert [c.name for c in single.channels] == list(sampled(SINGLE_MUSCLE_CHANNELS))
    assert single.check((10.0, 1500.0, 0.4, 0.1)) == (
        "force 1500.0 N beyond the load cell's range ±1000 N"
    )


def test_declarations_refuse_unknown_kinds_and_duplicates():
    with pytest.raises(ConfigError, match="unknown kind 'torque'"):
        Channel("tau", "torque")
    with pytest.raises(ConfigError, match="declared twice"):
        Channels((Channel("x", "position"), Channel("x", "force")))
