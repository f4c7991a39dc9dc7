"""The 500 Hz control loop on a :class:`~pmalab.rig.manipulator.ManipulatorRig`.

The loop is acquisition's (:func:`pmalab.acquisition.loop.sample_loop`, the one
real-time loop of pmalab): pacing by the rig's clock (a virtual clock jumps to each
deadline, so a simulated run goes as fast as the physics and the controller compute) or
by a hardware-timed sampler's own sample clock, SIGINT/SIGTERM deferred to the next
sample, lateness, missed deadlines and gaps counted; per sample it reads the sensors,
checks the limits, runs the cascade and records; the command goes to the regulator once
per block.

Safety (acquisition's rules, :class:`pmalab.acquisition.safety.SafetyMonitor`): every
sample is checked against the rig's limits (muscle pressure, travel, force, NaN); a trip,
a non-finite controller output, a device fault or Ctrl-C vents the regulator in the same
sample period and ends the run as ``aborted: <reason>``; the samples recorded so far are
kept.  ``rig.close()`` vents again on the way out.

Recording while it runs: a ``sink`` (:class:`pmalab.control.record.ControlRunWriter`)
gets the samples recorded since its last write whenever ``sink.due()`` (every 0.25 s of
wall time), so a crash or ``kill -9`` loses at most that much; the caller writes the rest,
the status and the metrics at the end.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from pmalab.acquisition.loop import (
    LATE_THRESHOLD_S,
    LoopStats,
    Stats,
    Terminated,
    Trip,
    deferred_signals,
    sample_loop,
)
from pmalab.acquisition.safety import SafetyMonitor
from pmalab.control.cascade import Cascade
from pmalab.control.controllers import CascadeSettings
from pmalab.control.model import IdentifiedModel
from pmalab.control.reference import Reference
from pmalab.errors import PmalabError
from pmalab.rig.base import VentResult, sampled, vent_phrase
from pmalab.rig.manipulator import ManipulatorRig

#: recorded signals → units (the run file's channels and the ``gains/`` datasets)
SIGNALS = {
    "time": "s",
    "position": "mm",
    "position_reference": "mm",
    "position_setpoint": "mm",
    "force": "N",
    "muscle_pressure": "MPa",
    "muscle_pressure_command": "MPa",
    "muscle_pressure_reference": "MPa",
    "force_reference": "N",
    "hysteresis_force": "N",
}
GAINS = {
    "outer_kp": "N/mm",
    "outer_ki": "N/(mm*s)",
    "outer_kd": "N*s/mm",
    "inner_kp": "MPa/MPa",
    "inner_ki": "1/s",
    "inner_kd": "s",
}
#: signals only the position loop has (a pressure-loop run records the others)
POSITION_ONLY = ("position_reference", "position_setpoint", "force_reference", "hysteresis_force")
#: samples between two looks at ``sink.due()`` (0.05 s of the run)
SINK_CHECK_EVERY = 25
#: samples per block of the loop's buffers (8.2 s at 500 Hz)
BLOCK = 4096
#: the signals a run keeps in memory when its samples stream to a sink (what its metrics
#: and summary read); the file holds every signal and gain
KEPT_WITH_SINK = (
    "time",
    "position",
    "position_reference",
    "muscle_pressure",
    "muscle_pressure_reference",
)


class SampleSink(Protocol):
    """Where a run's samples go while it runs (the live run file)."""

    @property
    def stats(self) -> Stats:
        """The run's timing counts (late samples, missed deadlines, gaps), kept with its
        file."""
        ...

    def due(self) -> bool:
        """True when the samples so far should be written now."""
        ...

    def write(
        self, signals: dict[str, np.ndarray], gains: dict[str, np.ndarray], lateness: np.ndarray
    ) -> None:
        """Append these samples (one block per signal and gain, equal lengths)."""
        ...


def signals_of(loop: str) -> dict[str, str]:
    """The signals (→ units) a run of ``loop`` ("position"/"pressure") records."""
    return {k: u for k, u in SIGNALS.items() if loop == "position" or k not in POSITION_ONLY}


def run_attrs(
    controller: str,
    reference: Reference,
    duration_s: float,
    settings: CascadeSettings,
    model: IdentifiedModel | None,
) -> dict[str, Any]:
    """A run's attrs known before it starts (the vent's outcome comes at its end)."""
    is_pos = reference.quantity == "position"
    return {
        "controller": controller,
        "loop": reference.quantity,
        "reference": reference.text,
        "waveform": reference.kind,
        "frequency_Hz": reference.frequency_Hz,
        "reference_magnitude": reference.magnitude,
        "reference_unit": reference.unit,
        "duration_s": duration_s,
        "sample_rate_Hz": 1.0 / settings.outer.dt,
        "settings": settings.to_dict(),
        "model": (model.source if model is not None and is_pos else ""),
        "model_law": (model.law if model is not None and is_pos else ""),
    }


