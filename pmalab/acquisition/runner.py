"""The 500 Hz runner: protocol → rig → crash-proof HDF5, with safety on every sample.

Timing.  A software-polled sampler is read at absolute deadlines ``t0 + k/rate`` on the
rig's clock (``RealClock.sleep_until`` sleeps, then spins; a ``VirtualClock`` jumps, so a
simulated run goes as fast as the physics allows), ``rate`` being the rate recorded at
(reduced or not).  Each sample keeps its actual timestamp (a Modbus sampler stamps the
middle of its request).  Its lateness is measured against its own scheduled time: the
moment its request started minus its deadline — so a slow link read steadily at a
reduced rate is on time, however long each request takes.  Samples later than
``late_threshold_s`` are counted as *late*, and deadlines that passed entirely (more than
one period overdue) are counted as *missed* and skipped — never dropped silently: the
counts go into the run's ``timing`` dataset and the CLI summary.  A hardware-timed
sampler paces itself; gaps in its timestamps count as missed samples, its lateness is the
timestamp minus its place on the nominal grid.  A run that missed more than
``timing_warn_fraction`` (1 %) of its scheduled samples, or had more than that share late,
gets ``timing_warning = 1`` in its ``timing`` dataset and a warning line at the end of
``pmalab run`` (:attr:`RunResult.warning`).

Safety.  :func:`pmalab.acquisition.safety.preflight` refuses a protocol before the file
is created or any device is commanded.  Every sample is checked against the rig's limits;
on a trip, Ctrl-C (``KeyboardInterrupt``), any exception or a device fault
(``RigError``), the cylinder regulator is vented at once (same sample period, before the
next deadline), then the muscle supply, the run is closed as ``aborted: <reason>`` with
its samples, and :class:`~pmalab.errors.SafetyAbort` is raised.  Its one line states, per
regulator, whether the vent was confirmed by the device (:class:`~pmalab.rig.base.VentReport`)
and, when it was not, that it FAILED and what the operator must do; a vent that failed is
tried once more after the file is closed, and the message reports the better outcome.
Every exit path — completed or not — ends with a vent (``rig.last_vent`` holds the last
outcome, which ``pmalab run`` reports).

Reduced rate.  A rig loaded with ``allow_reduced_rate = true`` whose link probe found the
protocol's rate unsustainable has ``rig.info["timing"]["reduced"]`` set and a lower
``rig.sampler.sample_rate_Hz``; the runner then keeps its deadlines at that rate, records
it as each run's ``sample_rate_Hz`` (with ``requested_sample_rate_Hz`` = the protocol's)
and prints one warning line.  A run whose waveform would get fewer than 20 samples per
period at that rate is refused before anything moves.

Observers.  ``RunnerOptions.observer`` (e.g. the live view, :mod:`pmalab.acquisition.live`)
is told when a run starts (it may tap the writer's ``add`` with a non-blocking hand-off)
and how it ended; its failures are ignored (a display never stops a recording).
``RunnerOptions.request_stop()`` — the live view's stop button — asks for the same safe
abort as Ctrl-C, acted on at the next sample.

Device statistics.  When the sampler has ``stats()`` (the drivers' link/ITV/indicator
fault counters: retries, timeouts, reconnects, bad frames, ...), its JSON is stored in
each run's ``device_stats`` dataset at the run's end — completed or aborted.
"""

from __future__ import annotations

import contextlib
import gc
import json
import math
import os
import re
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pmalab import __version__
from pmalab.acquisition.loop import (
    LATE_THRESHOLD_S,
    STOP_REQUEST,
    Sample,
    Stopped,
    Terminated,
    Trip,
    check_signal,
    deferred_signals,
    sample_loop,
)
from pmalab.acquisition.protocol import Protocol, RunSpec
from pmalab.acquisition.recorder import (
    Recorder,
    RunWriter,
    check_free_space,
    estimated_file_size,
)
from pmalab.acquisition.safety import (
    ProtocolRefused,
    SafetyMonitor,
    effective_limits,
    preflight,
)
from pmalab.acquisition.waveforms import command_block
from pmalab.errors import RigError, SafetyAbort
from pmalab.paths import check_output, output_failure
from pmalab.rig.base import Rig, VentReport, sampled


