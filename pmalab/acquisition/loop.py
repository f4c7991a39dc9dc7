"""The one real-time sample loop: ``pmalab run`` (recording) and ``pmalab control`` both
run through :func:`sample_loop`.

Per sample period:

1. **signals** — SIGINT/SIGTERM (and the live view's stop request) are deferred to a flag
   (:func:`deferred_signals`) acted on here, at the top of the loop, so a file is never
   left half-way through a sample; a second signal raises at once;
2. **pacing**, a strategy chosen by the sampler (:func:`pacing_for`):
   :class:`DeadlinePacing` for software-polled samplers — wait for t0 + k/rate on the
   rig's clock (a virtual clock jumps there, a host clock sleeps), lateness is measured
   when the request starts; :class:`DeviceClockPacing` for hardware-timed samplers — the
   device's sample clock stamps every sample, lateness is stamp − deadline and a hole in
   the stamps is a recorded gap;
3. **limits on every sample** (``check``, the :class:`~pmalab.acquisition.safety.SafetyMonitor`,
   over the rig's declared channels):
   a trip calls ``on_trip`` (the caller vents in the same period and keeps the sample)
   and raises :class:`Trip`;
4. the sample goes to ``step``, which returns the command for the next period; the
   command is sent once per block (a hardware-timed block holds several samples);
5. **missed deadlines**: deadlines that passed entirely while the loop was busy are
   counted and recorded as a gap (``stats.add_gap``) — never invented samples.

Lateness above ``late_threshold_s`` is counted in ``stats.n_late``.  ``stats`` is the run
file's writer (:class:`pmalab.acquisition.recorder.RunWriter` has ``n_late``,
``n_missed`` and ``add_gap``) or a :class:`LoopStats`.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from operator import attrgetter
from typing import Any, Protocol

from pmalab.rig.base import SINGLE_MUSCLE_CHANNELS, Clock, Sampler, sampled

#: ``pending["sig"]`` value of a stop request (not a signal number)
STOP_REQUEST = -1
#: the single-muscle rig's sampled channels (a sample's values, in this order)
SAMPLED: tuple[str, ...] = sampled(SINGLE_MUSCLE_CHANNELS)
#: one sample's values, in the order of the loop's ``channels``
Sample = tuple[float, ...]
#: a sample whose request starts (software-polled) or whose stamp lies (hardware-timed)
#: later than this after its deadline counts as late
LATE_THRESHOLD_S = 0.5e-3


class Trip(Exception):
    """A limit tripped on a sample (reason in ``args[0]``)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, acted on at the next sample."""


class Stopped(KeyboardInterrupt):
    """The operator's stop request (live view): the same safe abort as Ctrl-C."""


class Stats(Protocol):
    n_late: int
    n_missed: int

    # positional-only: RunWriter and LoopStats name the parameters differently
    def add_gap(self, t_rel: float, n: int, /) -> None: ...


@dataclass
class LoopStats:
    """Timing counts of one loop when no run-file writer keeps them."""

    n_late: int = 0
    n_missed: int = 0
    gaps: list[tuple[float, int]] = field(default_factory=list)

    def add_gap(self, t_rel: float, n: int) -> None:
        self.gaps.append((float(t_rel), int(n)))


@contextlib.contextmanager
def deferred_signals(pending: dict[str, int | None]) -> Iterator[None]:
    """Turn SIGINT/SIGTERM into ``pending["sig"]``, which the loop checks once per sample.

    An exception raised at an arbitrary bytecode could land between two HDF5 writes or
    half-way through buffering a sample; acting on the flag at the top of the loop keeps
    the file consistent and still vents within a sample period.  A second signal raises
    at once (an operator hammering Ctrl-C means it).  Main thread only.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        if pending["sig"] is not None:
            raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
        pending["sig"] = signum

    old_int = signal.signal(signal.SIGINT, handler)
    old_term = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)


def check_signal(pending: dict[str, int | None]) -> None:
    """Raise what a deferred signal asks for (and clear it)."""
    sig = pending["sig"]
    if sig is not None:
        pending["sig"] = None
        if sig == STOP_REQUEST:
            raise Stopped()
        raise Terminated() if sig == signal.SIGTERM else KeyboardInterrupt()


# --------------------------------------------------------------------------- pacing
class DeadlinePacing:
    """Software-polled sampler: one request per deadline t0 + k·dt on the rig's clock."""

    hardware = False

    def __init__(self, clock: Clock, dt: float) -> None:
        self.clock, self.dt = clock, dt
        self.t0 = clock.now()

    def wait(self, k: int) -> float:
        """Sleep until deadline k; the lateness (s) of the request's start."""
        deadline = self.t0 + k * self.dt
        self.clock.sleep_until(deadline)
        return self.clock.now() - deadline

    def missed(self, k: int) -> int:
        """Deadlines after k that passed entirely while the loop was busy."""
        lag = self.clock.now() - (self.t0 + k * self.dt)
        return int(lag / self.dt) if lag > self.dt else 0


