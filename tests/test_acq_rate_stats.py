"""Reduced-rate recording and the devices' fault counters in the run file."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from test_acq_fakes import make_fake_rig, raise_at

from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.acquisition.safety import ProtocolRefused
from pmalab.errors import RigError, SafetyAbort
from pmalab.runfile import read_runs

PROTO = """
[protocol]
name = "short"
[defaults]
muscle_pressure_MPa = 0.3
waveform = "sine"
magnitude_MPa = 0.3
cycles = 1
ramp_s = 0.2
settle_s = 0.2
pressure_stable_s = 0.2
[[run]]
name = "a"
frequency_Hz = 1.0
[[run]]
name = "b"
frequency_Hz = 2.0
"""


def opts() -> RunnerOptions:
    return RunnerOptions(progress=False, realtime_priority=False)


def reduce(rig, rate: float) -> None:
    """What the drivers' loader does after a too-slow probe with allow_reduced_rate."""
    rig.sampler.sample_rate_Hz = rate
    rig.info["timing"] = {"requested_rate_Hz": 500.0, "sustainable_Hz": rate * 1.3,
                          "sample_rate_Hz": rate, "reduced": True}
    rig.info["name"] = "slow bus"


def test_reduced_rate_runs_the_deadlines_at_the_samplers_rate(tmp_path, capsys):
    rig = make_fake_rig()
    reduce(rig, 100.0)
    out = tmp_path / "r.h5"
    res = run_protocol(rig, parse_protocol(PROTO, "short.toml"), out, options=opts())
    err = capsys.readouterr().err
    warn = [ln for ln in err.splitlines() if "reduced" in ln]
    assert len(warn) == 1
    assert "slow bus" in warn[0] and "100 Hz" in warn[0] and "500 Hz" in warn[0]
    runs = read_runs(out)
    for r, spec_dur in zip(runs, (0.2 + 0.4 + 1.0, 0.2 + 0.4 + 0.5)):
        assert r.attrs["sample_rate_Hz"] == 100.0
        assert r.attrs["requested_sample_rate_Hz"] == 500.0
        # virtual clock: the timestamps sit exactly on the 10 ms grid
        assert np.diff(r.time) == pytest.approx(0.01, abs=1e-9)
        assert len(r) == int(round(spec_dur * 100)) + 1
        assert r.attrs["status"] == "completed"
    assert [x.n_samples for x in res] == [len(r) for r in runs]
    with h5py.File(out) as f:
        assert f.attrs["sample_rate_Hz"] == 100.0
        assert f.attrs["requested_sample_rate_Hz"] == 500.0


def test_full_rate_without_the_reduced_flag(tmp_path, capsys):
    rig = make_fake_rig()
    rig.sampler.sample_rate_Hz = 100.0  # a lower sampler rate alone changes nothing
    out = tmp_path / "f.h5"
    run_protocol(rig, parse_protocol(PROTO, "short.toml"), out, options=opts())
    assert "reduced" not in capsys.readouterr().err
    r = read_runs(out)[0]
    assert r.attrs["sample_rate_Hz"] == 500.0 == r.attrs["requested_sample_rate_Hz"]
    assert np.median(np.diff(r.time)) == pytest.approx(0.002, abs=1e-9)
    assert r.attrs["device_stats"] == {}  # the fake sampler has no stats()


def test_reduced_rate_too_low_for_a_waveform_is_refused_before_anything_moves(tmp_path):
    rig = make_fake_rig()
    reduce(rig, 25.0)  # run 'b' at 2 Hz needs ≥ 40 Hz
    out = tmp_path / "no.h5"
    with pytest.raises(ProtocolRefused, match=r"run 'b': refused: .*needs ≥ 40 Hz.*25 Hz"):
        run_protocol(rig, parse_protocol(PROTO, "short.toml"), out, options=opts())
    assert not out.exists()
    assert rig.cylinder_regulator.max_commanded == 0.0


class Counters:
    """Cumulative link counters, bumped every sample (as a flaky link would)."""

    def __init__(self) -> None:
        self.n = 0

    def __call__(self) -> dict:
        return {"modbus": {"requests": self.n, "retries": self.n // 100, "timeouts": 1},
                "indicator": {"bad_frames": 2, "line_rate_Hz": 12.5}}


def with_stats(rig):
    sampler = rig.sampler
    counters = Counters()
    inner = sampler.read_block

    def read_block():
        counters.n += 1
        return inner()

    sampler.read_block = read_block
    sampler.stats = counters
    return counters


def test_device_stats_after_completed_runs(tmp_path):
    rig = make_fake_rig()
    counters = with_stats(rig)
    out = tmp_path / "s.h5"
    run_protocol(rig, parse_protocol(PROTO, "short.toml"), out, options=opts())
    a, b = read_runs(out)
    sa, sb = a.attrs["device_stats"], b.attrs["device_stats"]
    # counters as they stood at each run's end (cumulative since the rig was opened)
    assert sb == counters()
    assert sa["indicator"] == {"bad_frames": 2, "line_rate_Hz": 12.5}
    assert sa["modbus"]["timeouts"] == 1
    # every sample of a run (plus the pressure wait) is a request
    assert len(a) < sa["modbus"]["requests"] < sb["modbus"]["requests"]
    assert sb["modbus"]["requests"] - sa["modbus"]["requests"] >= len(b)
    assert sb["modbus"]["retries"] == sb["modbus"]["requests"] // 100


def test_device_stats_after_an_aborted_run(tmp_path):
    rig = make_fake_rig(raise_at(1.5, RigError("bus: no reply after 4 attempts")))
    counters = with_stats(rig)
    out = tmp_path / "abort.h5"
    with pytest.raises(SafetyAbort, match="device fault"):
        run_protocol(rig, parse_protocol(PROTO, "short.toml"), out, options=opts())
    (a,) = read_runs(out)  # 'b' never started: skipped by the reader
    assert a.attrs["status"].startswith("aborted: device fault")
    assert a.attrs["device_stats"] == counters()
    assert a.attrs["device_stats"]["modbus"]["requests"] > len(a) > 100
    with h5py.File(out) as f:
        assert f["runs"]["b"]["device_stats"][()] == b""  # not run: nothing stored


def test_failing_or_huge_stats_never_break_the_file(tmp_path):
    rig = make_fake_rig()

    def broken():
        raise OSError("port gone")

    rig.sampler.stats = broken
    out = tmp_path / "e.h5"
    run_protocol(rig, parse_protocol(PROTO, "short.toml"), out, options=opts())
    assert read_runs(out)[0].attrs["device_stats"] == {
        "error": "stats() failed: OSError: port gone"}
    rig2 = make_fake_rig()
    rig2.sampler.stats = lambda: {"blob": "x" * 20000}
    out2 = tmp_path / "h.h5"
    run_protocol(rig2, parse_protocol(PROTO, "short.toml"), out2, options=opts())
    assert "too long" in read_runs(out2)[0].attrs["device_stats"]["error"]