class RunObserver:
    """Watches a recording (the live view).  Called from the sample loop's thread, so each
    method must return at once; exceptions are ignored."""

    def run_started(self, index: int, spec: RunSpec, writer: RunWriter) -> None:
        """Run ``index`` of the protocol starts (muscle pressure not yet settled).  May
        replace ``writer.append`` (``(row, lateness)``, the row in ``writer.channels``
        order) by a tap that calls it and hands the sample on without blocking."""

    def run_ended(self, index: int, spec: RunSpec, status: str, message: str) -> None:
        """The run ended: ``status`` as stored ("completed" | "aborted: <reason>");
        ``message`` the abort's one-line message (empty when completed)."""


@dataclass
class RunResult:
    """What one run recorded.

    Attributes
    ----------
    name, status
        The run's name and how it ended (``completed`` or ``aborted: <reason>``).
    n_samples, duration_s
        Samples recorded and their time span, s.
    force_min, force_max
        The tension's range, N.
    timing
        Lateness statistics (s) and the counts of late and missed samples; missed
        deadlines are gaps in the file, never filled in.
    hardware_timed
        The samples were stamped by the device's clock (a gap is the device's).
    """

    name: str
    status: str
    n_samples: int
    duration_s: float
    force_min: float
    force_max: float
    timing: dict[str, float] = field(default_factory=dict)
    #: the samples were stamped by the device's clock (a gap is the device's, not ours)
    hardware_timed: bool = False

    @property
    def warning(self) -> str | None:
        """One line when the run missed or was late on more than the warn fraction of its
        samples (``timing_warning`` in its timing record), or when a device on its own
        clock skipped any samples; else None."""
        t = self.timing
        if not t.get("timing_warning"):
            missed = int(t.get("missed", 0))
            if self.hardware_timed and missed:
                return (
                    f"run '{self.name}': the device skipped {missed} sample(s) (its "
                    "buffer overflowed); recorded as gaps in the run's 'gaps' dataset, "
                    "nothing filled in"
                )
            return None
        late, missed = int(t.get("late", 0)), int(t.get("missed", 0))
        scheduled = self.n_samples + missed
        limit = 100 * t.get("warn_fraction", 0.01)
        return (
            f"run '{self.name}' did not keep its sample rate: {missed} of {scheduled} "
            f"scheduled samples missed ({100 * t.get('missed_fraction', 0.0):.1f} %), "
            f"{late} of {self.n_samples} late ({100 * t.get('late_fraction', 0.0):.1f} %; "
            f"more than {limit:g} % is a warning); the recorded samples keep their real "
            "timestamps"
        )

    def summary(self) -> str:
        t = self.timing
        frange = (
            f"force {self.force_min:.0f}…{self.force_max:.0f} N" if self.n_samples else "no samples"
        )
        lat = ""
        if t.get("lateness_max_s", 0.0) > 0:  # real clock: how well the deadlines were kept
            lat = (
                f" (lateness p99 {t.get('lateness_p99_s', 0.0) * 1e3:.3f} ms, "
                f"max {t['lateness_max_s'] * 1e3:.2f} ms)"
            )
        return (
            f"{self.name}: {self.status}, {self.n_samples} samples, "
            f"{self.duration_s:.1f} s, {frange}, late {int(t.get('late', 0))}, "
            f"missed {int(t.get('missed', 0))}{lat}"
        )


