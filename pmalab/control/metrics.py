"""Step and tracking metrics from recorded data, defined as python-control's ``step_info``.

For one step (python-control 0.10 ``step_info``, with the step's own start value y0
subtracted, since a square's down-step starts from the top; ``Δ = y_final − y0``):

* **rise time**: from the first sample with (y − y0) ≥ 10 % of Δ to the first with ≥ 90 %
  (signs follow Δ), s;
* **settling time** (2 %): the time of the first sample after the last one with
  |(y − y0)/Δ − 1| ≥ 0.02, measured from the step; NaN and ``settled = False`` when the
  last sample is still outside the band (the response never settles);
* **overshoot**: 100·(peak beyond y_final)/|Δ| %, 0 if the response never passes y_final;
* **steady-state error**: |r − y_final| in the signal's units;

y_final is python-control's ``yfinal`` — by default the last sample; here the mean of
the step window's last ``final_window_s`` (0.1 s = 50 samples), so 0.015 mm of sensor
noise does not move the band.  A step is only analysed when |Δ| is at least 10 noise
widths; a response that never reaches 10 %/90 % gets NaN rise time (flag
``reached = False``).  Tracking: RMS and max |r − y| over the analysed window.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

SETTLING_THRESHOLD = 0.02
RISE_LIMITS = (0.1, 0.9)


@dataclass(frozen=True)
class StepInfo:
    """python-control's step_info fields (times in s from the step, overshoot in %)."""

    rise_time: float
    settling_time: float
    overshoot: float
    undershoot: float
    peak: float
    peak_time: float
    steady_state_value: float
    settled: bool
    reached: bool

    def to_dict(self) -> dict:
        return asdict(self)


def step_info(
    t: np.ndarray,
    y: np.ndarray,
    y0: float = 0.0,
    y_final: float | None = None,
    settling_threshold: float = SETTLING_THRESHOLD,
    rise_limits: tuple[float, float] = RISE_LIMITS,
) -> StepInfo:
    """Step characteristics of ``y(t)`` (``t`` from the step instant, s).

    ``y0``: the value before the step (python-control assumes 0); ``y_final``: the final
    value (default: the last sample, as python-control).
    """
    t = np.asarray(t, dtype=float)
    yr = np.asarray(y, dtype=float) - y0
    inf = float(yr[-1]) if y_final is None else float(y_final) - y0
    nan = math.nan
    if not math.isfinite(inf) or inf == 0.0 or yr.size < 2:
        return StepInfo(nan, nan, nan, nan, nan, nan, inf + y0, False, False)
    sgn = math.copysign(1.0, inf)
    lo = np.flatnonzero(sgn * (yr - rise_limits[0] * inf) >= 0)
    hi = np.flatnonzero(sgn * (yr - rise_limits[1] * inf) >= 0)
    reached = lo.size > 0 and hi.size > 0
    rise = float(t[hi[0]] - t[lo[0]]) if reached else nan
    outside = np.flatnonzero(np.abs(yr / inf - 1.0) >= settling_threshold)
    settled_at = 0 if outside.size == 0 else int(outside[-1]) + 1
    settled = settled_at < t.size
    settling = float(t[settled_at]) if settled else nan
    y_os = float((sgn * yr).max())
    dy_os = abs(y_os) - abs(inf)
    overshoot = abs(100.0 * dy_os / inf) if dy_os > 0 else 0.0
    y_us = float((sgn * yr).min())
    undershoot = abs(100.0 * y_us / inf) if y_us < 0 else 0.0
    ip = int(np.argmax(sgn * yr))
    return StepInfo(
        rise,
        settling,
        overshoot,
        undershoot,
        float(yr[ip] + y0),
        float(t[ip]),
        inf + y0,
        bool(settled),
        bool(reached),
    )


