"""Checks an import makes once the channels are in canonical units: the run must look like a
PMA test in the units it claims, or it is refused with the likely fix.

:func:`pmalab.runfile.validate_channels` refuses values no test can reach (a pressure of
400 MPa is kPa); these checks catch the mix-ups that stay inside those bounds:

* a length that moves smoothly over a fraction of a millimetre (metres written as mm: a
  20 mm stroke reads 0.02), a force that swings smoothly by a few newtons at most (kN), a
  muscle pressure that never reaches 5 kPa (MPa labelled kPa), a time step of seconds
  (milliseconds labelled s) — each refused with the ``--units`` that fixes it;
* too few samples to identify anything, a force channel that never changes (an unconnected
  column), and a time gap longer than :data:`MAX_GAP_S` and :data:`MAX_GAP_STEPS` steps
  (two records run together: filters and hysteresis states would bridge it).

"Smooth" is measured against the channel's own sample-to-sample noise: a held length in mm
moves by its noise (span/noise of a few), a stroke written in metres by thousands of noise
steps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pmalab.errors import RunFileError

#: fewer samples than this are no test (the fitter needs whole cycles of hundreds)
MIN_SAMPLES = 50
#: a time step longer than this (s) and this many median steps is a gap between records
MAX_GAP_S = 1.0
MAX_GAP_STEPS = 50.0
#: span (5th–95th percentile) over sample-to-sample noise above which a channel moves
SMOOTH_RATIO = 50.0


def _noise(y: np.ndarray) -> float:
    """Sample-to-sample noise of ``y`` (robust: the MAD of its first differences / √2)."""
    d = np.diff(y)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def _span(y: np.ndarray) -> float:
    lo, hi = np.percentile(y, [5.0, 95.0])
    return float(hi - lo)


def _smooth(y: np.ndarray) -> bool:
    s, n = _span(y), _noise(y)
    return s > 0 and (n == 0 or s / n > SMOOTH_RATIO)


def check_import(
    path: str | Path,
    run: str,
    chans: dict[str, np.ndarray],
    units: dict[str, str],
    *,
    held_position: bool,
    pressure_given: bool,
) -> None:
    """Refuse (one :class:`RunFileError` line naming file, run and channel, with the fix)
    an imported run that cannot be a PMA test in the units it claims.

    Parameters
    ----------
    path, run
        Where the run came from (for the message).
    chans
        The channels in canonical units (s, mm, N, MPa).
    units
        The unit each channel was read in (as declared or defaulted).
    held_position, pressure_given
        The length or the pressure was given as a constant (``--position``, ``--pressure``).
    """
    where = f"{path}: run '{run}'"
    t = chans["time"]
    n = t.shape[0]
    if n < MIN_SAMPLES:
        raise RunFileError(
            f"{where}: only {n} samples: too short to identify (a test needs ≥ {MIN_SAMPLES}); "
            "a truncated export?"
        )
    dt = np.diff(t)
    step = float(np.median(dt))
    if step >= 0.1:
        hz = 1.0 / step
        hint = (
            "; milliseconds? add --units time=ms"
            if units.get("time") == "s" and 10.0 <= 1e3 * hz <= 1e5
            else ""
        )
        raise RunFileError(
            f"{where}: channel 'time': steps of {step:g} s ({hz:.3g} Hz sampling): no PMA test "
            f"is sampled that slowly{hint}"
        )
    gap = int(np.argmax(dt))
    if dt[gap] > MAX_GAP_S and dt[gap] > MAX_GAP_STEPS * step:
        raise RunFileError(
            f"{where}: channel 'time': jumps {dt[gap]:.4g} s at sample {gap + 1} (the median "
            f"step is {step * 1e3:.3g} ms): a gap between records; import the parts as "
            "separate files"
        )
    f = chans["force"]
    if np.ptp(f) == 0:
        raise RunFileError(
            f"{where}: channel 'force': constant ({f[0]:g} N in every sample): a dead sensor "
            "or an unconnected column"
        )
    if _smooth(f) and np.max(np.abs(f)) < 5.0 and units.get("force") == "N":
        raise RunFileError(
            f"{where}: channel 'force': swings smoothly between {f.min():.4g} and "
            f"{f.max():.4g} N only: kilonewtons? add --units force=kN"
        )
    x = chans["position"]
    if (
        not held_position
        and _smooth(x)
        and _span(x) < 0.2
        and 1.0 <= 1e3 * _span(x) <= 500.0
        and units.get("position") == "mm"
    ):
        raise RunFileError(
            f"{where}: channel 'position': moves smoothly over {_span(x):.4g} mm only: "
            "metres? add --units position=m"
        )
    p = chans["muscle_pressure"]
    if not pressure_given and np.max(p) < 0.005 and _smooth(p):
        u = units.get("muscle_pressure", "MPa")
        fix = {"kPa": "MPa", "Pa": "kPa", "MPa": "bar"}.get(u)
        raise RunFileError(
            f"{where}: channel 'muscle_pressure': peaks at {np.max(p) * 1e3:.3g} kPa (read as "
            f"{u}): no muscle works there"
            + (f"; the values look like {fix}: --units pressure={fix}" if fix else "")
        )
