"""The real-time tests' check against a file's own timing records (``timing_records``)
passes on a recording whose link stalls (late samples, missed deadlines recorded as gaps),
and fails on the same records with a gap left unrecorded, a sample invented, a stamp before
its wake or the wrong rate."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from test_acq_lateness import opts, slow_rig
from test_acq_rate_stats import PROTO
from timing_records import check_software_polled, kept_deadlines, read_timing_records

from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import run_protocol


@pytest.fixture(scope="module")
def stalled(tmp_path_factory):
    """Run 'a' of a 100 Hz recording whose every 20th request stalls 25 ms, its schedule."""
    out = tmp_path_factory.mktemp("records") / "stall.h5"
    proto = parse_protocol(PROTO, "short.toml")
    run_protocol(slow_rig(stall_every=20, stall_s=0.025), proto, out, options=opts())
    rec = read_timing_records(out, "a")
    return rec, math.floor(proto.runs[0].duration_s * rec.rate_Hz + 1e-9) + 1


def test_a_stalling_links_records_are_consistent(stalled):
    rec, n_scheduled = stalled
    # the records have something to say: late samples and recorded gaps
    assert len(rec.gaps) >= 5 and rec.lateness.max() > 0.005
    wake = check_software_polled(rec, n_scheduled, read_max_s=0.03)
    assert wake.shape == rec.time.shape
    assert check_software_polled(rec, None, read_max_s=0.03).shape == rec.time.shape
    assert not kept_deadlines(rec)  # ~5 % of the deadlines missed


def test_an_idle_runs_records_keep_their_deadlines(tmp_path):
    out = tmp_path / "steady.h5"
    proto = parse_protocol(PROTO, "short.toml")
    run_protocol(slow_rig(), proto, out, options=opts())
    rec = read_timing_records(out, "a")
    n = math.floor(proto.runs[0].duration_s * rec.rate_Hz + 1e-9) + 1
    check_software_polled(rec, n, read_max_s=0.03)
    assert kept_deadlines(rec) and len(rec.gaps) == 0 and len(rec.time) == n


def test_tampered_records_are_caught(stalled):
    rec, n_scheduled = stalled

    def fails(bad, n=n_scheduled):
        with pytest.raises(AssertionError):
            check_software_polled(bad, n, read_max_s=0.03)

    # a missed deadline whose gap was not recorded: the count, and the stamps alone (the
    # samples after it would sit a period earlier than they were taken)
    fails(replace(rec, gaps=rec.gaps[1:]))
    fails(replace(rec, gaps=rec.gaps[1:]), None)
    # a sample invented in a recorded gap: at the missed deadline, on time
    i = int(np.searchsorted(rec.time, rec.gaps[0, 0]))
    fails(replace(rec, time=np.insert(rec.time, i, rec.gaps[0, 0] + 1e-4),
                  lateness=np.insert(rec.lateness, i, 0.0)))
    # an invented sample at the end (one more than scheduled)
    fails(replace(rec, time=np.append(rec.time, rec.time[-1] + 0.01),
                  lateness=np.append(rec.lateness, 0.0)))
    # a sample lost without a trace
    lost = replace(rec, time=np.delete(rec.time, 50), lateness=np.delete(rec.lateness, 50))
    fails(lost)
    fails(lost, None)
    # a stamp before its own wake (lateness recorded larger than it was)
    late = rec.lateness.copy()
    late[30] += 0.004
    fails(replace(rec, lateness=late))
    # a wake before its deadline
    late = rec.lateness.copy()
    late[31] = -0.001
    fails(replace(rec, lateness=late))
    # the schedule of another rate
    fails(replace(rec, rate_Hz=rec.rate_Hz * 1.01))
