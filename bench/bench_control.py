"""Control: one controller step (µs), simulated manipulator speed, seed-experiment metrics."""

from __future__ import annotations

import math
import os
import time

os.environ.setdefault(
    "NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".venv", "numba-cache")
)

import numpy as np

from bench.table import print_table
from pmalab.control.cascade import Cascade
from pmalab.control.controllers import default_settings
from pmalab.control.experiments import SEED_EXPERIMENTS, load_experiments
from pmalab.control.model import IdentifiedModel
from pmalab.control.record import run_metrics
from pmalab.control.runner import run_control
from pmalab.rig.base import VirtualClock
from pmalab.rig.sim.manipulator import make_sim_manipulator

STEP_MEDIAN_US = 50.0
STEP_P99_US = 200.0
SPEED_GOAL = 100.0
#: the issue's targets for the adaptive controllers
TARGETS = {"overshoot_pct": 5.0, "settling_time_s": 3.0, "steady_state_error": 0.3,
           "sine_rms_mm": 1.0}


def _step_times(controller: str, model: IdentifiedModel, n: int = 20000) -> np.ndarray:
    """Per-call time (s) of one cascade step (both loops, model inversion, h step) on a
    recorded-like input: a 0.5 Hz sine around 10 mm with sensor-size noise."""
    rig = make_sim_manipulator()
    c = Cascade(controller, default_settings(), model, rig.geometry, 0.6)
    rng = np.random.default_rng(0)
    t = np.arange(n) * 0.002
    x = 10 + 5 * np.sin(2 * math.pi * 0.5 * t) + 0.015 * rng.standard_normal(n)
    p = 0.3 + 0.1 * np.sin(2 * math.pi * 0.5 * t - 0.5)
    r = 10 + 5 * np.sin(2 * math.pi * 0.5 * t + 0.1)
    out = np.empty(n)
    step = c.position_step
    for k in range(200):  # warm caches
        step(float(r[k]), 0.0, 0.0, float(x[k]), float(p[k]))
    pc = time.perf_counter
    for k in range(n):
        a = pc()
        step(float(r[k]), 0.0, 0.0, float(x[k]), float(p[k]))
        out[k] = pc() - a
    return out


def _plant_speed(seconds: float = 20.0) -> float:
    """Simulated seconds per wall second of the manipulator alone (advance + sample at
    500 Hz, a command every sample), best of 3."""
    best = 0.0
    for _ in range(3):
        rig = make_sim_manipulator(clock=VirtualClock())
        n = int(seconds * 500)
        reg, read, clock = rig.muscle_regulator, rig.sampler.read_now, rig.clock
        w0 = time.perf_counter()
        for k in range(n):
            clock.sleep_until(k * 0.002)
            read()
            reg.set_pressure(0.2 + 0.1 * math.sin(k * 0.002))
        best = max(best, seconds / (time.perf_counter() - w0))
        rig.close()
    return best


def _check(v: float | None, goal: float) -> str:
    if v is None or not math.isfinite(v):
        return "FAIL (never settles)"
    return "ok" if v <= goal else "FAIL"


def main() -> None:
    model = IdentifiedModel.load(None)
    rows = []
    for c in ("pid", "sn-pid", "rbf-pid"):
        us = _step_times(c, model) * 1e6
        med, p99 = float(np.median(us)), float(np.percentile(us, 99))
        rows.append((c, med, p99, f"≤ {STEP_MEDIAN_US:g} / ≤ {STEP_P99_US:g}",
                     "ok" if med <= STEP_MEDIAN_US and p99 <= STEP_P99_US else "FAIL"))
    load = os.getloadavg()[0]
    print("one controller step, both loops + model inversion + hysteresis step (µs); "
          f"machine load {load:.1f} on {os.cpu_count()} CPUs (p99 includes preemption):")
    print_table(["controller", "median", "p99", "target", "check"], rows)

    speed = _plant_speed()
    print()
    print_table(["simulated manipulator", "× real time", "target", "check"],
                [("advance + sample + command, 500 Hz", speed, f"≥ {SPEED_GOAL:g}",
                  "ok" if speed >= SPEED_GOAL else "FAIL")])

    es = load_experiments(SEED_EXPERIMENTS)
    rows = []
    closed = []
    for e in es.experiments:
        for c in es.controllers:
            rig = make_sim_manipulator(seed=es.seed)
            with rig:
                run = run_control(rig, c, e.reference, e.duration_s, es.settings, model, name=c)
            closed.append(e.duration_s / run.wall_s)
            m = run_metrics(run)
            u = e.reference.unit
            row = [e.name, c, run.status if not run.completed else "ok"]
            if m["kind"] == "square":
                row += [_f(m.get("overshoot_pct")), _f(m.get("rise_time_s")),
                        _f(m.get("settling_time_s")), _f(m.get("steady_state_error"), u)]
            else:
                row += ["", "", "", ""]
            row.append(_f(m.get("rms_error"), u))
            row.append(_verdict(e.name, c, m))
            rows.append(row)
    print()
    print("seed experiments (20 s, same initial gains; targets for the adaptive ones on the "
          "15 mm square: overshoot ≤ 5 %, settling ≤ 3 s, sse ≤ 0.3 mm; sine 20 mm: RMS ≤ 1 mm):")
    print_table(["experiment", "controller", "status", "overshoot %", "rise s", "settling s",
                 "sse", "RMS error", "target"], rows)
    print(f"closed loop (plant + controller + recording): {np.median(closed):.0f}× real time "
          "(median over the runs)")


def _f(v, unit: str = "") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "never"
    return f"{v:.3g}" + (f" {unit}" if unit else "")


def _verdict(exp: str, controller: str, m: dict) -> str:
    if controller == "pid":
        return ""
    if exp == "position-square-15mm":
        checks = [_check(m.get("overshoot_pct"), TARGETS["overshoot_pct"]),
                  _check(m.get("settling_time_s"), TARGETS["settling_time_s"]),
                  _check(m.get("steady_state_error"), TARGETS["steady_state_error"])]
        return "ok" if all(c == "ok" for c in checks) else "FAIL (" + ", ".join(
            n for n, c in zip(("overshoot", "settling", "sse"), checks) if c != "ok") + ")"
    if exp == "position-sine-20mm":
        return _check(m.get("rms_error"), TARGETS["sine_rms_mm"])
    return ""


if __name__ == "__main__":
    main()
