"""First hour: wall times a user waits for (report in 1 vs N processes, identify from the shell)

The report is rendered from one demo output (``pmalab demo``; set ``PMALAB_BENCH_DEMO`` to
an existing demo directory to skip recording it), with ``--jobs 1`` (the one-process
renderer) and ``--jobs N`` (N = the CPUs available), interleaved and repeated, so a
loaded machine slows both alike: the ratio is the figure to read, not the seconds.
``identify`` is timed as a user types it (a fresh interpreter per call).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.table import print_table

REPEATS = 3


def _pmalab(*args: str) -> float:
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "import sys; from pmalab.cli import main; sys.exit(main())", *args],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return time.perf_counter() - t0


def main() -> None:
    from pmalab.reports.parallel import default_jobs

    jobs = default_jobs()
    with tempfile.TemporaryDirectory() as tmp:
        demo = Path(os.environ.get("PMALAB_BENCH_DEMO") or Path(tmp) / "demo")
        if not (demo / "report.pdf").exists():
            _pmalab("demo", "--out", str(demo), "--quiet")
        dirs = [str(demo / d) for d in ("identify", "identify-improved", "diagnose")]
        times: dict[str, list[float]] = {"1": [], str(jobs): []}
        for _ in range(REPEATS):
            for j in times:
                out = str(Path(tmp) / f"r{j}.pdf")
                times[j].append(
                    _pmalab("report", *dirs, "--out", out, "--force", "-q", "--jobs", j)
                )
        ident = [
            _pmalab(
                "identify",
                str(demo / "campaign.h5"),
                "--model",
                "bouc-wen",
                "--out",
                str(Path(tmp) / f"id{k}"),
                "--quiet",
            )
            for k in range(REPEATS)
        ]
        start = [_pmalab("--help") for _ in range(REPEATS)]
    t1, tn = statistics.median(times["1"]), statistics.median(times[str(jobs)])
    print_table(
        ["what (median of 3, s)", "before", "after", "after/before"],
        [
            [f"report, demo output: --jobs 1 -> --jobs {jobs}", t1, tn, tn / t1],
            ["identify campaign.h5 (shell, fresh interpreter)", "", statistics.median(ident), ""],
            ["pmalab --help (start-up only)", "", statistics.median(start), ""],
        ],
    )
    print(f"   load average now: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
