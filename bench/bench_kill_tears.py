"""Kill -9 mid-flush: how often a recorder's last chunk is torn, and what the readers keep.

A subprocess runs the recorder's writer committing (resize + write + flush, SWMR) as fast
as it can, ``PMALAB_BENCH_TEARS_BATCH`` (default 10) samples a commit, and is killed with
SIGKILL at a random 0.05–0.6 s; ``PMALAB_BENCH_TEARS_N`` (default 100) kills.  Each flush
rewrites every channel's partly filled last chunk in place (a 32 KiB ``pwrite``), and a kill
inside that write leaves the chunk's checksum stale.  Columns: kills; files with a chunk
HDF5 refuses (what the readers refused before torn chunks were checked against their
previous checksum); of those, the chunk being the last; reads that fail now (must be 0);
reads that cut a run with a loss warning; recovered files whose length differs from the
extent on disk (must be 0).
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

from bench.table import print_table

ROOT = Path(__file__).resolve().parents[1]
WRITER = """
import sys
import numpy as np
from pmalab.acquisition.recorder import Recorder
rec = Recorder(sys.argv[1], [("a", {"muscle_pressure_MPa": 0.4})], {})
w = rec.writer("a")
w.set_status("running")
rng = np.random.default_rng()
i = 0
open(sys.argv[1] + ".go", "w").close()
while True:
    for _ in range(int(sys.argv[2])):
        w.add(i * 0.002, rng.normal(), rng.normal(), 0.4, 0.1, 0.1, 0.0)
        i += 1
    w.commit()
"""


def _killed_file(out: Path, batch: int) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(out), str(batch)],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    go = Path(str(out) + ".go")
    t0 = time.monotonic()
    while not go.exists() and time.monotonic() - t0 < 60:
        time.sleep(0.02)
    time.sleep(random.uniform(0.05, 0.6))
    proc.send_signal(signal.SIGKILL)
    proc.wait()


def _refused_chunks(out: Path) -> tuple[bool, bool]:
    """(a chunk HDF5 refuses, it is its dataset's last chunk)."""
    import h5py

    torn = last = False
    with h5py.File(out, "r", swmr=True) as h:
        g = h["runs/a"]
        for name in g:
            ds = g[name]
            if not isinstance(ds, h5py.Dataset) or ds.ndim != 1 or not ds.shape[0]:
                continue
            c = ds.chunks[0]
            for k in range(0, ds.shape[0], c):
                try:
                    ds[k : k + c]
                except OSError:
                    torn = True
                    last = last or k + c >= ds.shape[0]
    return torn, last


def main() -> None:
    import h5py

    from pmalab.acquisition.recover import recover
    from pmalab.runfile import read_runs

    n = int(os.environ.get("PMALAB_BENCH_TEARS_N", "100"))
    batch = int(os.environ.get("PMALAB_BENCH_TEARS_BATCH", "10"))
    torn = last = fails = cuts = wrong = 0
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n):
            out = Path(tmp) / f"k{i}.h5"
            _killed_file(out, batch)
            t, lst = _refused_chunks(out)
            torn += t
            last += lst
            with h5py.File(out, "r", swmr=True) as h:
                extent = min(
                    h["runs/a"][c].shape[0]
                    for c in h["runs/a"]
                    if isinstance(h["runs/a"][c], h5py.Dataset) and "units" in h["runs/a"][c].attrs
                )
            try:
                with warnings.catch_warnings(record=True) as w:
                    warnings.simplefilter("always")
                    read_runs(out)
                    recover(out)
                cut = any("lost" in str(x.message) for x in w)
                cuts += cut
                with h5py.File(out, "r") as h:
                    wrong += h["runs/a/time"].shape[0] != extent and not cut
            except Exception:  # any refusal or crash is counted: must be 0
                fails += 1
    print(f"   load {os.getloadavg()[0]:.1f}; {batch} samples a commit")
    print_table(
        ["kills", "torn chunks", "torn = last", "reads fail", "cut+warned", "recovered != extent"],
        [[n, torn, last, fails, cuts, wrong]],
    )


if __name__ == "__main__":
    main()
