"""Lateness against each sample's scheduled time, and the warning for a run that did not
keep its rate (virtual clock: a slow link is a sampler whose request takes clock time)."""

from __future__ import annotations

import pytest
from test_acq_fakes import FakeSampler, make_fake_rig
from test_acq_rate_stats import PROTO, reduce

import pmalab.acquisition.cli as acq_cli
from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.cli import main
from pmalab.runfile import read_runs


class SlowLink(FakeSampler):
    """Each request takes ``request_s`` of clock time, stamped at its middle (as the Modbus
    sampler does); every ``stall_every``-th request stalls ``stall_s`` more."""

    request_s = 0.004
    stall_every = 0
    stall_s = 0.0

    def read_block(self):
        self.clock.advance(self.request_s / 2)
        blk = super().read_block()
        extra = self.stall_s if self.stall_every and self.n % self.stall_every == 0 else 0.0
        self.clock.advance(self.request_s / 2 + extra)
        return blk


def slow_rig(rate: float = 100.0, **kw):
    rig = make_fake_rig()
    s = rig.sampler
    rig.sampler = SlowLink(s.clock, s.reg, s.supply)
    for k, v in kw.items():
        setattr(rig.sampler, k, v)
    reduce(rig, rate)
    return rig


def opts() -> RunnerOptions:
    return RunnerOptions(progress=False, realtime_priority=False)


def test_steady_reduced_rate_over_a_slow_link_is_on_time(tmp_path):
    """4 ms requests at 100 Hz: every sample is stamped 2 ms after its deadline, but each
    request starts on time — nothing is late or missed, and nothing is flagged."""
    rig = slow_rig()
    out = tmp_path / "steady.h5"
    res = run_protocol(rig, parse_protocol(PROTO, "short.toml"), out, options=opts())
    for r, rr in zip(read_runs(out), res):
        t = r.attrs["timing"]
        assert t["late"] == 0 and t["missed"] == 0 and t["timing_warning"] == 0
        assert t["lateness_max_s"] == pytest.approx(0.0, abs=1e-12)
        assert r.time[1] - r.time[0] == pytest.approx(0.01, abs=1e-12)
        assert rr.warning is None


def test_a_run_that_misses_more_than_1_percent_is_flagged_and_warned(tmp_path, capsys,
                                                                     monkeypatch):
    """Every 20th request stalls 25 ms at 100 Hz (29 ms in all): the next deadline passes
    entirely (missed) and the two after it start 9 and 3 ms late."""
    rig = slow_rig(stall_every=20, stall_s=0.025, force_noise=0.5)
    proto = tmp_path / "short.toml"
    proto.write_text(PROTO)
    monkeypatch.setattr(acq_cli, "load_rig_spec", lambda *a, **k: rig)
    out = tmp_path / "stall.h5"
    assert main(["run", "--rig", "fake", "--protocol", str(proto), "--out", str(out),
                 "--quiet"]) == 0
    cap = capsys.readouterr()
    warnings = [ln for ln in cap.err.splitlines() if "did not keep its sample rate" in ln]
    assert len(warnings) == 2 and "run 'a'" in warnings[0] and "run 'b'" in warnings[1]
    # after the summaries: the last thing the operator reads
    assert cap.err.strip().splitlines()[-1] == warnings[-1]
    for r in read_runs(out):
        t = r.attrs["timing"]
        scheduled = t["n_samples"] + t["missed"]
        assert t["missed"] >= scheduled // 20 - 1  # one per stall
        assert 2 * t["missed"] - 2 <= t["late"] <= 2 * t["missed"] + 2  # two late after each
        assert t["missed_fraction"] == pytest.approx(t["missed"] / scheduled)
        assert t["late_fraction"] == pytest.approx(t["late"] / t["n_samples"])
        assert t["missed_fraction"] > 0.04 and t["timing_warning"] == 1
        assert f"{int(t['missed'])} of {int(scheduled)} scheduled samples missed" in "".join(
            warnings)


def test_below_one_percent_is_not_flagged(tmp_path):
    """One 19 ms stall (23 ms request) in a 161-sample run: 1 missed (0.6 %), the next
    sample 3 ms late (0.6 %), the one after on time again."""
    rig = slow_rig(stall_every=150, stall_s=0.019)
    out = tmp_path / "few.h5"
    res = run_protocol(rig, parse_protocol(PROTO, "short.toml"), out, options=opts())
    t = res[0].timing
    assert t["missed"] == 1 and t["late"] == 1 and t["n_samples"] == 160
    assert t["timing_warning"] == 0 and res[0].warning is None

