"""Data you can trust: the cost of checksummed recording, and damaged files and imports by outcome.

Three tables:

* recording with and without HDF5 Fletcher32 checksums: the recorder's writer appending
  ``PMALAB_BENCH_TRUST_SAMPLES`` (default 300 000, 10 min at 500 Hz) samples in commits of
  125 (a 0.25 s flush at 500 Hz), each commit flushed as a run does — µs per sample and file
  size, median of interleaved repetitions;
* a recorded campaign (two simulated runs) damaged ``PMALAB_BENCH_TRUST_N`` times (default
  100) per kind — truncation, one bit flip, a zeroed 512-byte block, a metadata byte — and
  read: refused in one line, read identical, identical but for a flagged descriptive
  dataset, changed (read silently different: must be 0), traceback (must be 0), hang;
* importer inputs (CSV, TDMS, MAT v5, MAT v7.3) damaged the same ways and imported:
  refused in one line, imported with a warning, imported (equal data), imported with
  changed data and no warning, traceback.
"""

from __future__ import annotations

import os
import random
import statistics
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from bench.table import print_table

TESTS = Path(__file__).resolve().parent.parent / "tests"


def _record_cost(n: int, checksum: bool, d: Path) -> tuple[float, int]:
    from pmalab.acquisition import recorder as rec_mod
    from pmalab.runfile import CHECKSUM

    saved = dict(CHECKSUM)
    if not checksum:
        CHECKSUM.clear()
    try:
        path = d / f"rec-{checksum}-{time.perf_counter_ns()}.h5"
        rec = rec_mod.Recorder(path, [("r", {"muscle_pressure_MPa": 0.4})], {})
        w = rec.writer("r")
        block = 125
        cols = [np.linspace(0, 1, block) for _ in w.channels]
        late = np.zeros(block)
        t0 = time.perf_counter()
        for _ in range(n // block):
            w.extend(cols, late)
            w.commit()
        dt = time.perf_counter() - t0
        w.finish("completed")
        rec.close()
        size = path.stat().st_size
        path.unlink()
        return 1e6 * dt / n, size
    finally:
        CHECKSUM.clear()
        CHECKSUM.update(saved)


def _recording_table(d: Path) -> None:
    n = int(os.environ.get("PMALAB_BENCH_TRUST_SAMPLES", "300000"))
    res: dict[bool, list[tuple[float, int]]] = {True: [], False: []}
    for _ in range(3):
        for ck in (False, True):
            res[ck].append(_record_cost(n, ck, d))
    rows = []
    for ck in (False, True):
        us = statistics.median(r[0] for r in res[ck])
        rows.append(["Fletcher32 on" if ck else "no checksum", n, f"{us:.2f}",
                     f"{1e6 / us / 1e3:.0f}k", f"{res[ck][0][1] / 1e6:.2f}"])
    print_table(["recording", "samples", "µs/sample", "samples/s", "file MB"], rows)
    print("   a real-time run needs 500 samples/s")


def _campaign(d: Path) -> Path:
    from pmalab.cli import main

    proto = d / "p.toml"
    proto.write_text("".join(
        f'[[run]]\nname = "{n}"\nmuscle_pressure_MPa = {p}\nwaveform = "sine"\n'
        'frequency_Hz = 0.5\nmagnitude_MPa = 0.3\ncycles = 3\nramp_s = 0.5\nsettle_s = 0.2\n'
        for n, p in (("a", 0.3), ("b", 0.5))))
    out = d / "campaign.h5"
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["run", "--rig", "sim", "--protocol", str(proto), "--out", str(out),
                     "--quiet"]) == 0
    return out


def _runfile_table(d: Path) -> None:
    sys.path.insert(0, str(TESTS))
    from corrupt_runs import KINDS, corrupt, data_ranges, outcome_guarded

    from pmalab.runfile import read_runs

    n = int(os.environ.get("PMALAB_BENCH_TRUST_N", "100"))
    src = _campaign(d)
    original, data, ranges = read_runs(src), src.read_bytes(), data_ranges(src)
    rng = random.Random(1)
    counts: Counter[tuple[str, str]] = Counter()
    odd: list[str] = []
    for kind in KINDS:
        for k in range(n):
            bad = d / f"bad-{kind}-{k}.h5"
            bad.write_bytes(corrupt(data, kind, rng.random(), rng.randrange(8), ranges))
            out, detail = outcome_guarded(original, bad, timeout_s=60)
            counts[(kind, out)] += 1
            if out in ("changed", "traceback", "hang"):
                odd.append(f"{kind} #{k}: {out}: {detail[:120]}")
            bad.unlink()
    outs = ("refused", "identical", "flagged", "changed", "traceback", "hang")
    rows = [[kind, *(counts[(kind, o)] for o in outs)] for kind in KINDS]
    rows.append(["all", *(sum(counts[(k, o)] for k in KINDS) for o in outs)])
    print_table(["damage (recorded campaign)", *outs], rows)
    for line in odd[:10]:
        print("   " + line)