@dataclass
class RunnerOptions:
    """Tunables of the runner (defaults are the production values).

    Attributes
    ----------
    late_threshold_s
        A sample later than this after its deadline counts as late, s.
    timing_warn_fraction
        A run that missed more than this share of its scheduled samples, or had more than
        this share late, is flagged and warned about.
    flush_interval_s
        The longest wall time between two flushes of the file, s: it bounds what a
        kill -9 or a power cut loses.
    progress
        Show a progress bar on stderr (off anyway when stderr is not a terminal).
    prompt
        The operator prompt for a manual muscle regulator (default: a line on stderr).
    extra_attrs
        Extra root attrs of the file (e.g. the command line, the seed).
    realtime_priority, realtime_priority_level
        On a real clock, ask Linux for SCHED_FIFO priority while recording (silently
        skipped where not permitted, and recorded in the file's attrs).
    observer
        Told when each run starts and ends (e.g. the live view).
    """

    #: a sample later than this after its deadline counts as late (s)
    late_threshold_s: float = LATE_THRESHOLD_S
    #: a run that missed more than this share of its scheduled samples, or had more than
    #: this share late, is flagged (``timing_warning``) and warned about
    timing_warn_fraction: float = 0.01
    #: longest wall time between two flushes of the file (s): bounds the loss on kill -9
    flush_interval_s: float = 0.25
    #: show a tqdm progress bar on stderr (off anyway when stderr is not a TTY)
    progress: bool = True
    #: operator prompt for a manual muscle regulator (default: a line on stderr)
    prompt: Callable[[str], None] | None = None
    #: extra root attrs (e.g. command line, seed)
    extra_attrs: dict[str, Any] = field(default_factory=dict)
    #: on a real clock, ask Linux for SCHED_FIFO priority (and pause the garbage collector)
    #: while recording: on a loaded machine a normal process wakes from ``sleep`` several
    #: ms late (measured p99 3.4 ms on a shared 2-core VM); a FIFO thread wakes within
    #: ~60 µs.  Silently skipped where not permitted (recorded in the file's attrs).
    realtime_priority: bool = True
    realtime_priority_level: int = 50
    #: run-time state: the signal (SIGINT/SIGTERM) received and not yet acted on
    pending_signal: dict[str, int | None] = field(default_factory=lambda: {"sig": None})
    #: told when each run starts and ends (e.g. the live view); None: nobody watches
    observer: RunObserver | None = None

    def request_stop(self) -> None:
        """Ask the runner for a safe abort (vent, keep the samples) at the next sample;
        callable from any thread.  A pending signal is not overridden."""
        if self.pending_signal["sig"] is None:
            self.pending_signal["sig"] = STOP_REQUEST


def _vent(rig: Rig) -> VentReport:
    """Vent the cylinder regulator first (it moves the load), then the muscle supply;
    never raises (:meth:`Rig.vent`), the report says what each device confirmed."""
    return rig.vent()


#: stands for the vent report in :attr:`SafetyAbort.template` (re-rendered by the CLI
#: when a later vent, e.g. on closing the rig, confirms what this one could not)
VENT_SLOT = "\x00vent\x00"


def abort_error(template: str, report: VentReport) -> SafetyAbort:
    """A :class:`SafetyAbort` whose message is ``template`` with the vent report's line;
    ``.vent`` and ``.template`` let a caller re-render it with a later report."""
    err = SafetyAbort(template.replace(VENT_SLOT, report.line()))
    err.vent = report
    err.template = template
    return err


def update_abort_vent(err: SafetyAbort, later: VentReport | None) -> None:
    """Merge a later vent report into an abort's message (per regulator, a confirmed
    outcome of either attempt wins)."""
    report, template = err.vent, err.template
    if later is None or report is None or template is None:
        return
    merged = report.merged(later)
    err.vent = merged
    err.args = (template.replace(VENT_SLOT, merged.line()),)


def info_json(info: dict[str, Any]) -> str:
    """Rig provenance as JSON text; live objects (e.g. the simulator) by their type name."""
    clean: dict[str, Any] = {}
    for k, v in info.items():
        try:
            json.dumps(v)
            clean[k] = v
        except (TypeError, ValueError):
            clean[k] = f"<{type(v).__module__}.{type(v).__name__}>"
    return json.dumps(clean, sort_keys=True)


def run_attrs(
    spec: RunSpec, protocol: Protocol, rig: Rig, rate_Hz: float | None = None
) -> dict[str, Any]:
    """The per-run attrs (contract fields first, then provenance).

    ``rate_Hz`` is the rate actually recorded at (default: the protocol's).
    """
    return {
        "muscle_pressure_MPa": spec.muscle_pressure_MPa,
        "waveform": spec.waveform,
        "frequency_Hz": spec.frequency_Hz,
        "sample_rate_Hz": rate_Hz or protocol.sample_rate_Hz,
        "requested_sample_rate_Hz": protocol.sample_rate_Hz,
        "protocol": spec.to_json(),
        "role": spec.role,
        "amplitude_MPa": spec.amplitude_MPa,
        "offset_MPa": spec.offset_MPa,
        "cycles": spec.cycles,
        "settle_s": spec.settle_s,
        "ramp_s": spec.ramp_s,
        "steady_start_s": spec.steady_start_s,
        "steady_end_s": spec.steady_end_s,
        "description": spec.description,
        "protocol_name": protocol.name,
        "protocol_file": protocol.path,
        "software_version": __version__,
        "rig": info_json(rig.info),
        "calibration": json.dumps(rig.info.get("calibration", {}), sort_keys=True, default=str),
        "clock": "virtual" if rig.clock.virtual else "real",
        **({"held_muscle": spec.muscle} if spec.muscle else {}),
        **static_attrs(spec),
    }


