"""Simulated rig: speed (times faster than real time), seed-case loops, hidden-effect sizes."""

from __future__ import annotations

import math
import os
import time

os.environ.setdefault(
    "NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".venv", "numba-cache")
)

from bench.table import print_table
from pmalab.rig.base import VirtualClock
from pmalab.rig.sim import make_sim_rig
from pmalab.rig.sim.demo import hysteresis_width, run_isobaric
from pmalab.rig.sim.reference import baseline_tension
from pmalab.rig.sim.truth import EFFECT_SECTIONS

GOAL = 200.0
RATE = 500.0


def _seed_run(truth: str | None = None) -> tuple[float, float, float]:
    """One 0.15 Hz × 3-cycle seed run through make_sim_rig at 500 Hz.

    Returns (simulated s, wall s, CPU s of this process)."""
    rig = make_sim_rig(truth, seed=0, clock=VirtualClock())
    clock, sampler, reg = rig.clock, rig.sampler, rig.cylinder_regulator
    rig.muscle_supply.request(0.4762)
    clock.sleep_until(2.0)
    f, m = 0.15, 0.35
    n = round(3 / f * RATE)
    w0 = time.perf_counter()
    c0 = time.process_time()
    t0 = clock.now()
    for i in range(n):
        clock.sleep_until(t0 + i / RATE)
        sampler.read_block()
        t = clock.now() - t0
        reg.set_pressure(0.5 * m * (1.0 - math.cos(2.0 * math.pi * f * t)))
    wall = time.perf_counter() - w0
    cpu = time.process_time() - c0
    rig.close()
    return n / RATE, wall, cpu


def main() -> None:
    _seed_run()  # compile / load the numba cache
    rows = []
    for label, truth in (
        ("effects off", None),
        ("sensor-delay (history lookup)", "data/truth/hidden-sensor-delay.toml"),
    ):
        runs = [_seed_run(truth) for _ in range(5)]
        sim = runs[0][0]
        wall = min(r[1] for r in runs)
        cpu = min(r[2] for r in runs)
        ratio = sim / wall
        rows.append(
            [
                label,
                f"{sim:.1f}",
                f"{wall * 1e3:.0f}",
                f"{1e6 * wall / (sim * RATE):.1f}",
                f"{ratio:.0f}x",
                f"{sim / cpu:.0f}x",
                f"{GOAL:.0f}x",
                "yes" if ratio >= GOAL else "NO",
            ]
        )
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        "speed: 0.15 Hz x 3 cycles at 500 Hz, VirtualClock, loop of sleep_until/read_block/"
        f"set_pressure; best of 5 (load average {load:.1f} on {os.cpu_count()} CPUs)"
    )
    print_table(
        ["case", "sim s", "wall ms", "us/sample", "x real (wall)", "x real (cpu)", "goal", "met"],
        rows,
    )

    print("\nseed cases (effects off, one cycle after one warm-up cycle):")
    cases = [
        (0.4762, 0.15, 0.35, "sine"),
        (0.498, 0.1, 0.37, "sine"),
        (0.304, 0.3, 0.25, "sine"),
        (0.3102, 0.1, 0.31, "triangle"),
        (0.3984, 0.1, 0.31, "triangle"),
        (0.451, 0.2, 0.31, "sine"),
        (0.6, 0.15, 0.6, "sine"),
    ]
    rows = []
    for p, f, m, w in cases:
        d = run_isobaric(None, muscle_MPa=p, frequency_Hz=f, magnitude_MPa=m, waveform=w)
        x, F = d["position"], d["force"]
        rows.append(
            [
                f"{p:g} MPa {f:g} Hz 0-{m:g} {w}",
                f"{F.min():.0f}..{F.max():.0f}",
                f"{x.min():.1f}..{x.max():.1f}",
                f"{hysteresis_width(x, F):.0f}",
            ]
        )
    print_table(["case", "force N", "position mm", "loop width N"], rows)

    print("\neffect sizes: rms(measured force - baseline truth law along the measured position)")
    print("as % of the force std (second of two cycles; the baseline row is the noise floor)")
    rows = []
    for eid in ["baseline", *EFFECT_SECTIONS, "two-effects"]:
        truth = None if eid == "baseline" else f"data/truth/hidden-{eid}.toml"
        row = [eid]
        for f in (0.15, 0.3, 2.0):
            row.append(f"{100 * _effect_size(truth, f):.1f}")
        rows.append(row)
    print_table(["truth", "0.15 Hz %", "0.3 Hz %", "2 Hz %"], rows)


def _effect_size(truth: str | None, f: float) -> float:
    import numpy as np

    d = run_isobaric(
        truth, muscle_MPa=0.4762, frequency_Hz=f, magnitude_MPa=0.35, cycles=2, warmup_cycles=2
    )
    k = 11
    w = np.ones(k) / k
    x = np.pad(d["position"], k, mode="edge")
    x = np.convolve(np.convolve(x, w, mode="same")[::-1], w, mode="same")[::-1][k:-k]
    ref = baseline_tension(x, 0.4762)
    sl = slice(len(x) // 2, None)
    return float(np.sqrt(np.mean((d["force"][sl] - ref[sl]) ** 2)) / d["force"][sl].std())


if __name__ == "__main__":
    main()
