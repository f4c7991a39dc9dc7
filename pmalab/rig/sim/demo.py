"""One isobaric cycle on the simulated rig, and the numbers the demo prints."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from pmalab.rig.sim.physics import RigPhysics
from pmalab.rig.sim.truth import Truth


def run_isobaric(
    truth: Truth | str | Path | None = None,
    *,
    muscle_MPa: float = 0.4762,
    frequency_Hz: float = 0.15,
    magnitude_MPa: float = 0.35,
    cycles: float = 1.0,
    waveform: str = "sine",
    warmup_cycles: float = 1.0,
    sample_rate_Hz: float = 500.0,
    seed: int = 0,
    settle_s: float = 2.0,
    physics: RigPhysics | None = None,
) -> dict[str, np.ndarray]:
    """Drive RigPhysics directly through an isobaric test; return the measured channels.

    Cylinder command ``M/2·(1 − cos 2πft)`` (sine) or a triangle 0 → M → 0 — i.e. offset =
    amplitude = M/2, starting at 0 — with the muscle supply held at ``muscle_MPa``.  The
    first ``warmup_cycles`` are run but not returned.  Also returns the true state
    (``true_position``, ``true_tension``, ``true_muscle_pressure``) and the command.
    """
    ph = physics if physics is not None else RigPhysics(truth, seed=seed)
    ph.set_muscle_supply(muscle_MPa)
    ph.advance_to(ph.time + settle_s)
    t0 = ph.time
    dt = 1.0 / sample_rate_Hz
    n_warm = round(warmup_cycles / frequency_Hz * sample_rate_Hz)
    n = round(cycles / frequency_Hz * sample_rate_Hz) + 1
    keys = ("time", "position", "force", "muscle_pressure", "cylinder_pressure")
    out = {k: np.empty(n) for k in keys}
    extra = {
        k: np.empty(n) for k in ("command", "true_position", "true_tension", "true_muscle_pressure")
    }
    for i in range(n_warm + n):
        t = t0 + i * dt
        phase = (frequency_Hz * (t - t0)) % 1.0
        if waveform == "sine":
            cmd = 0.5 * magnitude_MPa * (1.0 - math.cos(2.0 * math.pi * phase))
        else:
            cmd = magnitude_MPa * (2.0 * phase if phase < 0.5 else 2.0 - 2.0 * phase)
        o = ph.advance_and_sample(t)
        ph.set_cylinder_command(cmd)
        j = i - n_warm
        if j >= 0:
            for c, k in enumerate(keys):
                out[k][j] = o[c]
            ts = ph.truth_state()
            extra["command"][j] = cmd
            extra["true_position"][j] = ts["position"]
            extra["true_tension"][j] = ts["tension"]
            extra["true_muscle_pressure"][j] = ts["muscle_pressure"]
    out.update(extra)
    return out


def hysteresis_width(position: np.ndarray, force: np.ndarray, n_grid: int = 60) -> float:
    """Max force difference (N) between the stretch (x falling) and release (x rising)
    branches of one loop, compared at equal position on the overlapping range.

    The positions are lightly smoothed to tell the branches apart despite noise.
    """
    x = np.asarray(position, float)
    f = np.asarray(force, float)
    k = 25
    xs = np.convolve(x, np.ones(k) / k, mode="same")
    fs = np.convolve(f, np.ones(k) / k, mode="same")
    xs, fs = xs[k:-k], fs[k:-k]
    v = np.gradient(xs)
    down = v < 0
    up = v > 0
    if down.sum() < 10 or up.sum() < 10:
        return 0.0
    lo = max(xs[down].min(), xs[up].min())
    hi = min(xs[down].max(), xs[up].max())
    if hi <= lo:
        return 0.0
    grid = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), n_grid)

    def branch(mask: np.ndarray) -> np.ndarray:
        order = np.argsort(xs[mask])
        return np.interp(grid, xs[mask][order], fs[mask][order])

    return float(np.max(branch(down) - branch(up)))


def demo_cycle(truth: Truth | str | Path | None = None) -> dict[str, Any]:
    """One isobaric cycle: 0.4762 MPa, 0.15 Hz, 0–0.35 MPa sine cylinder pressure.

    Returns ``force_min``/``force_max``/``force_range`` (N), ``position_min``/``position_max``
    (mm), ``hysteresis_width`` (N, stretch minus release branch at equal position — positive
    for a loop in the physical direction) and the cycle's arrays under ``"data"``.
    """
    d = run_isobaric(truth, muscle_MPa=0.4762, frequency_Hz=0.15, magnitude_MPa=0.35)
    f = d["force"]
    x = d["position"]
    return {
        "muscle_pressure_MPa": 0.4762,
        "frequency_Hz": 0.15,
        "magnitude_MPa": 0.35,
        "force_min": float(f.min()),
        "force_max": float(f.max()),
        "force_range": float(f.max() - f.min()),
        "position_min": float(x.min()),
        "position_max": float(x.max()),
        "hysteresis_width": hysteresis_width(x, f),
        "data": d,
    }