def static_attrs(spec: RunSpec) -> dict[str, Any]:
    """The run file's test type and held value (the attrs the static path of ``identify``
    reads): ``test_type``, and ``held_position_mm`` (isometric) or ``load_N`` (isotonic)."""
    out: dict[str, Any] = {"test_type": spec.test_type}
    if spec.held_position_mm is not None:
        out["held_position_mm"] = spec.held_position_mm
    if spec.load_N is not None:
        out["load_N"] = spec.load_N
    return out


def muscle_regulator(rig: Rig) -> Any:
    """The rig's commanded muscle regulator (``rig.muscle_regulator``), or None."""
    return getattr(rig, "muscle_regulator", None)


def _hold(rig: Rig, spec: RunSpec) -> None:
    """Clamp the length or hang the load a static run holds (a rig that does it itself)."""
    if spec.held_position_mm is not None:
        fn = getattr(rig, "hold_length", None)
        if fn is not None:
            fn(spec.held_position_mm)
    if spec.load_N is not None:
        fn = getattr(rig, "hang_load", None)
        if fn is not None:
            fn(spec.load_N)


def run_protocol(
    rig: Rig,
    protocol: Protocol,
    out: str | Path,
    *,
    force: bool = False,
    options: RunnerOptions | None = None,
) -> list[RunResult]:
    """Run every run of ``protocol`` on ``rig`` and record them into ``out`` at its rate.

    Unsafe protocols and existing outputs are refused before anything moves.  The samples
    are written as they come (crash-proof: a killed run keeps what it recorded) with their
    real time stamps; missed deadlines are recorded as gaps, never filled in.  Every exit
    vents the regulators.

    Parameters
    ----------
    rig
        An open rig (:func:`pmalab.rig.loader.load_rig`), the simulated one or hardware.
    protocol
        The runs to play (:func:`pmalab.acquisition.protocol.load_protocol`).
    out
        The run file to write (HDF5).
    force
        Overwrite an existing ``out``.
    options
        Progress bar, extra attrs and the like (:class:`RunnerOptions`); ``None``: defaults.

    Returns
    -------
    list of RunResult
        One per run: its name, samples, timing (late and missed samples) and status.

    Raises
    ------
    pmalab.acquisition.safety.ProtocolRefused
        The protocol exceeds the rig's limits (nothing moved).
    pmalab.errors.OutputExistsError
        ``out`` exists and ``force`` is false.
    pmalab.errors.SafetyAbort
        A limit trip, Ctrl-C, an exception or a device fault: raised after venting and
        closing the file with the aborted run's samples; its message states each vent's
        outcome.
    """
    opts = options or RunnerOptions()
    try:
        with deferred_signals(opts.pending_signal), _realtime_scheduling(rig, opts) as sched:
            opts.extra_attrs.setdefault("scheduling", sched)
            return _run_protocol(rig, protocol, out, force, opts)
    finally:
        # every exit path, including a refused protocol or an existing output; once (a
        # dead link makes each vent wait for its retries), then the sampler stops
        _vent(rig)
        with contextlib.suppress(Exception):
            rig.sampler.stop()


def _notify(opts: RunnerOptions, event: str, *args: Any) -> None:
    """Tell the observer (if any); its failures never reach the recording."""
    if opts.observer is not None:
        with contextlib.suppress(Exception):
            getattr(opts.observer, event)(*args)


@contextlib.contextmanager
def _realtime_scheduling(rig: Rig, opts: RunnerOptions):
    """SCHED_FIFO + no GC pauses while a real-clock run records; yields a description."""
    if rig.clock.virtual or not opts.realtime_priority or not hasattr(os, "sched_setscheduler"):
        yield "virtual clock" if rig.clock.virtual else "normal"
        return
    old_policy = os.sched_getscheduler(0)
    old_param = os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(opts.realtime_priority_level))
        granted = f"SCHED_FIFO {opts.realtime_priority_level}"
    except OSError as exc:
        granted = f"normal (SCHED_FIFO not permitted: {exc.strerror})"
    gc_was = gc.isenabled()
    gc.disable()
    try:
        yield granted
    finally:
        if gc_was:
            gc.enable()
        if granted.startswith("SCHED_FIFO"):
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, old_policy, old_param)