@dataclass
class ControlRun:
    """A finished (or aborted) control run: signals, gains, status and its settings."""

    name: str
    controller: str
    loop: str
    reference: Reference
    signals: dict[str, np.ndarray]
    gains: dict[str, np.ndarray]
    status: str
    attrs: dict[str, Any] = field(default_factory=dict)
    wall_s: float = 0.0
    #: how late each sample was read after its deadline (s; 0 on a virtual clock)
    lateness: np.ndarray = field(default_factory=lambda: np.zeros(0))

    #: samples recorded (with a sink, only :data:`KEPT_WITH_SINK` stay in ``signals``;
    #: every sample and gain is in the sink's file); -1: ``len(signals["time"])``
    n_samples: int = -1

    @property
    def n(self) -> int:
        return self.n_samples if self.n_samples >= 0 else int(self.signals["time"].shape[0])

    @property
    def completed(self) -> bool:
        return self.status == "completed"


def run_control(
    rig: ManipulatorRig,
    controller: str,
    reference: Reference,
    duration_s: float,
    settings: CascadeSettings,
    model: IdentifiedModel | None,
    *,
    name: str | None = None,
    progress: Callable[[float], None] | None = None,
    sink: SampleSink | None = None,
) -> ControlRun:
    """Run ``controller`` on ``rig`` following ``reference`` for ``duration_s`` seconds.

    The loop is the reference's quantity: a position reference runs the cascade (it needs
    the identified ``model``), a pressure reference the inner loop alone.  Never raises
    for a limit trip or Ctrl-C: the run comes back with ``status = "aborted: …"`` and the
    regulator vented (check :attr:`ControlRun.completed`).  ``sink`` receives the samples
    while the run goes (see the module docstring); a failing write aborts the run (vented)
    with the write's error as the reason.
    """
    dt = settings.outer.dt
    loop = reference.quantity
    if loop == "angle":
        raise PmalabError(
            f"{reference.text}: a joint angle needs an antagonistic pair (pmalab.control.joint)"
        )
    if loop == "position" and model is None:
        raise PmalabError("the position loop needs an identified model (--model)")
    p_max = float(min(rig.muscle_regulator.max_pressure_MPa, rig.limits.max_muscle_pressure_MPa))
    cascade = Cascade(
        controller, settings, model if loop == "position" else None, rig.geometry, p_max
    )
    n = int(round(duration_s / dt)) + 1
    # samples go into one block of buffers (never arrays for the whole run: 17 of them were
    # 2.4 GB for 10 hours at 500 Hz); a full block, or a due sink, hands them on
    buf = _Blocks(min(n, BLOCK), sink, keep=None if sink is None else KEPT_WITH_SINK)
    sig, gains, late = buf.sig, buf.gains, buf.late
    monitor = SafetyMonitor(rig.limits, channels=[rig.channels[c] for c in sampled(rig.channels)])
    sampler = rig.sampler
    regulator = rig.muscle_regulator
    status = "completed"
    vent: VentResult | None = None
    done = [0]  # samples recorded (missed deadlines leave no row: a gap, not a sample)
    wall0 = time.perf_counter()
    every = max(1, int(1.0 / dt))
    is_pos = loop == "position"
    s_t, s_x, s_xr, s_f, s_p = (
        sig["time"],
        sig["position"],
        sig["position_reference"],
        sig["force"],
        sig["muscle_pressure"],
    )
    s_u, s_pr, s_fr, s_h = (
        sig["muscle_pressure_command"],
        sig["muscle_pressure_reference"],
        sig["force_reference"],
        sig["hysteresis_force"],
    )
    s_sp = sig["position_setpoint"]
    gk = [gains[g] for g in GAINS]
    stats: Stats = sink.stats if sink is not None else LoopStats()

    def step(k: int, tr: float, v: tuple[float, ...], lk: float) -> float:
        x, f, p = v[0], v[1], v[2]  # the manipulator's sampled channels: position, force, p
        r, r_d, r_dd = reference.value(tr)
        out = cascade.position_step(r, r_d, r_dd, x, p) if is_pos else cascade.pressure_step(r, p)
        u = out.command
        if not math.isfinite(u):
            raise _Diverged("controller output is not finite (diverged)")
        i = buf.i
        if i == buf.size:  # the block is full: hand it on, start the next
            buf.flush()
            i = 0
        s_t[i], s_x[i], s_f[i], s_p[i], s_u[i] = tr, x, f, p, u
        s_pr[i], s_fr[i], s_h[i] = out.pressure_reference, out.force_reference, out.hysteresis
        if is_pos:
            s_xr[i] = r
            s_sp[i] = out.setpoint
        for arr, g in zip(gk, cascade.gains()):
            arr[i] = g
        late[i] = lk
        buf.i = i + 1
        done[0] += 1
        if progress is not None and k % every == 0:
            progress(tr)
        return u

    def on_trip(reason: str, *_sample: object) -> None:
        nonlocal vent
        vent = rig.vent()  # in this sample period

    def after_block(k: int) -> None:
        if (
            sink is not None
            and (k % SINK_CHECK_EVERY == 0 or sampler.hardware_timed)
            and sink.due()
        ):
            buf.flush()

    pending: dict[str, int | None] = {"sig": None}
    try:
        with deferred_signals(pending):
            sampler.start()
            sample_loop(
                rig.clock,
                sampler,
                1.0 / dt,
                n,
                check=monitor.check,
                step=step,
                command=regulator.set_pressure,
                on_trip=on_trip,
                pending=pending,
                stats=stats,
                late_threshold_s=LATE_THRESHOLD_S,
                after_block=after_block,
                channels=sampled(rig.channels),
            )
    except Trip as exc:
        status = f"aborted: {exc}"
    except _Diverged as exc:
        vent = rig.vent()
        status = f"aborted: {exc}"
    except Terminated:
        status = "aborted: terminated (SIGTERM)"
    except KeyboardInterrupt:
        status = "aborted: interrupted (Ctrl-C)"
    except PmalabError as exc:
        status = f"aborted: {exc}"
    finally:
        vent = rig.vent() if vent is None or not vent.ok else vent
        try:
            sampler.stop()
        except Exception:  # the vent above is what matters; stop faults are secondary
            pass
    if sink is not None:
        try:
            buf.flush()  # the last block (the caller's finish() writes summary and status)
        except PmalabError as exc:  # a full disk: the samples so far are in the file
            status = f"aborted: {exc}"
    kept_sig, kept_gains, kept_late = buf.result()
    signals = {kk: v for kk, v in kept_sig.items() if kk in signals_of(loop)}
    attrs = run_attrs(controller, reference, duration_s, settings, model)
    attrs.update(
        vent=vent_phrase("muscle regulator", vent),
        vent_confirmed=vent.ok,
        n_late=int(stats.n_late),
        n_missed=int(stats.n_missed),
    )
    return ControlRun(
        name or controller,
        controller,
        loop,
        reference,
        signals,
        kept_gains,
        status,
        attrs,
        time.perf_counter() - wall0,
        kept_late,
        n_samples=done[0],
    )


