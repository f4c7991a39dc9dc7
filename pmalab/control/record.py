"""Control runs → an HDF5 run file (contract ``pmalab.run`` v1, :mod:`pmalab.runfile`) plus metrics,
written WHILE the run goes, so a crash, ``kill -9`` or Ctrl-C leaves a readable file.

One group per run (``/runs/<controller>``), every per-sample dataset 1-D with a ``units``
attr:

* the contract's channels ``time`` (s), ``position`` (mm, from home), ``force`` (N, load
  cell in series with the muscle), ``muscle_pressure`` (MPa), so ``pmalab identify`` and
  every run-file reader open it;
* ``position_reference`` (mm), ``position_setpoint`` (mm: the shaped set point the
  cascade follows), ``muscle_pressure_command`` (MPa, to the regulator),
  ``muscle_pressure_reference`` (MPa: the pressure loop's reference, or the cascade's
  desired pressure p_d), ``force_reference`` (N, F_d), ``hysteresis_force`` (N, h)
  (a pressure-loop run has no position-only ones);
* ``gains/<loop>_<kp|ki|kd>`` — the gains over time (units in their attrs);
* ``lateness`` (s): how late each sample was read after its deadline (0 on the virtual
  clock);
* ``status``: "pending" (not started), "running" (started; a file left so was cut by a
  crash or ``kill -9``: :func:`pmalab.runfile.read_runs` reads the samples every channel
  holds), "completed" or "aborted: <reason>";
* ``summary`` (bytes of JSON, written when the run ends, completed or aborted):
  ``metrics`` (:mod:`pmalab.control.metrics`), ``vent``, ``vent_confirmed``,
  ``wall_time_s``, ``muscle_pressure_MPa`` (the run's mean pressure: a control run has no
  nominal one), ``n_samples``; :func:`pmalab.runfile.read_runs` merges it into the run's
  attrs.  ``timing`` as the acquisition's runs.

Run attrs (known before the run starts): ``controller``, ``loop``, ``reference``,
``waveform``, ``frequency_Hz``, ``settings`` (JSON), ``model``, ``model_law``,
``sample_rate_Hz``, ``protocol``, and what the caller adds (``command_line``, ``truth``).
Root attrs add ``kind = "control"``.

The writer is the acquisition's SWMR recorder (:mod:`pmalab.acquisition.recorder`):
every group, dataset and attr is made before the file is switched to SWMR mode and
renamed from ``OUT.partial`` to ``OUT``; samples are appended and flushed every 0.25 s
of wall time, so a kill loses at most that much.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np

from pmalab import __version__
from pmalab.acquisition.loop import Stats
from pmalab.control.controllers import CascadeSettings
from pmalab.control.metrics import summarize
from pmalab.control.model import IdentifiedModel
from pmalab.control.reference import Reference
from pmalab.control.runner import GAINS, ControlRun, run_attrs, signals_of
from pmalab.identify.schema import ControlMetrics, ControlSummary
from pmalab.paths import check_output, output_failure


def _clean(v: Any) -> Any:
    """JSON-safe: numpy → Python, NaN/inf → None."""
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def run_metrics(run: ControlRun) -> dict[str, Any]:
    """The run's metrics (:func:`pmalab.control.metrics.summarize` on what it recorded)."""
    s = run.signals
    if run.n < 2:
        return {"kind": run.reference.kind, "rms_error": None, "max_error": None}
    if run.loop == "position":
        y, r = s["position"], s["position_reference"]
    else:
        y, r = s["muscle_pressure"], s["muscle_pressure_reference"]
    duration = float(s["time"][-1]) + run.attrs.get("sample_rate_Hz", 500.0) ** -1
    out = summarize(run.reference.kind, s["time"], y, r, run.reference.step_times(duration))
    out["unit"] = run.reference.unit
    out["completed"] = run.completed
    return _clean(out)


def control_channels(loop: str) -> dict[str, str]:
    """The per-sample datasets (path in the run's group → units) of a ``loop`` run."""
    return {**signals_of(loop), **{f"gains/{k}": u for k, u in GAINS.items()}}


def _attrs(d: Mapping[str, Any]) -> dict[str, Any]:
    return {
        k: (json.dumps(_clean(v)) if isinstance(v, dict | list) else v)
        for k, v in d.items()
        if v is not None
    }


