"""A real-time recording checked against its own timing records (tests' helper).

A software-polled recording (``DeadlinePacing``) reads deadline k at t0 + k/rate on the
rig's clock: it sleeps until the deadline, records how late it woke (the ``lateness``
dataset, wake − deadline), stamps the sample at the middle of its request, and records the
deadlines that passed entirely while it was busy as a gap (the ``gaps`` dataset: start
s, samples missed) — never an invented sample.  On a busy machine the samples are late and
some deadlines missed, and the file says so.  What holds on any machine:

* the schedule is the announced rate's: the gaps put every sample on its deadline k, and
  each sample's stamp lies between its own wake (deadline + recorded lateness) and the next
  sample's wake (a request ends before the next starts);
* the loop never wakes before its deadline (lateness ≥ 0);
* nothing is lost or invented: samples + missed deadlines = the deadlines scheduled.

What holds only on a machine that kept its deadlines (the idle-machine figures) is stated
as a condition on the same records: :func:`kept_deadlines`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

#: lateness is stored as float32: its rounding, and the clock read's, in s
TOL_S = 2e-6


@dataclass
class TimingRecords:
    """One run's stamps (s from deadline 0), lateness (s) and gap rows (start s, n)."""

    time: np.ndarray
    lateness: np.ndarray
    gaps: np.ndarray
    rate_Hz: float


def read_timing_records(path: str | Path, run: str) -> TimingRecords:
    """The stamps, lateness and gaps of ``run`` in a (closed) run file."""
    with h5py.File(path, "r") as f:
        g = f["runs"][run]
        return TimingRecords(
            np.asarray(g["time"][:], dtype=np.float64),
            np.asarray(g["lateness"][:], dtype=np.float64),
            np.asarray(g["gaps"][()], dtype=np.float64).reshape(-1, 2),
            float(g.attrs["sample_rate_Hz"]),
        )


def deadline_indices(n: int, gaps: np.ndarray, dt: float) -> np.ndarray:
    """Each sample's deadline index k, from the gap records (samples in order, every gap
    starting on the grid at the deadline after the sample before it)."""
    starts = gaps[:, 0] / dt
    kg = np.rint(starts).astype(int)
    assert np.all(np.abs(starts - kg) < 1e-6 * np.maximum(1.0, kg)), ("gap off the grid", gaps)
    counts = gaps[:, 1].astype(int)
    assert np.all(counts >= 1) and np.all(counts == gaps[:, 1]), ("gap counts", gaps)
    k = np.empty(n, dtype=np.int64)
    j, kk = 0, 0
    for i in range(n):
        while j < len(kg) and kg[j] == kk:
            kk += counts[j]
            j += 1
        assert j == len(kg) or kg[j] > kk, ("a gap inside delivered samples", gaps[j], kk)
        k[i] = kk
        kk += 1
    # what is left are gaps after the last sample, in order
    assert np.all(np.diff(kg[j:]) > 0) and (j == len(kg) or kg[j] >= kk), ("trailing gaps", gaps[j:])
    return k


def check_software_polled(rec: TimingRecords, n_scheduled: int | None, read_max_s: float
                          ) -> np.ndarray:
    """Assert the file is consistent with its own lateness and gap records (module
    docstring); ``n_scheduled``: the run's deadlines (duration × rate + 1; None for a run
    that ended early: only the deadlines up to its last sample are accounted for),
    ``read_max_s``: the longest a request may take (its link's timeout × attempts).
    Returns each sample's wake time (deadline + lateness, s)."""
    n = len(rec.time)
    dt = 1.0 / rec.rate_Hz
    assert n >= 2 and rec.lateness.shape == (n,)
    assert np.all(rec.lateness >= -TOL_S), rec.lateness.min()  # never before its deadline
    k = deadline_indices(n, rec.gaps, dt)
    if n_scheduled is None:  # ended early: the schedule ran to its last sample
        n_scheduled = int(k[-1]) + 1
        rec = TimingRecords(rec.time, rec.lateness, rec.gaps[rec.gaps[:, 0] < k[-1] * dt],
                            rec.rate_Hz)
    # nothing lost, nothing invented: samples and missed deadlines make up the schedule
    # (a skip past the last deadline counts only the deadlines that were scheduled)
    missed = np.minimum(rec.gaps[:, 1], np.maximum(0.0, n_scheduled - rec.gaps[:, 0] / dt))
    assert k[-1] < n_scheduled and n + int(round(missed.sum())) == n_scheduled, (
        n, rec.gaps, n_scheduled)
    wake = k * dt + rec.lateness
    assert np.all(np.diff(wake) > 0)
    # stamped inside its own request: after its wake, before the next sample's wake
    off = rec.time - wake
    assert np.all(off >= -TOL_S), (off.min(), int(np.argmin(off)))
    assert np.all(rec.time[:-1] < wake[1:] + TOL_S), int(np.argmax(rec.time[:-1] - wake[1:]))
    assert off[-1] <= read_max_s, off[-1]
    return wake


def kept_deadlines(rec: TimingRecords, share: float = 0.05) -> bool:
    """Whether the run kept its deadlines by its own records: at most 1 % of the scheduled
    deadlines missed (the runner's own warning threshold) and at most 5 % of the samples
    woke later than 5 % of the period (an idle machine wakes within microseconds)."""
    dt = 1.0 / rec.rate_Hz
    missed = float(rec.gaps[:, 1].sum())
    return (
        missed <= 0.01 * (len(rec.time) + missed)
        and float(np.mean(rec.lateness > 0.05 * dt)) <= share
    )


def too_busy_refusal(exc: BaseException | str) -> str:
    """Assert that a rig refused as "too busy to judge the link" says so on its own probe's
    figures (the process waited for a CPU more than the threshold; the fastest read no
    slower than the median), and return the message; re-raise any other error (a message
    that is not this refusal fails the test with it)."""
    import re

    from pmalab.rig.drivers.modbus_daq import HOST_BUSY_SHARE

    m = re.search(
        r"too busy to judge the link: .* waited for a CPU (\d+) % of the time, and block "
        r"reads took ([\d.]+) ms \(median\) though the fastest took ([\d.]+) ms",
        str(exc),
    )
    if m is None:
        if isinstance(exc, str):
            raise AssertionError(exc)
        raise exc
    assert int(m[1]) >= 100 * HOST_BUSY_SHARE, str(exc)
    assert float(m[3]) <= float(m[2]), str(exc)
    return str(exc)
