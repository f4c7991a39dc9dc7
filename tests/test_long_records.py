"""Long records read a window at a time: the anti-aliased decimation identification uses
for runs of many cycles, checked on a short record with small windows (the same code paths
as a 10-hour one; the memory figures are in bench/)."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from pmalab.errors import RunFileError
from pmalab.identify.estimation.joint import MIN_SAMPLES_PER_CYCLE, joint_stride
from pmalab.identify.long_records import decimate, decimation_plan, long_runs
from pmalab.identify.signals import zero_phase_lowpass
from pmalab.runfile import Run, read_runs, write_runs
from pmalab.runwindows import LongRuns

FS, F = 500.0, 0.5


def _run(name: str, seconds: float, seed: int = 0) -> Run:
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    t = np.arange(n) / FS + rng.normal(0, 1e-6, n)  # measured stamps, a little jitter
    x = 10 + 8 * np.sin(2 * math.pi * F * t) + 0.5 * np.sin(2 * math.pi * 7 * F * t)
    x = x + rng.normal(0, 0.015, n)
    force = 400 - 20 * x + rng.normal(0, 0.7, n)
    p = 0.4 + rng.normal(0, 0.001, n)
    attrs = {"muscle_pressure_MPa": 0.4, "frequency_Hz": F, "waveform": "sine",
             "sample_rate_Hz": FS}
    return Run(name, t, x, force, p, cylinder_pressure=p + 0.1, attrs=attrs)


def test_a_long_run_is_read_in_windows_decimated_as_its_attrs_state(tmp_path):
    long, short = _run("long", 121.0), _run("short", 20.0, seed=1)
    path = write_runs(tmp_path / "r.h5", [long, short])
    got = {r.name: r for r in read_runs(path, long_runs=LongRuns(30_000, _small_blocks))}
    stride, cut = decimation_plan(FS, F)
    assert stride == 5 and cut == pytest.approx(30.0)  # 200 samples a cycle, 60× f
    d = got["long"]
    assert len(d) == math.ceil(len(long) / 5)
    # time and force at the stride, untouched (force noise stays white)
    np.testing.assert_array_equal(d.time, long.time[::5])
    np.testing.assert_array_equal(d.force, long.force[::5])
    # position and pressures: the whole-record zero-phase low-pass, then the stride — the
    # blocks (4,000 samples, filtered with margins) join as one filtered record (to 1 nm:
    # each block takes its sample rate from its own jittered stamps)
    whole = zero_phase_lowpass(long.time, long.position, cut)[::5]
    np.testing.assert_allclose(d.position, whole, rtol=0, atol=1e-6)
    assert np.std(d.position - long.position[::5]) < 0.015  # and the noise is filtered
    assert d.cylinder_pressure is not None and long.cylinder_pressure is not None
    np.testing.assert_allclose(
        d.cylinder_pressure, zero_phase_lowpass(long.time, long.cylinder_pressure, cut)[::5],
        atol=1e-9)
    dec = d.attrs["decimation"]
    assert dec["stride"] == 5 and dec["samples_read"] == len(long)
    assert dec["samples_per_cycle"] == pytest.approx(200, rel=1e-3)
    assert d.attrs["sample_rate_Hz"] == pytest.approx(100.0)
    assert d.attrs["recorded_sample_rate_Hz"] == FS
    # the short run of the same file is read whole, as ever
    np.testing.assert_array_equal(got["short"].position, short.position)
    assert "decimation" not in got["short"].attrs


def _small_blocks(w):
    return decimate(w, block=4000)


def test_a_fault_deep_in_a_long_run_names_file_run_channel_and_window(tmp_path):
    path = write_runs(tmp_path / "r.h5", [_run("long", 60.0)])
    with h5py.File(path, "a") as f:
        f["runs/long/force"][25_123] = np.nan
    with pytest.raises(RunFileError) as ei:
        read_runs(path, long_runs=LongRuns(10_000, _small_blocks))
    msg = str(ei.value)
    assert "run 'long'" in msg and "channel 'force'" in msg and "window of samples" in msg


def test_windows_are_whole_cycles_and_the_default_threshold_leaves_campaigns_alone(tmp_path):
    path = write_runs(tmp_path / "r.h5", [_run("long", 41.0)])
    seen = {}

    def keep(w):
        seen["cycles"] = w.cycle_windows(2)
        return w.run()

    read_runs(path, long_runs=LongRuns(1000, keep))
    wins = seen["cycles"]
    assert len(wins) == 10 and all(b - a == 2 * int(FS / F) for a, b in wins)
    # a campaign's runs (minutes) stay below the threshold: read whole, unchanged
    (r,) = read_runs(path, long_runs=long_runs())
    assert "decimation" not in r.attrs and len(r) == int(41.0 * FS)


def test_the_joint_fit_never_strides_a_long_run_below_100_samples_a_cycle():
    ten_hours = int(10 * 3600 * FS)
    k = joint_stride(ten_hours, FS, F)
    assert FS / k / F >= MIN_SAMPLES_PER_CYCLE  # was 2,500 samples: one every 7 cycles
    # a campaign run (a few cycles) keeps its former stride: 200 a cycle
    assert joint_stride(int(20 / 0.15 * FS), FS, 0.15) == math.ceil(int(20 / 0.15 * FS) / 2500)
    assert joint_stride(30_000, FS, 0.15) == 16


def test_the_loop_direction_of_a_record_of_hundreds_of_cycles():
    """The branch masks' smoothing stays within a fraction of a cycle however many cycles a
    record holds (at n/400 samples it spanned more than a cycle at 500 cycles and the loop
    read as anti-physical)."""
    from pmalab.identify.metrics import branch_masks, loop_direction

    rng = np.random.default_rng(0)
    t = np.arange(100_000) / 100.0  # 500 cycles at 0.5 Hz, 200 samples a cycle
    x = 20 + 8 * np.sin(2 * math.pi * F * t) + rng.normal(0, 0.01, t.size)
    v = np.cos(2 * math.pi * F * t)
    stretch, release = branch_masks(x)
    assert np.mean(stretch == (v < 0)) > 0.99 and np.mean(release == (v > 0)) > 0.99
    force = 400 - 20 * x + np.where(v < 0, 30.0, -30.0)  # stretching: 60 N more tension
    assert loop_direction(force, x) == pytest.approx(60.0, rel=0.05)


@pytest.mark.parametrize("kind", ["exponential", "zeros", "mostly-zero", "ties"])
def test_the_recorder_percentiles_of_a_long_run_in_bounded_memory(tmp_path, monkeypatch, kind):
    """A run's lateness percentiles at its end, read in blocks past a size (a 10 kHz run of
    hours would read and sort gigabytes): the same values as np.percentile."""
    import pmalab.acquisition.recorder as rec

    monkeypatch.setattr(rec, "PERCENTILE_WHOLE", 1000)
    monkeypatch.setattr(rec, "PERCENTILE_BLOCK", 4096)
    rng = np.random.default_rng(1)
    data = {
        "exponential": rng.exponential(1e-4, 100_003),
        "zeros": np.zeros(50_000),
        "mostly-zero": np.r_[np.zeros(90_000), rng.exponential(1e-3, 10_000)],
        "ties": np.round(rng.normal(0, 1, 77_777), 2),
    }[kind]
    with h5py.File(tmp_path / "x.h5", "w") as f:
        f["x"] = data
    with h5py.File(tmp_path / "x.h5", "r") as f:
        got = rec.dataset_percentiles(f["x"], len(data), (50.0, 99.0))
    np.testing.assert_allclose(got, np.percentile(data, [50, 99]), rtol=1e-12, atol=0)


def test_the_fitted_part_is_the_same_samples_whether_cut_to_its_steady_window_or_not():
    """identify cuts a run to its full-amplitude window before taking a long record's
    first cycles, diagnose after: both fit (and hold out) the same samples."""
    from pmalab.identify.long_records import fit_part

    r = _run("long", 200.0)
    r = Run(r.name, r.time[::5], r.position[::5], r.force[::5], r.muscle_pressure[::5],
            attrs={**r.attrs, "steady_start_s": 3.0, "steady_end_s": 195.0,
                   "decimation": {"stride": 5}})
    a = fit_part(r.steady(), cycles=20)
    b = fit_part(r, cycles=20).steady()
    np.testing.assert_array_equal(a.time, b.time)
    assert a.time[0] == pytest.approx(r.time[0] + 3.0, abs=0.011)
    assert a.time[-1] - a.time[0] == pytest.approx(40.0, abs=0.02)  # 20 cycles at 0.5 Hz
    assert a.attrs["fit_part"]["cycles"] == 20