class ControlRecording:
    """The live output file of one ``pmalab control`` call (one experiment).

    ``runs``: ``(name, attrs)`` of every run planned, in order (their groups are all made
    up front; a run never started stays ``pending`` and readers skip it); all of one
    ``loop``.  Use :meth:`writer` per run, then :meth:`close`.
    """

    def __init__(
        self,
        path: str | Path,
        runs: Sequence[tuple[str, Mapping[str, Any]]],
        loop: str,
        *,
        force: bool = False,
        root_attrs: Mapping[str, Any] | None = None,
        flush_interval_s: float = 0.25,
    ) -> None:
        from pmalab.acquisition.recorder import Recorder

        path = check_output(path, force)
        root = {
            "kind": "control",
            "pmalab_version": __version__,
            "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            **_attrs(root_attrs or {}),
        }
        self.path = path
        self.rec = Recorder(
            path,
            [(n, _attrs(a)) for n, a in runs],
            root,
            flush_interval_s=flush_interval_s,
            channels=control_channels(loop),
            summary=True,
        )

    def writer(self, name: str) -> ControlRunWriter:
        return ControlRunWriter(self, name)

    def close(self) -> None:
        try:
            self.rec.close()
        except (OSError, RuntimeError) as exc:
            raise output_failure(self.path, exc) from None

    def __enter__(self) -> ControlRecording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ControlRunWriter:
    """One run's sink (:class:`pmalab.control.runner.SampleSink`): appends blocks of
    samples to the live file, then :meth:`finish` writes the rest, summary and status."""

    def __init__(self, recording: ControlRecording, name: str) -> None:
        self.recording = recording
        self.w = recording.rec.writer(name)
        self.sent = 0  # samples handed to the file so far
        self._guard(lambda: (self.w.set_status("running"), recording.rec.file.flush()))

    @property
    def stats(self) -> Stats:
        """The run writer's timing counts (:class:`pmalab.acquisition.loop.Stats`)."""
        return self.w

    def due(self) -> bool:
        return self.recording.rec.flush_due()

    def _guard(self, fn: Any) -> None:
        try:
            fn()
        except (OSError, RuntimeError) as exc:  # a full disk, a vanished directory
            raise output_failure(self.recording.path, exc) from None

    def write(
        self,
        signals: Mapping[str, np.ndarray],
        gains: Mapping[str, np.ndarray],
        lateness: np.ndarray,
    ) -> None:
        n = len(lateness)
        if not n:
            return
        cols = [gains[c[6:]] if c.startswith("gains/") else signals[c] for c in self.w.channels]

        def do() -> None:
            self.w.extend(cols, lateness)
            self.w.commit()

        self._guard(do)
        self.sent += n

    def finish(self, run: ControlRun) -> None:
        """The samples not yet written, the summary (metrics, vent) and the status."""
        i = self.sent
        if i < run.n:  # a loop that streamed to this sink has written every sample
            self.write(
                {k: v[i:] for k, v in run.signals.items()},
                {k: v[i:] for k, v in run.gains.items()},
                run.lateness[i:],
            )
        self._guard(lambda: self.w.set_summary(_clean(run_summary(run))))
        self._guard(lambda: self.w.finish(run.status))


def run_summary(run: ControlRun) -> ControlSummary:
    """The end-of-run facts of ``run`` (its ``summary`` dataset,
    :class:`pmalab.identify.schema.ControlSummary`)."""
    p = run.signals["muscle_pressure"]
    return {
        "metrics": cast(ControlMetrics, run_metrics(run)),
        "vent": run.attrs.get("vent"),
        "vent_confirmed": run.attrs.get("vent_confirmed"),
        "wall_time_s": run.wall_s,
        "muscle_pressure_MPa": float(np.mean(p)) if p.size else 0.0,
        "n_samples": run.n,
    }


def planned_attrs(
    controller: str,
    reference: Reference,
    duration_s: float,
    settings: CascadeSettings,
    model: IdentifiedModel | None,
    **extra: Any,
) -> dict[str, Any]:
    """A run group's attrs, written before it starts."""
    a = run_attrs(controller, reference, duration_s, settings, model)
    a["protocol"] = {
        "kind": "control",
        "reference": reference.text,
        "controller": controller,
        "loop": reference.quantity,
    }
    a.update(extra)
    return a
