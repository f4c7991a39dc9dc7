"""Channel health: a sensor that stopped, dropped out or spiked is refused before any fit.

A measured channel carries its own noise: the position, force and pressure a rig records
differ from one sample to the next by a few least-significant bits at least.  Two
failures read as plausible numbers and would be fitted as data:

* **stuck** — the same value repeated for :data:`STUCK_SAMPLES` samples or more (a block of
  zeros on disk, a frozen link that repeats its last reading, a sensor held at a rail).
  Judged only where the channel's noise is at least :data:`RESOLVED_NOISE` of its
  resolution (the smallest step it makes): a well-resolved noisy channel repeats a value
  16 times running with a probability below 1e-15; a coarsely quantised one (a slow
  pressure gauge) legitimately repeats and is not judged;
* **spike** — one sample away from both neighbours by more than :data:`SPIKE_NOISE` noise
  levels and beyond what the quantity can do in one sample interval (the position: out and
  back within :data:`MAX_ACCEL_MM_S2`), while the neighbours agree with each other: a
  flipped bit or a transmission error, not motion.

Channels a run was given as constants (``--pressure``, ``--position`` of an import) are not
judged.  Each finding is one line naming the file, run, channel and sample.
"""

from __future__ import annotations

import numpy as np

from pmalab.errors import RunFileError

#: repeated identical samples that make a channel stuck
STUCK_SAMPLES = 16
#: a channel is judged for stuck stretches when its noise is at least this many resolution steps
RESOLVED_NOISE = 3.0
#: noise below this fraction of a channel's magnitude is round-off, not a sensor's (a real
#: sensor's noise is 1e-4 to 1e-2 of its reading)
RELATIVE_NOISE = 1e-5
#: a spike departs from both neighbours by more than this many noise levels ...
SPIKE_NOISE = 12.0
#: ... and (position) out and back faster than a muscle accelerates: a spike of height h in
#: one sample interval dt needs an acceleration of about 2h/dt²; 100 m/s² (10 g) is beyond a
#: muscle pulling a test rig's cylinder and load cell
MAX_ACCEL_MM_S2 = 1e5
#: the channels judged, with the least change (canonical units) a spike must make: below
#: it a sample is within any sensor's glitch-free error
JUDGED = {"position": 0.2, "force": 5.0, "muscle_pressure": 0.02}


def noise_level(y: np.ndarray) -> float:
    """Sample-to-sample noise of ``y``: the MAD of its third differences / √20 (smooth motion
    cancels in a third difference — a noise-free simulated or derived record has almost no
    noise by this measure — while white noise of σ gives σ·√20)."""
    d3 = np.diff(y, 3)
    if d3.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d3 - np.median(d3))) / np.sqrt(20.0))


def roughness(y: np.ndarray) -> float:
    """Sample-to-sample scatter of ``y`` including its motion's curvature: the MAD of its
    second differences / √6 (σ for white noise; larger for a signal fast against the sample
    rate, e.g. a 150 Hz sweep at 750 Hz, whose samples then legitimately zig-zag)."""
    d2 = np.diff(y, 2)
    if d2.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def resolution(y: np.ndarray) -> float:
    """The smallest non-zero step between consecutive samples (a quantised channel's LSB)."""
    d = np.abs(np.diff(y))
    d = d[d > 0]
    return float(d.min()) if d.size else 0.0


def _longest_repeat(y: np.ndarray) -> tuple[int, int]:
    """(start, length) of the longest stretch of identical consecutive values."""
    same = np.concatenate(([False], y[1:] == y[:-1], [False]))
    edges = np.flatnonzero(np.diff(same.astype(np.int8)))
    if edges.size == 0:
        return 0, 1
    starts, stops = edges[::2], edges[1::2]
    k = int(np.argmax(stops - starts))
    return int(starts[k]), int(stops[k] - starts[k]) + 1


def check_health(
    path: str,
    run: str,
    chans: dict[str, np.ndarray],
    skip: tuple[str, ...] = (),
) -> None:
    """Refuse a run one of whose measured channels is stuck or spiked (module docstring).

    Parameters
    ----------
    path, run
        Where the run came from (for the message).
    chans
        Channels in canonical units (s, mm, N, MPa), equal lengths.
    skip
        Channels given as constants rather than measured.
    """
    t = chans["time"]
    if t.shape[0] < 8:
        return
    dt = float(np.median(np.diff(t)))
    for ch, least in JUDGED.items():
        if ch in skip or ch not in chans:
            continue
        y = np.asarray(chans[ch], dtype=np.float64)
        sigma, lsb = noise_level(y), resolution(y)
        where = f"{path}: run '{run}': channel '{ch}'"
        # a measured channel's noise, not float round-off of a noise-free (simulated, derived)
        # record: at least RELATIVE_NOISE of its magnitude and RESOLVED_NOISE of its steps
        real_noise = sigma >= RELATIVE_NOISE * (float(np.max(np.abs(y))) + 1.0)
        if lsb > 0 and real_noise and sigma >= RESOLVED_NOISE * lsb:
            start, n = _longest_repeat(y)
            if n >= STUCK_SAMPLES:
                raise RunFileError(
                    f"{where}: stuck at {y[start]:.6g} for {n} samples from sample {start} "
                    f"(its noise is {sigma:.3g}, its resolution {lsb:.3g}): a dead sensor, a "
                    "dropped link or damaged data — not fitted"
                )
        rough = roughness(y)
        limit = max(SPIKE_NOISE * rough, least)
        if ch == "position":
            limit = max(limit, 0.5 * MAX_ACCEL_MM_S2 * dt * dt)
        a, b, c = y[:-2], y[1:-1], y[2:]
        dev = np.minimum(np.abs(b - a), np.abs(b - c))
        spike = (dev > limit) & (np.sign(b - a) == np.sign(b - c)) & (np.abs(a - c) < limit / 2)
        if np.any(spike):
            i = int(np.flatnonzero(spike)[0]) + 1
            raise RunFileError(
                f"{where}: sample {i} jumps to {y[i]:.6g} from {y[i - 1]:.6g} and back "
                f"({dev[i - 1]:.3g} away from both neighbours; the channel's scatter is "
                f"{rough:.3g}): a spike no {ch.replace('_', ' ')} makes in "
                f"{dt * 1e3:.3g} ms — damaged data, not fitted"
            )
