"""The parameter trajectory of a long record: the model refitted window by window along it.

In a fatigue or creep test the drift of the muscle over hours *is* the result.  One fit of
a whole 10-hour record gives the average muscle; the trajectory fits the same model (law,
effects, the run's fixed parameters) to consecutive windows of whole excitation cycles, so
k, c0 and the hysteresis parameters are seen against the cycle count, each with the
standard error of its window's fit, and a weighted straight line through each parameter
states its drift (per hour of the record and in % of its start value per hour) with the
line's standard error.

Which runs: a run of at least :data:`MIN_CYCLES` excitation cycles; its windows are
:data:`WINDOWS` runs of whole cycles (fewer, of :data:`MIN_WINDOW_CYCLES` cycles each, on
a shorter record).  Each window's fit starts from the whole run's parameters (no start
grid: the windows are the same muscle a little later), so the cost is the record's length
once over — linear in it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from pmalab.identify.estimation.single import FitError, FitResult, fit_run
from pmalab.identify.model import ForceModel
from pmalab.runfile import Run

#: a run with at least this many excitation cycles gets a trajectory
MIN_CYCLES = 40
#: windows along a long record
WINDOWS = 24
#: ... each of at least this many whole cycles
MIN_WINDOW_CYCLES = 4


def cycle_windows(run: Run, n_windows: int = WINDOWS) -> tuple[list[slice], int]:
    """Consecutive windows of whole excitation cycles along ``run`` and the cycles in each:
    ``n_windows`` of them (fewer on a short record, ≥ :data:`MIN_WINDOW_CYCLES` cycles
    each); ([], 0) when the run holds fewer than :data:`MIN_CYCLES` cycles or its
    frequency is unknown."""
    f = run.frequency or 0.0
    n = len(run)
    if f <= 0 or n < 2:
        return [], 0
    dt = float(np.median(np.diff(run.time[: min(n, 4096)])))
    per_cycle = 1.0 / (f * dt) if dt > 0 else 0.0
    cycles = int(n // per_cycle) if per_cycle >= 2 else 0
    if cycles < MIN_CYCLES:
        return [], 0
    per_window = max(MIN_WINDOW_CYCLES, cycles // n_windows)
    k = cycles // per_window
    size = per_window * per_cycle
    return [slice(int(round(i * size)), int(round((i + 1) * size))) for i in range(k)], per_window


def _part(run: Run, s: slice) -> Run:
    """The samples ``s`` of ``run`` (views; attrs without the full-amplitude window)."""
    attrs = {k: v for k, v in run.attrs.items() if k not in ("steady_start_s", "steady_end_s")}
    cp, cpc = run.cylinder_pressure, run.cylinder_pressure_command
    return Run(
        name=run.name,
        time=run.time[s],
        position=run.position[s],
        force=run.force[s],
        muscle_pressure=run.muscle_pressure[s],
        cylinder_pressure=None if cp is None else cp[s],
        cylinder_pressure_command=None if cpc is None else cpc[s],
        attrs=attrs,
        file=run.file,
    )


def trend(t_h: np.ndarray, y: np.ndarray, se: np.ndarray | None) -> dict[str, float | None]:
    """Weighted straight line ``y = a + b·t`` (``t`` in hours; weights 1/se², equal when
    any se is missing): ``start`` a, ``per_hour`` b and its standard error (scaled by the
    fit's reduced χ², so a scatter wider than the stated errors widens it), and
    ``percent_per_hour`` = 100·b/a."""
    ok = np.isfinite(y)
    t, v = t_h[ok], y[ok]
    if t.size < 3 or np.ptp(t) <= 0:
        return {"start": None, "per_hour": None, "per_hour_stderr": None, "percent_per_hour": None}
    w = np.ones_like(v)
    weighted = False
    if se is not None:
        s = se[ok]
        if np.all(np.isfinite(s)) and np.all(s > 0):
            w, weighted = 1.0 / s**2, True
    a_mat = np.column_stack([np.ones_like(t), t]) * np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(a_mat, v * np.sqrt(w), rcond=None)
    resid = (v - (coef[0] + coef[1] * t)) * np.sqrt(w)
    dof = max(1, t.size - 2)
    chi2 = float(resid @ resid) / dof
    # stated errors: never narrower than they say; none: the scatter is the error
    cov = np.linalg.pinv(a_mat.T @ a_mat) * (max(chi2, 1.0) if weighted else chi2)
    a, b = float(coef[0]), float(coef[1])
    return {
        "start": a,
        "per_hour": b,
        "per_hour_stderr": float(math.sqrt(max(cov[1, 1], 0.0))),
        "percent_per_hour": (100.0 * b / a) if a != 0 else None,
    }


def run_trajectory(
    run: Run,
    model: ForceModel,
    whole: FitResult,
    *,
    n_windows: int = WINDOWS,
) -> dict[str, Any] | None:
    """The trajectory of one run (None when it is too short, :func:`cycle_windows`).

    ``whole`` is the run's own fit: its values start every window's fit and its fixed
    parameters stay fixed at them (every window is the same model).  A window whose fit
    fails is reported with its reason and no parameters."""
    wins, per_window = cycle_windows(run, n_windows)
    if not wins:
        return None
    start = dict(whole.values)
    fixed: Mapping[str, float | None] = {k: start[k] for k in whole.fixed if k in start}
    f = float(run.frequency or 0.0)
    t0 = float(run.time[0])
    rows: list[dict[str, Any]] = []
    for i, s in enumerate(wins):
        part = _part(run, s)
        row: dict[str, Any] = {
            "window": i,
            "cycle_start": i * per_window,
            "cycle_end": (i + 1) * per_window,
            "time_s": float(0.5 * (part.time[0] + part.time[-1]) - t0),
        }
        try:
            res = fit_run(part, model, fixed=dict(fixed), init=start, auto_fix=False)
        except (FitError, ValueError, np.linalg.LinAlgError) as exc:
            row.update(status="failed", reason=str(exc).splitlines()[0][:200])
            rows.append(row)
            continue
        row.update(
            status="ok",
            parameters={k: float(v) for k, v in res.values.items()},
            stderr={k: (None if v is None else float(v)) for k, v in res.stderr.items()},
            nrmse=float(res.nrmse),
            rmse=float(res.rmse),
        )
        rows.append(row)
    good = [r for r in rows if r["status"] == "ok"]
    names = [n for n in whole.names if n not in ("h0",)]
    trends: dict[str, Any] = {}
    if good:
        t_h = np.array([r["time_s"] for r in good]) / 3600.0
        for n in names:
            y = np.array([r["parameters"].get(n, np.nan) for r in good], dtype=float)
            se = np.array(
                [np.nan if r["stderr"].get(n) is None else r["stderr"][n] for r in good],
                dtype=float,
            )
            trends[n] = trend(t_h, y, se)
    return {
        "file": run.file,
        "run": run.name,
        "frequency_Hz": f,
        "cycles_per_window": per_window,
        "windows": rows,
        "parameters": names,
        "trend": trends,
        "method": (
            f"the model refitted on {len(wins)} consecutive windows of {per_window} whole "
            "cycles (start: the run's own fit; its fixed parameters held); stderr per window "
            "from its fit; trend: weighted least-squares line vs time (1/stderr²), its "
            "stderr scaled by the reduced chi-square"
        ),
    }
