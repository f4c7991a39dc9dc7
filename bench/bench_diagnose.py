"""Diagnosis: a 14-run simulated campaign, 7 candidate effects, ranking + ladder (goal ≤ 30 s on 2 cores)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from bench.table import print_table

#: 7 pressure levels × 2 frequencies = 14 runs, 3 cycles each
LEVELS = ((0.2, 0.08, 0.13), (0.25, 0.1, 0.16), (0.3, 0.12, 0.19), (0.35, 0.14, 0.22),
          (0.4, 0.18, 0.27), (0.45, 0.2, 0.3), (0.5, 0.24, 0.36))
FREQS = (0.25, 1.0)


def _protocol() -> str:
    lines = ['[protocol]', 'name = "bench-diagnose"', "", "[defaults]", 'waveform = "sine"',
             "cycles = 3", "ramp_s = 1.0", "settle_s = 0.5", ""]
    for p, amp, off in LEVELS:
        for f in FREQS:
            lines += ["[[run]]", f'name = "p{int(p * 1000)}kPa-{f:g}Hz"', 'role = "identification"',
                      f"muscle_pressure_MPa = {p}", f"frequency_Hz = {f}",
                      f"amplitude_MPa = {amp}", f"offset_MPa = {off}", ""]
    return "\n".join(lines)


def main() -> None:
    from pmalab.cli import main as pmalab_main
    from pmalab.identify.diagnose import diagnose
    from pmalab.paths import RIGS_DIR
    from pmalab.runfile import read_runs

    rows = []
    with tempfile.TemporaryDirectory() as td:
        proto = Path(td) / "protocol.toml"
        proto.write_text(_protocol())
        for effect in ("viscous-friction", "clean"):
            rig = RIGS_DIR / ("sim.toml" if effect == "clean" else f"sim-{effect}.toml")
            out = Path(td) / f"{effect}.h5"
            pmalab_main(["run", "--rig", str(rig), "--protocol", str(proto), "--out", str(out),
                         "--seed", "21", "--quiet"])
            runs = read_runs(out)
            diagnose(runs[:2], model="bouc-wen", jobs=1, max_steps=0)  # warm the JIT caches
            t0 = time.perf_counter()
            d = diagnose(runs, model="bouc-wen", jobs=2)
            dt = time.perf_counter() - t0
            n_fits = sum(len(r["candidates"]) for r in d.to_json()["rounds"]) * len(LEVELS) + len(LEVELS)
            rows.append((effect, len(runs), 7, len(d.ladder) - 1, d.winner or "none",
                         d.ladder[0]["nrmse"], d.ladder[-1]["nrmse"], n_fits, dt,
                         "yes" if dt <= 30.0 else "NO"))
    print_table(("hidden effect", "runs", "candidates", "ladder steps", "named", "nrmse base",
                 "nrmse final", "group fits", "time s", "≤ 30 s"), rows)