def recording_rate(rig: Rig, protocol: Protocol) -> tuple[float, str | None]:
    """The rate to record at (Hz) and, when reduced, a one-line warning.

    Reduced only when the rig says so (``rig.info["timing"]["reduced"]``: its loader
    probed the link with ``allow_reduced_rate = true``) and the sampler's rate is below
    the protocol's.  Raises :class:`ProtocolRefused` when a run's waveform would get fewer
    than 20 samples per period at the reduced rate.
    """
    requested = float(protocol.sample_rate_Hz)
    timing = rig.info.get("timing")
    reduced = isinstance(timing, dict) and bool(timing.get("reduced"))
    rate = float(getattr(rig.sampler, "sample_rate_Hz", requested) or requested)
    if not reduced or rig.sampler.hardware_timed or not 0 < rate < requested:
        return requested, None
    where = protocol.path or protocol.name
    for r in protocol.runs:
        if r.frequency_Hz > rate / 20 + 1e-12:
            raise ProtocolRefused(
                f"{where}: run '{r.name}': refused: field 'frequency_Hz' = {r.frequency_Hz:g} "
                f"Hz needs ≥ {20 * r.frequency_Hz:g} Hz sampling, but the rig's link sustains "
                f"only {rate:g} Hz (reduced rate)"
            )
    name = rig.info.get("name") or rig.info.get("kind") or "rig"
    sustain = timing.get("sustainable_Hz") if isinstance(timing, dict) else None
    why = f" (its link sustains about {sustain:.0f} Hz)" if isinstance(sustain, int | float) else ""
    if why and isinstance(timing, dict) and timing.get("host_busy"):
        # the probe measured the busy computer too
        why = (
            f" (its link, on this busy computer, sustained about {sustain:.0f} Hz: pmalab's "
            f"threads, summed, waited for a CPU {100 * float(timing.get('cpu_wait_share', 0.0)):.0f} % of the probe)"
        )
    return rate, (
        f"pmalab: warning: {name}: recording at a reduced {rate:g} Hz instead of "
        f"the protocol's {requested:g} Hz{why}; allow_reduced_rate = true"
    )


def _device_stats(rig: Rig) -> dict[str, Any] | None:
    """The sampler's fault counters (``stats()``), or None when it has none."""
    stats = getattr(rig.sampler, "stats", None)
    if not callable(stats):
        return None
    try:
        d = stats()
    except Exception as exc:  # counters are provenance: never let them fail a run
        return {"error": f"stats() failed: {type(exc).__name__}: {exc}"}
    return d if isinstance(d, dict) else {"value": d}


def _store_device_stats(rig: Rig, w: RunWriter) -> None:
    d = _device_stats(rig)
    if d is not None:
        w.set_device_stats(d)