class DeviceClockPacing:
    """Hardware-timed sampler: the device's sample clock paces and stamps the samples."""

    hardware = True

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.t0: float | None = None
        self.last: float | None = None

    def stamp(self, t: float, k: int) -> tuple[int, float]:
        """(samples missing before this one, its lateness against deadline k + missing)."""
        if self.t0 is None:
            self.t0 = t
            self.last = t
            return 0, 0.0
        gap = 0
        assert self.last is not None
        if t - self.last > 1.5 * self.dt:  # a hole in the stream
            gap = int(round((t - self.last) / self.dt)) - 1
        self.last = t
        return gap, t - (self.t0 + (k + gap) * self.dt)


def pacing_for(sampler: Sampler, clock: Clock, dt: float) -> DeadlinePacing | DeviceClockPacing:
    """The pacing strategy the sampler needs (device clock for hardware-timed samplers)."""
    return DeviceClockPacing(dt) if sampler.hardware_timed else DeadlinePacing(clock, dt)


# --------------------------------------------------------------------------- the loop
def sample_loop(
    clock: Clock,
    sampler: Sampler,
    rate_Hz: float,
    n_total: int,
    *,
    check: Callable[[Sample], str | None],
    step: Callable[[int, float, Sample, float], Any],
    command: Callable[[Any], None],
    on_trip: Callable[[str, float, Sample, float], None],
    pending: dict[str, int | None],
    stats: Stats,
    late_threshold_s: float,
    after_block: Callable[[int], None] | None = None,
    channels: Sequence[str] = SAMPLED,
) -> float:
    """Run the sample loop (module docstring) for ``n_total`` deadlines at ``rate_Hz``.

    ``channels``: the sampled channels a sample holds, in order (the rig's declaration
    without time and commands, :func:`pmalab.rig.base.sampled`); the loop names none of
    them.  ``check(values)`` returns a trip reason or None; ``step(k, t_rel, values,
    lateness)`` gets every delivered sample (t_rel from the first deadline, s) and returns
    the command for the next period (whatever ``command`` takes: one pressure, or one per
    regulator) or None to keep the last; ``command(u)`` sends it once per block.  A trip
    calls ``on_trip(reason, t_rel, values, lateness)`` and raises :class:`Trip`
    (``"<reason> at t=<t_rel> s"``).  ``after_block(k)`` runs after each block (flushes,
    progress).  Returns t0, the time of deadline 0 on the sampler's time base.
    """
    dt = 1.0 / rate_Hz
    pace = pacing_for(sampler, clock, dt)
    names = tuple(channels)
    # the single-muscle fields in one C call; a declaration with other channels by name
    fields = {"position", "force", "muscle_pressure", "cylinder_pressure"}
    getter = attrgetter(*names) if names and set(names) <= fields else None
    k = 0
    cmd: Any = None
    t0 = getattr(pace, "t0", None) or 0.0
    while k < n_total:
        if pending["sig"] is not None:
            check_signal(pending)
        lateness = 0.0
        if isinstance(pace, DeadlinePacing):
            lateness = pace.wait(k)
            t0 = pace.t0
        blk = sampler.read_block()
        arrs = getter(blk) if getter is not None and not blk.extra else None
        if arrs is None or len(names) == 1:
            arrs = [blk.column(c) for c in names]
        times = blk.time.tolist()
        one = len(times) == 1  # a software-polled sample: no per-column lists
        cols = [] if one else [a.tolist() for a in arrs]
        for j, t in enumerate(times):
            v: Sample = tuple([a.item(0) for a in arrs]) if one else tuple([c[j] for c in cols])
            if isinstance(pace, DeviceClockPacing):
                gap, lateness = pace.stamp(t, k)
                assert pace.t0 is not None
                t0 = pace.t0
                if gap:
                    stats.n_missed += gap
                    stats.add_gap(t - t0 - gap * dt, gap)
                    k += gap
                    if k >= n_total:
                        break
            reason = check(v)
            if reason is not None:
                on_trip(reason, t - t0, v, lateness)
                raise Trip(f"{reason} at t={t - t0:.3f} s")
            if lateness > late_threshold_s:
                stats.n_late += 1
            u = step(k, t - t0, v, lateness)
            if u is not None:
                cmd = u
            k += 1
            if k >= n_total:
                break
        if cmd is not None:
            command(cmd)
        if after_block is not None:
            after_block(k)
        if isinstance(pace, DeadlinePacing):
            skip = pace.missed(k)
            if skip:
                stats.n_missed += skip
                stats.add_gap(k * dt, skip)
                k += skip
    return float(t0 or 0.0)
