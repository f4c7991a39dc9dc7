"""Long records: a 10-hour 500 Hz fatigue record (and a 1-hour 10 kHz one) recorded,
identified and diagnosed within 1.5 GB of resident memory, identify time linear in length.

Each stage is its own ``pmalab`` process under ``/usr/bin/time -v`` (peak resident set
size, wall time): ``run`` on ``data/rigs/sim-fatigue.toml`` (its muscle softens by 2 % an
hour; virtual clock: as fast as the physics runs), ``identify`` (Bouc-Wen; the record is
read a window at a time and decimated to 200 samples a cycle; the parameter trajectory is
fitted along it) and ``diagnose``.  Records of 10 minutes, 1 hour and 10 hours at 500 Hz
give the identify-time table; a 1-hour 10 kHz record the high-rate case.

Environment: ``PMALAB_BENCH_LONG_HOURS`` (default ``0.1667,1,10``: the record lengths at
500 Hz), ``PMALAB_BENCH_LONG_10K_HOURS`` (default ``1``; ``0`` skips it),
``PMALAB_BENCH_LONG_DIR`` (keep the records there and reuse them; default: a temporary
directory), ``PMALAB_BENCH_LONG_STAGES`` (default ``run,identify,diagnose,report``).
First, the trajectory's drift recovery over ``PMALAB_BENCH_LONG_SEEDS`` (default 10) noise
seeds on 100-s records of a −600 %/h drift (the suite test's setting);
``PMALAB_BENCH_LONG_ONLY_SEEDS=1`` stops after it.
Slow: the 10-hour record alone takes tens of minutes of simulation.  Not in the suite.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.table import print_table

#: the issue's memory goal (peak resident set size of each stage)
GOAL_MB = 1536.0
RIG = Path(__file__).resolve().parents[1] / "pmalab" / "data" / "rigs" / "sim-fatigue.toml"


def protocol(hours: float, rate_Hz: float) -> str:
    """One 0.5 Hz sine run of ``hours`` at 0.4 MPa (cycles to fill the time)."""
    cycles = max(2, int(round((hours * 3600.0 - 2.5) * 0.5)))
    return (
        f'[protocol]\nname = "fatigue"\nsample_rate_Hz = {rate_Hz:g}\n[[run]]\nname = "fatigue"\n'
        'muscle_pressure_MPa = 0.4\nwaveform = "sine"\nfrequency_Hz = 0.5\n'
        f"magnitude_MPa = 0.3\ncycles = {cycles}\nramp_s = 1.0\nsettle_s = 0.5\n"
    )


def timed(cmd: list[str]) -> tuple[float, float, str]:
    """(wall s, peak RSS MiB, output) of ``cmd`` under /usr/bin/time -v."""
    t0 = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    rss = int(m.group(1)) / 1024 if m else float("nan")
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{p.stdout}\n{p.stderr[-2000:]}")
    return wall, rss, p.stdout


def pmalab(*args: str) -> list[str]:
    return [sys.executable, "-m", "pmalab.cli", *args]


def record(d: Path, hours: float, rate_Hz: float) -> tuple[Path, float, float]:
    """The record (reused when present in a kept directory), wall s and peak MiB (nan: reused)."""
    tag = f"{hours:g}h-{rate_Hz:g}Hz"
    out = d / f"fatigue-{tag}.h5"
    facts = d / f"fatigue-{tag}.json"  # the recording's own wall time and peak memory
    if out.exists() and facts.exists():
        m = json.loads(facts.read_text())
        return out, float(m["wall_s"]), float(m["peak_MiB"])
    proto = d / f"fatigue-{tag}.toml"
    proto.write_text(protocol(hours, rate_Hz))
    wall, rss, _ = timed(
        pmalab("run", "--rig", str(RIG), "--protocol", str(proto), "--out", str(out), "--quiet",
               "--force")
    )
    facts.write_text(json.dumps({"wall_s": wall, "peak_MiB": rss}))
    return out, wall, rss


def drift_recovery(seeds: int, drift: float = -600.0, cycles: int = 48) -> None:
    """The trajectory's k trend over ``seeds`` noise seeds on short records of a fast drift
    (the suite test's setting): error against the truth and how often the truth lies within
    ± 2 of the trend's standard errors."""
    import numpy as np

    from pmalab.cli import main as cli

    rows, errs, inside = [], [], 0
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        (d / "truth.toml").write_text(f"[muscle]\nstiffness_drift_percent_per_hour = {drift}\n")
        (d / "p.toml").write_text(
            '[protocol]\nname = "fatigue"\n[[run]]\nname = "fatigue"\nmuscle_pressure_MPa = 0.4\n'
            f'waveform = "sine"\nfrequency_Hz = 0.5\nmagnitude_MPa = 0.3\ncycles = {cycles}\n'
            "ramp_s = 1.0\nsettle_s = 0.5\n"
        )
        for seed in range(seeds):
            (d / "rig.toml").write_text(f'[rig]\nkind = "sim"\ntruth = "truth.toml"\nseed = {seed}\n')
            f, out = d / f"r{seed}.h5", d / f"id{seed}"
            cli(["run", "--rig", str(d / "rig.toml"), "--protocol", str(d / "p.toml"), "--out",
                 str(f), "--quiet"])
            cli(["identify", str(f), "--model", "bouc-wen", "--out", str(out), "--quiet"])
            k = json.loads((out / "identification.json").read_text())["trajectory"][0]["trend"]["k"]
            pct = float(k["percent_per_hour"])
            se = 100.0 * float(k["per_hour_stderr"]) / abs(float(k["start"]))
            errs.append(100.0 * (pct / drift - 1.0))
            inside += abs(pct - drift) <= 2 * se
            rows.append([seed, round(pct, 1), round(se, 1), round(errs[-1], 1)])
    print_table(["seed", "k trend %/h", "s.e. %/h", "error % of truth"], rows)
    e = np.abs(np.array(errs))
    print(f"truth {drift:g} %/h over {cycles} cycles: |error| mean {e.mean():.1f} %, max "
          f"{e.max():.1f} % (suite tolerance 10 %); truth within ± 2 s.e. on {inside} of {seeds}")


def main() -> None:
    seeds = int(os.environ.get("PMALAB_BENCH_LONG_SEEDS", "10"))
    if seeds > 0:
        drift_recovery(seeds)
    if os.environ.get("PMALAB_BENCH_LONG_ONLY_SEEDS"):
        return
    hours = [float(h) for h in os.environ.get("PMALAB_BENCH_LONG_HOURS", "0.1667,1,10").split(",")]
    h10k = float(os.environ.get("PMALAB_BENCH_LONG_10K_HOURS", "1"))
    stages = os.environ.get("PMALAB_BENCH_LONG_STAGES", "run,identify,diagnose,report").split(",")
    keep = os.environ.get("PMALAB_BENCH_LONG_DIR")
    cases = [(h, 500.0) for h in hours] + ([(h10k, 10_000.0)] if h10k > 0 else [])
    rows = []
    with tempfile.TemporaryDirectory() as td:
        d = Path(keep) if keep else Path(td)
        d.mkdir(parents=True, exist_ok=True)
        for h, rate in cases:
            f, run_s, run_mb = record(d, h, rate)
            row = [f"{h:g} h", f"{rate:g}", round(h * 3600 * rate / 1e6, 2)]
            row += [round(run_s), round(run_mb)]
            ident = d / f"{f.stem}-id"
            if "identify" in stages:
                wall, rss, _ = timed(
                    pmalab("identify", str(f), "--model", "bouc-wen", "--out", str(ident),
                           "--force", "--quiet")
                )
                doc = json.loads((ident / "identification.json").read_text())
                traj = (doc.get("trajectory") or [{}])[0]
                k = [w["parameters"].get("k") for w in traj.get("windows", [])]
                drift = (100 * (k[-1] / k[0] - 1)) if len(k) > 1 and k[0] else float("nan")
                dec = doc["decimation"][0]["read"]
                row += [round(wall, 1), round(rss), dec.get("stride", 1), len(k), round(drift, 1)]
            else:
                row += ["-"] * 5
            if "diagnose" in stages:
                wall, rss, _ = timed(
                    pmalab("diagnose", str(f), "--model", "bouc-wen", "--out",
                           str(d / f"{f.stem}-diag"), "--force", "--quiet")
                )
                row += [round(wall, 1), round(rss)]
            else:
                row += ["-", "-"]
            if "report" in stages and "identify" in stages:
                wall, rss, _ = timed(
                    pmalab("report", str(ident), "--out", str(d / f"{f.stem}.pdf"), "--force")
                )
                row += [round(wall, 1), round(rss)]
            else:
                row += ["-", "-"]
            rows.append(row)
            print(row, flush=True)
    print_table(
        ["record", "rate Hz", "Msamples", "run s", "run MiB", "identify s", "identify MiB",
         "read stride", "trajectory windows", "k drift %", "diagnose s", "diagnose MiB",
         "report s", "report MiB"],
        rows,
    )
    print(f"goal: every stage ≤ {GOAL_MB:.0f} MiB peak resident; identify s ∝ record length; "
          "truth: k drifts −2 %/h (−20 % over 10 h)")


if __name__ == "__main__":
    main()
