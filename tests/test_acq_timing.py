"""Runner timing: absolute deadlines, actual timestamps, late and missed samples counted."""

from __future__ import annotations

import numpy as np
import pytest
from test_acq_fakes import FakeSampler, make_fake_rig

from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.rig.base import Block, VirtualClock
from pmalab.runfile import read_runs

PROTO = parse_protocol(
    '[[run]]\nname = "r"\nmuscle_pressure_MPa = 0.3\nfrequency_Hz = 1.0\nmagnitude_MPa = 0.2\n'
    "cycles = 2\nramp_s = 0.5\nsettle_s = 0.5\n",
    "timing.toml",
)
DT = 1 / 500


class HiccupClock(VirtualClock):
    """A virtual clock that wakes late: every sleep returns ``work`` s after its deadline
    (the loop's own processing time) and ``delays`` maps a deadline index, counted from
    ``start`` (the recording's time zero), to an extra delay (s)."""

    def __init__(self, delays: dict[int, float], work: float = 20e-6) -> None:
        super().__init__()
        self.delays, self.work = delays, work
        self.start: float | None = None

    def sleep_until(self, t: float) -> None:
        super().sleep_until(t)
        self._t += self.work
        if self.start is not None:
            self._t += self.delays.get(int(round((t - self.start) / DT)), 0.0)


def test_late_and_missed_samples_are_counted_and_timestamps_kept(tmp_path, monkeypatch):
    import pmalab.acquisition.runner as runner

    clock = HiccupClock({100: 0.0003, 200: 0.0008, 300: 0.0073})
    rig = make_fake_rig(clock=clock)
    orig_record = runner._record

    def record(*a, **k):  # arm the hiccups when the recording starts
        clock.start = clock.now()
        return orig_record(*a, **k)

    monkeypatch.setattr(runner, "_record", record)
    (res,) = run_protocol(rig, PROTO, tmp_path / "t.h5", options=RunnerOptions(progress=False))
    (r,) = read_runs(tmp_path / "t.h5")
    t = r.attrs["timing"]
    # 0.3 ms late is on time (threshold 0.5 ms); 0.8 ms is late; 7.3 ms is late and its slot
    # overran deadlines 301 and 302 entirely: those are missed (skipped, not faked), and
    # deadline 303 is sampled 1.3 ms late
    assert t["late"] == 3 and t["missed"] == 2
    assert res.timing["missed"] == 2
    expected = int(round(PROTO.runs[0].duration_s / DT)) + 1
    assert len(r) == expected - 2
    lat = r.time - np.arange(len(r)) * DT
    lat[301:] -= 2 * DT  # samples after the skipped deadlines
    np.testing.assert_allclose(lat[[0, 99, 100, 200, 300, 301, 302]],
                               [20e-6, 20e-6, 320e-6, 820e-6, 7320e-6, 1340e-6, 20e-6],
                               atol=1e-9)  # actual timestamps kept
    assert t["lateness_max_s"] == pytest.approx(0.00732, abs=1e-6)
    assert np.all(np.diff(r.time) > 0)


class HardwareSampler(FakeSampler):
    """Hardware-timed: returns blocks of 50 samples on its own 500 Hz grid, with a gap."""

    hardware_timed = True

    def __init__(self, *a, gap_at: int = 1000, gap: int = 7, **k) -> None:
        super().__init__(*a, **k)
        self.i = 0
        self.gap_at, self.gap = gap_at, gap

    def read_block(self) -> Block:
        rows = []
        for _ in range(50):
            if self.i == self.gap_at:
                self.i += self.gap  # the device dropped `gap` samples
            t = self.i * DT
            self.clock.sleep_until(t)
            b = FakeSampler.read_block(self)
            rows.append([t, b.position[0], b.force[0], b.muscle_pressure[0],
                         b.cylinder_pressure[0]])
            self.i += 1
        a = np.array(rows).T
        return Block(*a)


def test_hardware_timed_sampler_gaps_count_as_missed(tmp_path):
    rig = make_fake_rig()
    hw = HardwareSampler(rig.clock, rig.cylinder_regulator, rig.muscle_supply, gap_at=2000)
    rig.sampler = hw
    run_protocol(rig, PROTO, tmp_path / "h.h5", options=RunnerOptions(progress=False))
    (r,) = read_runs(tmp_path / "h.h5")
    assert r.attrs["timing"]["missed"] == 7
    expected = int(round(PROTO.runs[0].duration_s / DT)) + 1
    assert len(r) == expected - 7
    assert np.sum(np.diff(r.time) > 1.5 * DT) == 1


def test_gaps_are_recorded_as_data_where_and_how_long(tmp_path):
    """Each gap is a row of the run's ``gaps`` dataset (start s from the run's first
    sample, samples missed); the samples on either side are the device's own, none invented."""
    import h5py

    rig = make_fake_rig()
    hw = HardwareSampler(rig.clock, rig.cylinder_regulator, rig.muscle_supply, gap_at=2000,
                         gap=5)
    rig.sampler = hw
    run_protocol(rig, PROTO, tmp_path / "g.h5", options=RunnerOptions(progress=False))
    (r,) = read_runs(tmp_path / "g.h5")
    with h5py.File(tmp_path / "g.h5") as f:
        gaps = f["runs"][PROTO.runs[0].name]["gaps"][:]
    assert gaps.shape == (1, 2) and gaps[0, 1] == 5
    jump = int(np.flatnonzero(np.diff(r.time) > 1.5 * DT)[0])
    # the first missing sample was due one period after the last one delivered
    assert gaps[0, 0] == pytest.approx(r.time[jump] - r.time[0] + DT, abs=1e-9)
    assert r.time[jump + 1] - r.time[jump] == pytest.approx(6 * DT, abs=1e-9)
    assert r.attrs["timing"]["missed"] == 5


def test_identification_says_where_a_gap_was_bridged(tmp_path):
    """A recorded gap reaches the identification as a note (samples missing, where, how
    long), not as silently interpolated data."""
    from pmalab.identify.api import gap_notes

    rig = make_fake_rig()
    rig.sampler = HardwareSampler(rig.clock, rig.cylinder_regulator, rig.muscle_supply,
                                  gap_at=2000, gap=5)
    run_protocol(rig, PROTO, tmp_path / "g.h5", options=RunnerOptions(progress=False))
    (r,) = read_runs(tmp_path / "g.h5")
    (note,) = gap_notes([r])
    assert "1 gap(s)" in note and "5 missing" in note and "bridged" in note
    clean = make_fake_rig()
    run_protocol(clean, PROTO, tmp_path / "c.h5", options=RunnerOptions(progress=False))
    assert gap_notes(read_runs(tmp_path / "c.h5")) == []
