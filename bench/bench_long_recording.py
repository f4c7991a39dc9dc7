"""A long real-time recording with the live view open: the recorder's memory stays flat and
its lateness does not drift.

``pmalab run --rig sim --realtime --live`` of one 500 Hz sine run lasting
``PMALAB_BENCH_LONG_S`` seconds (default 1800: 30 minutes), one SSE client reading the live
page's event stream throughout.  Every 10 s the recorder process's resident memory is read
(psutil).  Reported: RSS after the first minute and at the end (growth, goal ≤ 5 %), and
the lateness p99 of the first and the last minute (goal: unchanged).  Not in the suite.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from bench.bench_live import SSE_CLIENT
from bench.table import print_table


def main() -> None:
    import psutil

    seconds = float(os.environ.get("PMALAB_BENCH_LONG_S", "1800"))
    cycles = max(1.0, (seconds - 2.5) * 0.5)
    with tempfile.TemporaryDirectory() as td:
        proto = Path(td) / "long.toml"
        proto.write_text(f'[protocol]\nname = "long"\n[[run]]\nname = "long"\n'
                         f'muscle_pressure_MPa = 0.4\nwaveform = "sine"\nfrequency_Hz = 0.5\n'
                         f'magnitude_MPa = 0.3\ncycles = {cycles:g}\nramp_s = 1.0\n'
                         f'settle_s = 0.5\n')
        out = Path(td) / "long.h5"
        rec = subprocess.Popen([sys.executable, "-m", "pmalab.cli", "run", "--rig", "sim",
                                "--realtime", "--protocol", str(proto), "--out", str(out),
                                "--live", "127.0.0.1:0", "--quiet"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        port = None
        while port is None:
            line = rec.stdout.readline()
            if not line:
                raise RuntimeError("the recorder ended before its live page started")
            m = re.search(r"http://127\.0\.0\.1:(\d+)", line)
            if m:
                port = int(m.group(1))
        client = subprocess.Popen([sys.executable, "-c", SSE_CLIENT, str(port),
                                   str(seconds + 120)], stdout=subprocess.PIPE, text=True)
        proc = psutil.Process(rec.pid)
        rss: list[tuple[float, float]] = []
        t0 = time.monotonic()
        while rec.poll() is None:
            try:
                rss.append((time.monotonic() - t0, proc.memory_info().rss / 2**20))
            except psutil.Error:
                break
            time.sleep(10)
        rec.communicate()
        client.communicate(timeout=180)
        with h5py.File(out, "r") as f:
            g = f["runs/long"]
            late = np.asarray(g["lateness"][()], dtype=float)
            t = np.asarray(g["time"][()], dtype=float)
    first = late[t < 60]
    last = late[t > t[-1] - 60]
    r1 = next(v for s, v in rss if s >= 60) if any(s >= 60 for s, _ in rss) else rss[0][1]
    r_end = rss[-1][1]
    print_table(["recorded s", "RSS after 1 min MiB", "RSS at end MiB", "growth %",
                 "lateness p99 first min ms", "lateness p99 last min ms", "samples"],
                [[round(float(t[-1]), 0), round(r1, 1), round(r_end, 1),
                  round(100 * (r_end / r1 - 1), 1), round(1e3 * np.percentile(first, 99), 3),
                  round(1e3 * np.percentile(last, 99), 3), len(t)]])