def _import_table(d: Path) -> None:
    sys.path.insert(0, str(TESTS))
    from corrupt_imports import FORMATS, import_outcomes

    n = int(os.environ.get("PMALAB_BENCH_TRUST_N", "100"))
    counts, odd = import_outcomes(d, n, seed=2)
    outs = ("refused", "warned", "imported", "shorter", "within-noise", "silent-change",
            "traceback", "hang")
    rows = [[fmt, *(counts[(fmt, o)] for o in outs)] for fmt in FORMATS]
    rows.append(["all", *(sum(counts[(f, o)] for f in FORMATS) for o in outs)])
    print_table(["damage (importer input)", *outs], rows)
    for line in odd[:10]:
        print("   " + line)


def _health_table(d: Path) -> None:
    """Channel health on clean data: simulated campaigns over seeds and every simulated rig,
    and the shipped real records — none may trip (the thresholds' calibration)."""
    import contextlib
    import io

    from pmalab.cli import main as cli
    from pmalab.health import _longest_repeat, check_health, noise_level, resolution
    from pmalab.paths import RIGS_DIR
    from pmalab.runfile import read_runs

    seeds = int(os.environ.get("PMALAB_BENCH_TRUST_SEEDS", "20"))
    # single-muscle simulated rigs (a pair's protocol names its muscle)
    rigs = ["sim", *sorted(str(p) for p in RIGS_DIR.glob("sim-*.toml") if "pair" not in p.name)]
    proto = d / "h.toml"
    proto.write_text("".join(
        f'[[run]]\nname = "{n}"\nmuscle_pressure_MPa = {p}\nwaveform = "{w}"\n'
        f'frequency_Hz = {f}\nmagnitude_MPa = 0.3\ncycles = 3\nramp_s = 0.5\nsettle_s = 0.2\n'
        for n, p, w, f in (("a", 0.2, "sine", 0.5), ("b", 0.45, "triangle", 0.3),
                           ("c", 0.6, "sine", 1.0))))
    rows = []
    for rig in rigs:
        runs = trips = 0
        worst_rep = 0
        for s in range(seeds if rig == "sim" else max(1, seeds // 5)):
            out = d / "h.h5"
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                rc = cli(["run", "--rig", rig, "--protocol", str(proto), "--out", str(out),
                          "--force", "--quiet", "--seed", str(s)])
            if rc:
                raise RuntimeError(f"recording on {rig} failed")
            for r in read_runs(out):
                runs += 1
                for c in ("position", "force"):
                    y = r.channels()[c]
                    if resolution(y) > 0 and noise_level(y) >= 3 * resolution(y):
                        worst_rep = max(worst_rep, _longest_repeat(y)[1])
                try:
                    check_health(str(out), r.name, r.channels())
                except Exception:
                    trips += 1
        rows.append([Path(rig).stem, runs, trips, worst_rep])
    sys.path.insert(0, str(TESTS))
    from pmalab.acquisition.csv_import import CsvImportOptions, parse_layout, read_export
    from pmalab.paths import DATA_DIR

    runs = trips = 0
    for f in sorted((DATA_DIR / "real" / "zillen-oring257").glob("*.csv")):
        o = CsvImportOptions(delimiter="\t", no_header=True,
                             layout=parse_layout("time,-,-,-,position,pressure,force"),
                             units={"time": "ms", "muscle_pressure": "bar"},
                             negate=("position",))
        try:
            runs += len(read_export(f, o))
        except Exception:
            trips += 1
    rows.append(["real: zillen-oring257", runs, trips, "-"])
    print_table(["clean data (channel health)", "runs", "tripped (must be 0)",
                 "longest repeat (stuck ≥ 16)"], rows)


def main() -> None:
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        _health_table(d)
        _recording_table(d)
        _runfile_table(d)
        if (TESTS / "corrupt_imports.py").exists():
            _import_table(d)


if __name__ == "__main__":
    main()