def _run_protocol(
    rig: Rig, protocol: Protocol, out: str | Path, force: bool, opts: RunnerOptions
) -> list[RunResult]:
    preflight(protocol, rig)
    rate, warning = recording_rate(rig, protocol)
    out = check_output(out, force)
    check_free_space(
        out,
        estimated_file_size(
            [int(math.floor(r.duration_s * rate + 1e-9)) + 1 for r in protocol.runs],
            len(rig.channels),
        ),
    )
    if warning:
        print(warning, file=sys.stderr, flush=True)
    limits = effective_limits(rig)
    monitor = SafetyMonitor(limits, channels=[rig.channels[n] for n in sampled(rig.channels)])
    root = {
        "software": "pmalab",
        "software_version": __version__,
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "protocol_name": protocol.name,
        "protocol_file": protocol.path,
        "protocol_text": protocol.text,
        "rig": info_json(rig.info),
        "calibration": json.dumps(rig.info.get("calibration", {}), sort_keys=True, default=str),
        "limits": json.dumps(limits.__dict__, sort_keys=True),
        "clock": "virtual" if rig.clock.virtual else "real",
        # what stamps each sample: the device's sample clock (t = k / rate) or the host's
        "time_base": (
            "device sample clock"
            if rig.sampler.hardware_timed
            else "virtual clock"
            if rig.clock.virtual
            else "host clock"
        ),
        "sample_rate_Hz": rate,
        "requested_sample_rate_Hz": protocol.sample_rate_Hz,
        **opts.extra_attrs,
    }
    results: list[RunResult] = []
    pbar = _progress(protocol, opts.progress)
    try:
        rec = Recorder(
            out,
            [(r.name, run_attrs(r, protocol, rig, rate)) for r in protocol.runs],
            root,
            flush_interval_s=opts.flush_interval_s,
            channels=rig.channels,
        )
        try:
            for i, spec in enumerate(protocol.runs):
                w = rec.writer(spec.name)
                w.late_threshold_s = opts.late_threshold_s
                w.warn_fraction = opts.timing_warn_fraction
                _notify(opts, "run_started", i, spec, w)
                try:
                    hold = getattr(rig, "hold", None)
                    if hold is not None:  # a rig with several muscles: which one is held
                        hold(spec.muscle)
                    if spec.static:
                        _hold(rig, spec)
                    if i == 0:
                        rig.cylinder_regulator.set_pressure(0.0)
                        getattr(rig.sampler, "configure", lambda _r: None)(rate)
                        rig.sampler.start()
                    _wait_for_muscle_pressure(rig, spec, rate, monitor, opts, pbar)
                    _record(rig, spec, rate, monitor, w, rec, opts, pbar)
                    # end of a run: command zero before the next pressure level
                    rig.cylinder_regulator.set_pressure(0.0)
                    _store_device_stats(rig, w)
                    timing = w.finish("completed")
                    _notify(opts, "run_ended", i, spec, "completed", "")
                except BaseException as exc:
                    # vent FIRST — before any file work — then close the run as aborted
                    vented = _vent(rig)
                    reason = _reason(exc)
                    failed = _close_aborted(
                        rig, rec, w, protocol.runs[i + 1 :], f"aborted: {reason}"
                    )
                    if not vented.ok:  # once more: a link may answer again by now
                        vented = vented.merged(_vent(rig))
                    kept = (
                        f"{w.n} samples kept (status 'aborted')"
                        if failed is None
                        else f"the file could not be finished ({failed}): what was flushed "
                        "before stays readable"
                    )
                    abort = abort_error(
                        f"{out}: run '{spec.name}' aborted: {reason}; {VENT_SLOT}; {kept}", vented
                    )
                    abort.hard_exit = rec.unclosed
                    _notify(opts, "run_ended", i, spec, f"aborted: {reason}", str(abort))
                    raise abort from (exc if isinstance(exc, Exception) else None)
                results.append(
                    _result(spec.name, "completed", w, timing, rig.sampler.hardware_timed)
                )
        except BaseException:
            with contextlib.suppress(Exception):  # never hide the reason of the abort
                rec.close()
            raise
        try:
            rec.close()
        except (OSError, RuntimeError) as exc:  # e.g. the disk filled up at the very end
            err = output_failure(out, exc, "close the run file")
            err.hard_exit = rec.unclosed
            raise err from None
    finally:
        if pbar is not None:
            pbar.close()
    return results


def _close_aborted(
    rig: Rig, rec: Recorder, w: RunWriter, later: list[RunSpec], status: str
) -> str | None:
    """Close an aborted run's file: status first, then samples, statistics and the rest.

    The status goes first because it is written in place (no new file space); then the
    buffered samples, then the device counters.  Each step runs even when an earlier one
    failed (what was flushed stays readable); returns why the file could not be finished
    (the first failure, one line), or None.
    """
    steps: list[Callable[[], object]] = [
        lambda: (w.set_status(status), rec.file.flush()),
        lambda: w.finish(status),
        # a faulted device may fail to report its counters: the samples come first
        lambda: (_store_device_stats(rig, w), rec.file.flush()),
        lambda: [rec.writer(spec.name).set_status("not run: campaign aborted") for spec in later],
        rec.close,
    ]
    first: str | None = None
    for step in steps:
        try:
            step()
        except Exception as exc:
            if first is None:
                first = _hdf5_reason(exc)
    return first


def _hdf5_reason(exc: BaseException) -> str:
    """Why a file operation failed, in a few words (HDF5 nests the OS's reason)."""
    m = re.search(r"error message = '([^']*)'", str(exc))
    return m.group(1) if m else _first_line(exc)


