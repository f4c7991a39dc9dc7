"""A run of a run file read a window of samples at a time, never whole.

A fatigue or creep test records for hours: 10 hours at 500 Hz is 18 million samples per
channel, 10 kHz for an hour twice that.  :func:`~pmalab.runfile.read_runs` reads a run's
datasets whole and converts each to float64 (the channels of such a run alone are
gigabytes), so a long run is instead handed, still on disk, as a :class:`RunWindows`: the
run's attrs and length, and :meth:`RunWindows.read` for any window of samples, checked and
converted to canonical units like a whole run (:func:`~pmalab.runfile.validate_channels`).
:meth:`RunWindows.cycle_windows` cuts the run into whole excitation cycles (the
``blocks_of`` rule of diagnosis: only whole cycles are comparable).

Who reads a long run this way says so to :func:`~pmalab.runfile.read_runs` with a
:class:`LongRuns` (the run length from which it applies and what to make of the windows,
e.g. identification's anti-aliased decimation, :mod:`pmalab.identify.long_records`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmalab.errors import RunFileError
from pmalab.runfile import Run, damage_words, validate_channels

#: samples read to estimate the sample interval of a run without a nominal rate
_RATE_PROBE = 4096


class RunWindows:
    """One run of an open run file, read a window at a time (canonical units).

    Parameters
    ----------
    path, name:
        the file and the run (for messages and :attr:`Run.file`).
    datasets:
        ``{canonical channel: (open HDF5 dataset, its units attr)}`` (valid while the file
        is open; a multi-muscle run's channels already picked for one muscle).
    n:
        samples every channel holds (a killed writer's run is cut to the shortest).
    attrs:
        the run's attrs as :func:`~pmalab.runfile.read_runs` decoded them.
    exempt_last:
        the run's last sample is not held to the plausible ranges (an aborted run keeps
        the reading that tripped its limit).
    """

    def __init__(
        self,
        path: Path,
        name: str,
        datasets: dict[str, tuple[Any, str | None]],
        n: int,
        attrs: dict[str, Any],
        *,
        exempt_last: bool = False,
    ) -> None:
        self.path, self.name, self.n, self.attrs = Path(path), name, int(n), attrs
        self.exempt_last = exempt_last
        self.datasets = dict(datasets)

    def __len__(self) -> int:
        return self.n

    @property
    def frequency_Hz(self) -> float | None:
        """The excitation frequency (Hz) the run's attrs state, or None."""
        f = self.attrs.get("frequency_Hz")
        try:
            v = float(f) if f is not None else 0.0
        except (TypeError, ValueError):
            return None
        return v if v > 0 and np.isfinite(v) else None

    def sample_interval_s(self) -> float:
        """Median interval between the measured time stamps of the run's first samples (s)."""
        t = self.read(0, min(self.n, _RATE_PROBE))["time"]
        return float(np.median(np.diff(t)))

    def read(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Channels of samples ``start ≤ i < stop``, checked and in canonical units.

        A fault names the file, run and channel and where the window starts."""
        start, stop = max(0, int(start)), min(self.n, int(stop))
        raw = {}
        for ch, (ds, units) in self.datasets.items():
            try:
                raw[ch] = (ds[start:stop], units)
            except (OSError, RuntimeError) as exc:  # a chunk failing its checksum, say
                raise RunFileError(
                    f"{self.path}: run '{self.name}': channel '{ch}': {damage_words(exc)} "
                    f"(in the window of samples {start}–{stop - 1})"
                ) from None
        try:
            return validate_channels(
                self.path, self.name, raw, exempt_last=self.exempt_last and stop == self.n
            )
        except RunFileError as exc:
            raise RunFileError(f"{exc} (in the window of samples {start}–{stop - 1})") from None

    def run(self, start: int = 0, stop: int | None = None) -> Run:
        """Samples ``start ≤ i < stop`` as an in-memory :class:`Run` (attrs copied)."""
        stop = self.n if stop is None else stop
        chans = self.read(start, stop)
        attrs = dict(self.attrs)
        if (start, stop) != (0, self.n):
            attrs["samples"] = [int(start), int(stop)]
        return Run(name=self.name, attrs=attrs, file=str(self.path), **chans)

    def cycle_windows(self, cycles: int = 1) -> list[tuple[int, int]]:
        """``(start, stop)`` sample ranges of ``cycles`` whole excitation cycles each, from
        the run's first sample; the last incomplete window is left out; [] when the
        frequency is unknown or the run is shorter than one window."""
        f = self.frequency_Hz
        if f is None or self.n < 2:
            return []
        per = int(round(cycles / (f * self.sample_interval_s())))
        if per < 2:
            return []
        return [(i * per, (i + 1) * per) for i in range(self.n // per)]

    def blocks(
        self, size: int, margin: int = 0
    ) -> Iterator[tuple[int, int, dict[str, np.ndarray]]]:
        """The run in consecutive cores ``[a, b)`` of ``size`` samples, each read with up to
        ``margin`` samples either side (for filters): ``(a − lo, b − lo, channels)``, where
        ``lo`` is the first sample read, so ``channels[c][a − lo : b − lo]`` is the core.

        Consecutive reads overlap by at least one sample, so time is checked increasing
        across their joins as within them."""
        size = max(2, int(size))
        margin = max(1, int(margin))
        for a in range(0, self.n, size):
            b = min(self.n, a + size)
            lo, hi = max(0, a - margin), min(self.n, b + margin)
            yield a - lo, b - lo, self.read(lo, hi)


@dataclass(frozen=True)
class LongRuns:
    """How a reader wants runs of at least ``min_samples`` samples: handed to ``read`` as
    :class:`RunWindows` (still on disk), which returns the run to use."""

    min_samples: int
    read: Callable[[RunWindows], Run]

    def take(
        self,
        path: Path,
        name: str,
        datasets: dict[str, tuple[Any, str | None]],
        n: int,
        attrs: dict[str, Any],
        *,
        exempt_last: bool = False,
    ) -> Run:
        """The run :func:`~pmalab.runfile.read_runs` returns for this long run."""
        return self.read(RunWindows(path, name, datasets, n, attrs, exempt_last=exempt_last))
