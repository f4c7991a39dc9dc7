"""Long records (fatigue, creep: hours of cycling) read for identification by a stated,
anti-aliased decimation, a window at a time.

A 10-hour run at 500 Hz holds 18 million samples a channel; read whole with its float64
copies and the filtered signals a fit drives its law with, it needs gigabytes.  Nothing of
the model needs that rate: the force laws are rate independent or depend on the velocity
of a motion at the excitation frequency f, and a hysteresis loop is drawn faithfully by
~100 samples a cycle (:meth:`~pmalab.identify.signals.Signals.every`).  A run of at least
:data:`LONG_RUN_SAMPLES` samples is therefore read (:mod:`pmalab.runwindows`) in blocks of
:data:`BLOCK` samples and kept at :data:`SAMPLES_PER_CYCLE` samples per cycle:

* position and pressures — what drives the model — pass the zero-phase (forward and
  backward) 4th-order Butterworth low-pass every fit applies
  (:func:`~pmalab.identify.signals.zero_phase_lowpass`, cut-off 60× f) before they are
  taken at the stride; the cut-off is held below :data:`ANTI_ALIAS_FRACTION` of the
  decimated Nyquist frequency, so nothing above it folds back into the loop.  Each block
  is filtered with a margin of samples either side that is then dropped, so the blocks
  join as one filtered record (the filter's memory is far shorter than the margin);
* force — what the model is scored on — is taken at the stride unfiltered: its signal
  (harmonics of f) lies far below the decimated Nyquist frequency (100× f), and its
  sensor noise, folded, stays white with the same variance, so the noise floor and nrmse
  keep their meaning;
* time stamps are the measured ones, at the stride.

The decimated run says what was done in its attrs (``decimation``), which
``identification.json`` reports.  A run without a stated excitation frequency cannot be
decimated by cycles and is read whole.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pmalab.runfile import Run
from pmalab.runwindows import LongRuns, RunWindows

#: a run of at least this many samples is read decimated (33 min at 500 Hz; 100 s at 10 kHz)
LONG_RUN_SAMPLES = 1_000_000
#: samples per excitation cycle a long run keeps (loops need ~100; margin ×2)
SAMPLES_PER_CYCLE = 200
#: the position/pressure cut-off stays below this share of the decimated Nyquist frequency
ANTI_ALIAS_FRACTION = 0.6
#: samples read per block (2 MB a channel in float64)
BLOCK = 1 << 18
#: a long record's run-level fit uses its first this many whole cycles (:func:`fit_part`)
FIT_CYCLES = 500
#: channels low-passed before they are decimated (they drive the model)
FILTERED = ("position", "muscle_pressure", "cylinder_pressure")


def decimation_plan(sample_rate_Hz: float, frequency_Hz: float | None) -> tuple[int, float]:
    """``(stride, cut-off Hz)`` of a long run's decimation: the stride keeps at least
    :data:`SAMPLES_PER_CYCLE` samples per cycle; the cut-off is the fits' own (60× f) held
    below :data:`ANTI_ALIAS_FRACTION` of the decimated Nyquist frequency.  Stride 1 when
    the frequency is unknown."""
    # the filter's module (numba) is imported when a long run is met: reading a
    # campaign of ordinary runs needs NumPy and h5py only (pmalab.identify.reading)
    from pmalab.identify.signals import default_cutoff_Hz

    if not frequency_Hz or frequency_Hz <= 0:
        return 1, default_cutoff_Hz(sample_rate_Hz, None)
    # measured stamps jitter: a rate 0.1 % under a whole multiple still counts as it
    stride = max(1, int(sample_rate_Hz / (SAMPLES_PER_CYCLE * frequency_Hz) * 1.001))
    nyquist = 0.5 * sample_rate_Hz / stride
    cut = min(default_cutoff_Hz(sample_rate_Hz, frequency_Hz), ANTI_ALIAS_FRACTION * nyquist)
    return stride, float(cut)


def decimate(w: RunWindows, block: int = BLOCK) -> Run:
    """The run of ``w`` decimated as the module docstring states, read ``block`` samples at
    a time; its attrs carry ``decimation`` (what was done, for the record)."""
    from pmalab.identify.signals import zero_phase_lowpass

    f = w.frequency_Hz
    dt = w.sample_interval_s()
    fs = 1.0 / dt
    stride, cut = decimation_plan(fs, f)
    if stride == 1:
        run = w.run()
        run.attrs["decimation"] = {
            "stride": 1,
            "samples_read": w.n,
            "samples_kept": w.n,
            "note": "read whole: "
            + ("its excitation frequency is unknown" if f is None else "already ≤ 200/cycle"),
        }
        return run
    block = max(stride, block - block % stride)  # cores start on the stride's grid
    margin = int(math.ceil(10.0 * fs / cut)) + 64  # ≫ the filter's memory (~1/(4 fc) s)
    m = -(-w.n // stride)
    out: dict[str, np.ndarray] = {}
    i = 0
    for a, b, ch in w.blocks(block, margin):
        if not out:
            out = {c: np.empty(m) for c in ch}
        t = ch["time"]
        k = len(range(a, b, stride))
        for c, v in ch.items():
            if c in FILTERED:
                v = zero_phase_lowpass(t, v, cut)
            out[c][i : i + k] = v[a:b:stride]
        i += k
    attrs: dict[str, Any] = dict(w.attrs)
    attrs["decimation"] = {
        "stride": stride,
        "samples_read": w.n,
        "samples_kept": m,
        "sample_interval_s": dt,
        "decimated_rate_Hz": fs / stride,
        "samples_per_cycle": fs / stride / f if f else None,
        "cutoff_Hz": cut,
        "method": (
            "position and pressures: zero-phase 4th-order Butterworth low-pass "
            f"at {cut:.4g} Hz, then every {stride}th sample; force and time: every "
            f"{stride}th sample (force noise stays white); read in blocks of {block} samples"
        ),
    }
    if attrs.get("sample_rate_Hz") is not None:
        attrs["recorded_sample_rate_Hz"] = attrs["sample_rate_Hz"]
        attrs["sample_rate_Hz"] = fs / stride
    return Run(name=w.name, attrs=attrs, file=str(w.path), **out)


def fit_part(run: Run, cycles: int | None = None) -> Run:
    """What a fit of the whole run uses: a long record (one read decimated) of more than
    ``cycles`` excitation cycles is fitted on its first ``cycles`` whole cycles — the muscle
    as the test began; how it changes after is its parameter trajectory
    (:mod:`pmalab.identify.campaign.trajectory`), fitted along all of it.  One set of
    constant parameters through hours of a drifting muscle is a compromise no single cycle
    shows (on a 10-hour fatigue record it is not even near the start or the end), and its
    free-run fit costs gigabytes.  Other runs are returned as they are.  The part's attrs
    say what it is (``fit_part``)."""
    cycles = FIT_CYCLES if cycles is None else int(cycles)
    dec = run.attrs.get("decimation")
    f = run.frequency
    if not dec or int(dec.get("stride", 1)) <= 1 or not f or len(run) < 2:
        return run
    t0 = float(run.time[0])
    # the first full-amplitude cycles: from the recorded steady window's start, unless the
    # run was already cut to it (Run.steady leaves "window_s"), so identify (which cuts
    # first) and diagnose (which cuts after) fit and hold out the same samples
    s0 = 0.0 if "window_s" in run.attrs else float(run.attrs.get("steady_start_s") or 0.0)
    span = cycles / f
    if float(run.time[-1]) - t0 - s0 <= span:
        return run
    part = run.window(s0, s0 + span - 0.5 * float(np.median(np.diff(run.time[:4096]))))
    part.attrs.pop("window_s", None)
    total = (float(run.time[-1]) - t0 - s0) * f
    part.attrs["fit_part"] = {
        "cycles": cycles,
        "of_cycles": round(total, 1),
        "time_s": [s0, s0 + span],
        "note": "the run-level fit uses the first cycles; the trajectory covers the record",
    }
    for key in ("steady_start_s", "steady_end_s"):
        part.attrs.pop(key, None)
    return part


def long_runs(min_samples: int | None = None) -> LongRuns:
    """What analysis passes to :func:`~pmalab.runfile.read_runs`: runs of at least
    ``min_samples`` samples (default :data:`LONG_RUN_SAMPLES`) are read decimated
    (:func:`decimate`)."""
    n = LONG_RUN_SAMPLES if min_samples is None else int(min_samples)
    return LongRuns(min_samples=n, read=decimate)