def _first_line(exc: BaseException) -> str:
    """An exception's message on one line (HDF5's messages span several)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _reason(exc: BaseException) -> str:
    if isinstance(exc, Trip):
        return str(exc.args[0])
    if isinstance(exc, Terminated):
        return "terminated (SIGTERM)"
    if isinstance(exc, Stopped):
        return "stopped from the live view"
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted (Ctrl-C)"
    if isinstance(exc, RigError):
        return f"device fault: {exc}"
    msg = _hdf5_reason(exc) if str(exc).strip() else ""
    return f"exception: {type(exc).__name__}" + (f": {msg}" if msg else "")


def _result(
    name: str, status: str, w: RunWriter, timing: dict[str, float], hardware_timed: bool = False
) -> RunResult:
    fmin, fmax = w.force_range
    return RunResult(
        name, status, w.n, float(timing.get("duration_s", 0.0)), fmin, fmax, timing, hardware_timed
    )


def _progress(protocol: Protocol, enabled: bool):
    if not enabled or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(
        total=round(protocol.duration_s, 1),
        unit="s",
        file=sys.stderr,
        desc=protocol.name,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| "
        "{n:.0f}/{total:.0f} s [{elapsed}<{remaining}]{postfix}",
    )


def _default_prompt(msg: str) -> None:
    print(f"pmalab: {msg}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- muscle pressure
def _wait_for_muscle_pressure(
    rig: Rig, spec: RunSpec, rate: float, monitor: SafetyMonitor, opts: RunnerOptions, pbar
) -> None:
    """Request the muscle pressure; sample (with safety checks) until it is within
    tolerance and stable for ``pressure_stable_s``.

    Stable: over the last ``pressure_stable_s`` of samples, |mean − target| ≤ tolerance and
    the standard deviation ≤ tolerance/2 (sensor noise of a PSE510-class gauge is a few
    kPa; a manual regulator still being turned moves far more than that).
    """
    target = spec.preload_MPa if spec.static else spec.muscle_pressure_MPa
    tol = spec.pressure_tolerance_MPa
    supply = rig.muscle_supply
    prompt = opts.prompt or _default_prompt
    if spec.static:  # the commanded regulator starts at the waveform's minimum
        muscle_regulator(rig).set_pressure(target)
    elif supply.automatic:
        supply.request(target)
    else:
        # the supply words the request; the runner adds which run and when it will start
        supply.request(
            target,
            lambda text: prompt(
                f"run '{spec.name}': {text} (recording starts once the reading is within "
                f"±{tol:g} MPa of {target:.4g} MPa and stable)"
            ),
        )
    if pbar is not None:
        pbar.set_postfix_str(f"{spec.name}: waiting for {target:.3g} MPa")
    clock, sampler = rig.clock, rig.sampler
    names = sampled(rig.channels)
    i_held = names.index(held_pressure_channel(rig))
    need = max(2, int(round(spec.pressure_stable_s * rate)))
    window: deque[float] = deque(maxlen=need)
    dt = 1.0 / rate
    t_start = clock.now()
    k = 0
    last_note = t_start
    pending = opts.pending_signal
    while True:
        check_signal(pending)
        if not sampler.hardware_timed:
            clock.sleep_until(t_start + k * dt)
            k += 1
        blk = sampler.read_block()
        cols = [blk.column(c).tolist() for c in names]
        held = cols[i_held]
        for j in range(len(blk)):
            reason = monitor.check(tuple([col[j] for col in cols]))
            if reason:
                _vent(rig)
                raise Trip(reason + " (while waiting for the muscle pressure)")
            window.append(held[j])
        now = clock.now()
        if len(window) == need:
            mean = math.fsum(window) / need
            if abs(mean - target) <= tol:
                var = math.fsum((v - mean) ** 2 for v in window) / need
                if math.sqrt(var) <= tol / 2:
                    return
        if now - t_start > spec.pressure_timeout_s:
            mean = math.fsum(window) / max(1, len(window))
            raise RigError(
                f"muscle pressure did not settle at {target:.4g} MPa within "
                f"{spec.pressure_timeout_s:g} s (reading {mean:.4g} MPa)"
            )
        if not supply.automatic and now - last_note >= 5.0 and not clock.virtual:
            last_note = now
            prompt(f"muscle pressure reads {window[-1]:.4g} MPa (target {target:.4g})")


# --------------------------------------------------------------------------- recording
class CommandBlocks:
    """The command at each sample deadline, generated a block of deadlines at a time as
    the run is played (never the whole run: a 10-hour run at 500 Hz holds 18 million
    deadlines).

    ``cmds[k]`` is :func:`~pmalab.acquisition.waveforms.command_samples` at deadline
    ``k`` (same values); deadlines are asked for in increasing order (a gap of missed
    deadlines skips ahead), so one block of ``block`` Python floats is held at a time.
    """

    def __init__(self, spec: RunSpec, rate_Hz: float, n_total: int, block: int = 4096) -> None:
        self.spec, self.rate, self.n, self.block = spec, float(rate_Hz), int(n_total), block
        self._start = 0
        self._values: list[float] = []

    def __getitem__(self, k: int) -> float:
        i = k - self._start
        if 0 <= i < len(self._values):
            return self._values[i]
        if not 0 <= k < self.n:
            raise IndexError(k)
        stop = min(self.n, k + self.block)
        self._start = k
        self._values = command_block(self.spec, self.rate, k, stop).tolist()
        return self._values[0]


def held_pressure_channel(rig: Rig) -> str:
    """The channel that reads the pressure the run holds (the single-muscle rig's
    ``muscle_pressure``; a rig declaring several muscles names it, ``held_pressure``)."""
    return str(getattr(rig, "held_pressure", "muscle_pressure"))


def command_row(rig: Rig, spec: RunSpec) -> Callable[[float], tuple[float, ...]]:
    """The recorded values of the rig's declared command channels for a waveform value
    ``cmd`` (the single-muscle rig: the cylinder's command alone; a rig declaring more
    commands says how, ``command_values(cmd, spec)``)."""
    fn: Callable[[float, RunSpec], tuple[float, ...]] | None = getattr(rig, "command_values", None)
    if fn is not None:
        return lambda cmd: fn(cmd, spec)
    return lambda cmd: (cmd,)


def _record(
    rig: Rig,
    spec: RunSpec,
    rate: float,
    monitor: SafetyMonitor,
    w: RunWriter,
    rec: Recorder,
    opts: RunnerOptions,
    pbar,
) -> None:
    """Record one run through the sample loop (:mod:`pmalab.acquisition.loop`): command the
    waveform, check, store, flush — until its end."""
    sampler = rig.sampler
    # a static run plays its waveform on the muscle's regulator; the cylinder stays at 0
    reg = muscle_regulator(rig) if spec.static else rig.cylinder_regulator
    dt = 1.0 / rate
    n_total = int(math.floor(spec.duration_s * rate + 1e-9)) + 1
    add = w.append
    flush_due = rec.flush_due
    w.start_unix = time.time()
    w.set_status("running")
    if pbar is not None:
        pbar.set_postfix_str(spec.name)
    progress_step = max(1, int(rate // 2))
    hw = sampler.hardware_timed
    cmds = CommandBlocks(spec, rate, n_total)
    since = [0, 0]  # samples delivered, samples the progress bar has shown
    # the recorded row is the rig's declaration: time, the sampled channels, the commands
    commands = command_row(rig, spec)
    if spec.static and getattr(rig, "command_values", None) is None:
        commands = lambda _cmd: (0.0,)  # noqa: E731  (a rig declaring no muscle command)

    def step(k: int, t_rel: float, v: Sample, lateness: float) -> float:
        # the waveform's value at this sample's nominal time (computed a block of deadlines ahead);
        # sent right after the block and held by the regulator until the next one
        cmd = cmds[k]
        add((t_rel, *v, *commands(cmd)), lateness)
        since[0] += 1
        return cmd

    def on_trip(reason: str, t_rel: float, v: Sample, lateness: float) -> None:
        # vent in this sample period, keep the sample, then the loop aborts
        _vent(rig)
        if math.isfinite(t_rel + math.fsum(v)):  # a NaN would break the contract
            add((t_rel, *v, *commands(0.0)), lateness)

    def after_block(k: int) -> None:
        if (hw or not k & 31) and flush_due():  # wall clock looked at every 32 samples
            w.commit()
        if pbar is not None and since[0] - since[1] >= progress_step:
            pbar.update((since[0] - since[1]) * dt)
            since[1] = since[0]

    sample_loop(
        rig.clock,
        sampler,
        rate,
        n_total,
        check=monitor.check,
        step=step,
        command=reg.set_pressure,
        on_trip=on_trip,
        pending=opts.pending_signal,
        stats=w,
        late_threshold_s=opts.late_threshold_s,
        after_block=after_block,
        channels=sampled(rig.channels),
    )
    reg.set_pressure(0.0)
    if pbar is not None and since[0] > since[1]:
        pbar.update((since[0] - since[1]) * dt)
