"""Acquisition: simulated seed campaigns vs real time; 500 Hz real-time lateness on the sim rig.

Two sections:

* the seed protocols on the simulated rig's virtual clock — rig seconds recorded per wall
  second (speed ×), including HDF5 writing;
* a real-time run on the simulated rig (RealClock, absolute deadlines, sleep then spin) for
  ``PMALAB_BENCH_RT_SECONDS`` (default 60) s: lateness p50/p99/max of the samples and the
  late (> 0.5 ms) and missed counts.  Goal: p99 ≤ 0.5 ms and none missed.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from bench.table import print_table
from pmalab.acquisition.protocol import load_protocol, parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.rig.base import RealClock
from pmalab.rig.loader import load_rig
from pmalab.runfile import decode_attr


def _campaign(name: str, out: Path) -> list[object]:
    proto = load_protocol(name)
    rig = load_rig("sim", seed=1)
    t0 = time.perf_counter()
    with rig:
        res = run_protocol(rig, proto, out, force=True, options=RunnerOptions(progress=False))
    wall = time.perf_counter() - t0
    rig_s = sum(r.duration_s for r in res)
    n = sum(r.n_samples for r in res)
    missed = sum(int(r.timing.get("missed", 0)) for r in res)
    return [f"{name} (virtual clock)", round(rig_s, 1), round(wall, 2), f"{rig_s / wall:.0f}×",
            n, "-", missed, "-", "-", "-"]


def sine_protocol(seconds: float, name: str):
    """One 0.4 MPa sine run whose recorded length is ~``seconds`` (settle 0.5 s, ramps 1 s
    each): the real-time benches' load."""
    cycles = max(1.0, (seconds - 2.5) * 0.5)
    return parse_protocol(
        f"""
[[run]]
name = "{name}"
muscle_pressure_MPa = 0.4
waveform = "sine"
frequency_Hz = 0.5
magnitude_MPa = 0.3
cycles = {cycles:g}
ramp_s = 1.0
settle_s = 0.5
""",
        name,
    )


def _realtime(seconds: float, out: Path) -> list[object]:
    proto = sine_protocol(seconds, "realtime")
    rig = load_rig("sim", seed=2, clock=RealClock())
    t0 = time.perf_counter()
    with rig:
        (res,) = run_protocol(rig, proto, out, force=True, options=RunnerOptions(progress=False))
    wall = time.perf_counter() - t0
    import h5py

    with h5py.File(out, "r") as f:
        print(f"   real-time scheduling: {decode_attr(f.attrs.get('scheduling', '?'))}")
    t = res.timing
    return ["sim rig, real time (RealClock)", round(res.duration_s, 1), round(wall, 2),
            f"{res.duration_s / wall:.2f}×", res.n_samples, int(t["late"]), int(t["missed"]),
            f"{t['lateness_p50_s'] * 1e3:.3f}", f"{t['lateness_p99_s'] * 1e3:.3f}",
            f"{t['lateness_max_s'] * 1e3:.3f}"]


def main() -> None:
    seconds = float(os.environ.get("PMALAB_BENCH_RT_SECONDS", "60"))
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for name in ("seed-bouc-wen", "seed-duhem"):
            rows.append(_campaign(name, Path(d) / f"{name}.h5"))
        rows.append(_realtime(seconds, Path(d) / "rt.h5"))
    print_table(["mode", "rig s", "wall s", "speed", "samples", "late>0.5ms", "missed",
                 "p50 ms", "p99 ms", "max ms"], rows)
    print("   goal in real time: p99 ≤ 0.5 ms, none missed")


if __name__ == "__main__":
    main()