@dataclass(frozen=True)
class StepResult:
    """One step of a recorded square response."""

    t_step: float
    r_before: float
    r_after: float
    info: StepInfo
    steady_state_error: float

    def to_dict(self) -> dict:
        d = self.info.to_dict()
        d.update(
            t_step=self.t_step,
            r_before=self.r_before,
            r_after=self.r_after,
            steady_state_error=self.steady_state_error,
        )
        return d


def square_steps(
    t: np.ndarray,
    y: np.ndarray,
    r: np.ndarray,
    step_times: Sequence[float],
    final_window_s: float = 0.1,
    min_step: float = 0.0,
) -> list[StepResult]:
    """step_info of every step of a square reference that the recording covers whole.

    Each window runs from one step to the next (or the end of the data); it is analysed
    when it holds at least ``final_window_s`` of samples after the step and the
    reference changes by more than ``min_step``.
    """
    t = np.asarray(t, dtype=float)
    out = []
    bounds = [*list(step_times), math.inf]
    for a, b in itertools.pairwise(bounds):
        i0 = int(np.searchsorted(t, a - 1e-9))
        i1 = int(np.searchsorted(t, b - 1e-9)) if math.isfinite(b) else t.size
        if i0 >= t.size or t[i1 - 1] - t[i0] < max(final_window_s, 0.5) or b - a <= 0:
            continue
        if math.isfinite(b) and t[-1] < b - 2 * (t[1] - t[0]):
            continue  # the recording stops inside this step: its final value is unknown
        r_after = float(r[i0])
        r_before = float(r[i0 - 1]) if i0 > 0 else 0.0
        if abs(r_after - r_before) <= min_step:
            continue
        y0 = float(y[i0 - 1]) if i0 > 0 else float(y[i0])
        tw, yw = t[i0:i1] - a, y[i0:i1]
        nf = max(1, int(np.sum(tw >= tw[-1] - final_window_s)))
        y_final = float(np.mean(yw[-nf:]))
        info = step_info(tw, yw, y0=y0, y_final=y_final)
        out.append(StepResult(float(a), r_before, r_after, info, abs(r_after - y_final)))
    return out


def tracking(t: np.ndarray, y: np.ndarray, r: np.ndarray, t_from: float = 0.0) -> dict:
    """RMS and max |r − y| from ``t_from`` on (signal units)."""
    keep = np.asarray(t) >= t_from
    e = np.asarray(r)[keep] - np.asarray(y)[keep]
    if e.size == 0:
        return {"rms_error": math.nan, "max_error": math.nan}
    return {"rms_error": float(np.sqrt(np.mean(e * e))), "max_error": float(np.max(np.abs(e)))}


def summarize(
    kind: str, t: np.ndarray, y: np.ndarray, r: np.ndarray, step_times: Sequence[float]
) -> dict:
    """The metrics table row of one run: steps (square) and tracking (both).

    Square: ``overshoot_pct`` is the largest over the steps (the seeds report the maximum),
    ``rise_time_s`` the mean of the up-steps', ``settling_time_s`` the largest (NaN if any
    step never settles, with ``settled = False``), ``steady_state_error`` the largest.
    """
    out: dict = {"kind": kind, **tracking(t, y, r)}
    if kind != "square":
        return out
    steps = square_steps(t, y, r, step_times)
    out["steps"] = [s.to_dict() for s in steps]
    if not steps:
        out.update(
            overshoot_pct=math.nan,
            rise_time_s=math.nan,
            settling_time_s=math.nan,
            steady_state_error=math.nan,
            settled=False,
        )
        return out
    up = [s for s in steps if s.r_after > s.r_before]
    rises = [s.info.rise_time for s in (up or steps)]
    settle = [s.info.settling_time for s in steps]
    out.update(
        overshoot_pct=max(s.info.overshoot for s in steps),
        overshoot_up_pct=max((s.info.overshoot for s in up), default=math.nan),
        rise_time_s=float(np.mean(rises)),
        settling_time_s=(max(settle) if all(math.isfinite(v) for v in settle) else math.nan),
        steady_state_error=max(s.steady_state_error for s in steps),
        settled=all(s.info.settled for s in steps),
    )
    return out
