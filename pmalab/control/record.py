"""Control runs → an HDF5 run file (contract ``pmalab.run`` v1, DESIGN.md) plus metrics.

One group per run (``/runs/<controller>``), every dataset 1-D with a ``units`` attr:

* the contract's channels ``time`` (s), ``position`` (mm, from home), ``force`` (N, load
  cell in series with the muscle), ``muscle_pressure`` (MPa), so ``pmalab identify`` and
  every run-file reader open it;
* ``position_reference`` (mm), ``muscle_pressure_command`` (MPa, to the regulator),
  ``muscle_pressure_reference`` (MPa: the pressure loop's reference, or the cascade's
  desired pressure p_d), ``force_reference`` (N, F_d), ``hysteresis_force`` (N, h);
* ``gains/<loop>_<kp|ki|kd>`` — the gains over time (units in their attrs);
* ``status`` ("completed" or "aborted: <reason>", as recorded runs carry it).

Run attrs: ``controller``, ``loop``, ``reference``, ``waveform``, ``frequency_Hz``,
``settings`` (JSON), ``model``, ``vent``, ``metrics`` (JSON, :mod:`pmalab.control.metrics`)
and the contract's ``muscle_pressure_MPa`` (the run's mean pressure: a control run has no
nominal one), ``sample_rate_Hz``, ``protocol``.  Root attrs add ``kind = "control"``.

The file is written under ``OUT.partial`` and renamed when complete, so the output name
never holds half a file; an aborted run is written with what it recorded.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pmalab import __version__
from pmalab.control.metrics import summarize
from pmalab.control.runner import GAINS, SIGNALS, ControlRun
from pmalab.paths import check_output, output_failure
from pmalab.runfile import FORMAT, FORMAT_VERSION

STATUS_LEN = 256


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


def write_control_file(path: str | Path, runs: Sequence[ControlRun], *, force: bool = False,
                       root_attrs: Mapping[str, Any] | None = None) -> Path:
    """Write ``runs`` to ``path`` (atomically: ``.partial`` then rename); return the path."""
    import h5py

    path = check_output(path, force)
    tmp = path.with_name(path.name + ".partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        f = h5py.File(tmp, "w")
    except OSError as exc:
        raise output_failure(path, exc) from None
    try:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["kind"] = "control"
        f.attrs["pmalab_version"] = __version__
        f.attrs["created"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        for k, v in (root_attrs or {}).items():
            f.attrs[k] = json.dumps(_clean(v)) if isinstance(v, dict | list) else v
        grp = f.create_group("runs", track_order=True)
        for run in runs:
            _write_run(grp, run)
        f.close()
        os.replace(tmp, path)
    except BaseException as exc:
        f.close()
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError | RuntimeError):
            raise output_failure(path, exc) from None
        raise
    return path


def _write_run(grp: Any, run: ControlRun) -> None:
    g = grp.create_group(run.name)
    metrics = run_metrics(run)
    p = run.signals["muscle_pressure"]
    attrs = dict(run.attrs)
    attrs.update(
        muscle_pressure_MPa=float(np.mean(p)) if p.size else 0.0,
        protocol={"kind": "control", "reference": run.reference.text,
                  "controller": run.controller, "loop": run.loop},
        metrics=metrics,
        wall_time_s=run.wall_s,
    )
    for k, v in attrs.items():
        if v is None:
            continue
        g.attrs[k] = json.dumps(_clean(v)) if isinstance(v, dict | list) else v
    for name, values in run.signals.items():
        ds = g.create_dataset(name, data=np.asarray(values, dtype=np.float64))
        ds.attrs["units"] = SIGNALS[name]
    gg = g.create_group("gains")
    for name, values in run.gains.items():
        ds = gg.create_dataset(name, data=np.asarray(values, dtype=np.float64))
        ds.attrs["units"] = GAINS[name]
    g.create_dataset("status", data=np.bytes_(run.status.encode("utf-8")[: STATUS_LEN - 1]),
                     dtype=f"S{STATUS_LEN}")