class _Blocks:
    """One block of sample buffers (every signal, gain and the lateness), handed on when
    full: to the sink (the live run file) when there is one, and into the run's in-memory
    result — every channel without a sink, only ``keep`` (the signals the metrics read)
    with one."""

    def __init__(self, size: int, sink: SampleSink | None, keep: tuple[str, ...] | None) -> None:
        self.size = max(1, size)
        self.sink, self.keep = sink, keep
        self.sig = {k: np.full(self.size, np.nan) for k in SIGNALS}
        self.gains = {k: np.full(self.size, np.nan) for k in GAINS}
        self.late = np.zeros(self.size)
        self.i = 0  # samples in the block
        self._sig: dict[str, list[np.ndarray]] = {k: [] for k in SIGNALS}
        self._gains: dict[str, list[np.ndarray]] = {k: [] for k in GAINS}
        self._late: list[np.ndarray] = []

    def flush(self) -> None:
        """Hand the block's samples on and empty it (the buffers are reused in place)."""
        b = self.i
        if not b:
            return
        self.i = 0
        sig = {k: v[:b].copy() for k, v in self.sig.items()}
        gains = {k: v[:b].copy() for k, v in self.gains.items()}
        late = self.late[:b].copy()
        for k, v in sig.items():
            if self.keep is None or k in self.keep:
                self._sig[k].append(v)
        if self.keep is None:
            for k, v in gains.items():
                self._gains[k].append(v)
            self._late.append(late)
        if self.sink is not None:
            self.sink.write(sig, gains, late)

    def result(
        self,
    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
        """What the run keeps in memory (the block not yet flushed included)."""
        if self.i and self.sink is None:
            self.flush()

        def cat(parts: list[np.ndarray]) -> np.ndarray:
            return np.concatenate(parts) if parts else np.zeros(0)

        sig = {k: cat(v) for k, v in self._sig.items() if self.keep is None or k in self.keep}
        gains = {k: cat(v) for k, v in self._gains.items()} if self.keep is None else {}
        return sig, gains, cat(self._late)


class _Diverged(Exception):
    """The controller's output is not finite (the run aborts, vented)."""
