"""Simulated rig: speed (times faster than real time) and the seed-case loops."""

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

GOAL = 200.0
RATE = 500.0


def _seed_run(truth: str | None = None) -> tuple[float, float]:
    """One 0.15 Hz × 3-cycle seed run through make_sim_rig at 500 Hz; (sim s, wall s)."""
    rig = make_sim_rig(truth, seed=0, clock=VirtualClock())
    clock, sampler, reg = rig.clock, rig.sampler, rig.cylinder_regulator
    rig.muscle_supply.request(0.4762)
    clock.sleep_until(2.0)
    f, m = 0.15, 0.35
    n = round(3 / f * RATE)
    w0 = time.perf_counter()
    t0 = clock.now()
    for i in range(n):
        clock.sleep_until(t0 + i / RATE)
        sampler.read_block()
        t = clock.now() - t0
        reg.set_pressure(0.5 * m * (1.0 - math.cos(2.0 * math.pi * f * t)))
    wall = time.perf_counter() - w0
    rig.close()
    return n / RATE, wall


def main() -> None:
    _seed_run()  # compile / load the numba cache
    rows = []
    for label, truth in (
        ("effects off", None),
        ("sensor-delay (history lookup)", "data/truth/hidden-sensor-delay.toml"),
    ):
        sim, wall = min((_seed_run(truth) for _ in range(3)), key=lambda r: r[1])
        ratio = sim / wall
        rows.append(
            [
                label,
                f"{sim:.1f}",
                f"{wall * 1e3:.0f}",
                f"{1e6 * wall / (sim * RATE):.1f}",
                f"{ratio:.0f}x",
                f"{GOAL:.0f}x",
                "yes" if ratio >= GOAL else "NO",
            ]
        )
    print(
        "speed: 0.15 Hz x 3 cycles at 500 Hz, VirtualClock, loop of sleep_until/read_block/set_pressure"
    )
    print_table(["case", "sim s", "wall ms", "us/sample", "x real time", "goal", "met"], rows)

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


if __name__ == "__main__":
    main()
