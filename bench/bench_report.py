"""Report: `pmalab report` of a demo output, this tree against an earlier commit (wall and CPU)

The report a user waits for at the end of ``pmalab demo`` (identify + identify --add +
diagnose, 23 pages) and in the campaign tutorial (the same with ``--png``; the docs build
and the suite run it with one page worker), rendered by this tree and by the sources of an
earlier commit (``PMALAB_BENCH_BEFORE``, default 75093c8: before the page drawing work of
2026-11-26's second session; empty: this tree only), each from the shell
(a fresh interpreter), interleaved run by run so a loaded machine slows both alike.  Wall
time is the median of ``REPEATS`` runs; CPU time is user + sys of the command and its page
workers (median).  ``PMALAB_BENCH_DEMO`` names an existing demo directory (else one is
recorded).  The PDFs of both trees must have the same number of pages.
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.bench_first_hour import _source
from bench.table import print_table

REPEATS = 3
BEFORE_DEFAULT = "75093c8"


def _run(src: Path | None, *args: str, cwd: Path) -> tuple[float, float]:
    """Wall and CPU (user + sys, children included) of ``pmalab ARGS`` from ``src``, run in
    ``cwd`` (not a source tree: ``python -c`` puts the working directory first on the path)."""
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "import sys; from pmalab.cli import main; sys.exit(main())", *args],
        check=True,
        stdout=subprocess.DEVNULL,
        env=env,
        cwd=cwd,
    )
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def _pages(pdf: Path) -> int:
    data = pdf.read_bytes()
    return data.count(b"/Type /Page\n") + data.count(b"/Type /Page ")


def main() -> None:
    before = os.environ.get("PMALAB_BENCH_BEFORE", BEFORE_DEFAULT).strip()
    rows: list[list[object]] = []
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        demo = Path(os.environ.get("PMALAB_BENCH_DEMO") or tmp / "demo")
        if not (demo / "report.pdf").exists():
            _run(None, "demo", "--out", str(demo), "--quiet", cwd=tmp)
        dirs = [str(demo / d) for d in ("identify", "identify-improved", "diagnose")]
        trees: dict[str, Path | None] = {"after": Path(__file__).resolve().parents[1]}
        if before:
            trees["before"] = _source(before, tmp / "src-before")
        cases = {
            "report, demo output (PDF; the demo's call)": [],
            "report, demo output --png (the tutorial's call)": ["--png"],
            "report, demo output --jobs 1 (one process)": ["--jobs", "1"],
            "report, demo output --png --jobs 1 (the docs build's call)": ["--png", "--jobs", "1"],
        }
        pages: dict[str, int] = {}
        for what, extra in cases.items():
            wall: dict[str, list[float]] = {k: [] for k in trees}
            cpu: dict[str, list[float]] = {k: [] for k in trees}
            for k in range(REPEATS):
                for name, src in trees.items():
                    out = tmp / f"{name}.pdf"
                    opts = [*extra]
                    if opts[:1] == ["--png"]:
                        opts = ["--png", str(tmp / f"png-{name}-{k}-{len(extra)}"), *opts[1:]]
                    w, c = _run(
                        src, "report", *dirs, "--out", str(out), "--force", "-q", *opts, cwd=tmp
                    )
                    wall[name].append(w)
                    cpu[name].append(c)
                    pages[name] = _pages(out)
            a_w, a_c = statistics.median(wall["after"]), statistics.median(cpu["after"])
            if "before" in trees:
                b_w, b_c = statistics.median(wall["before"]), statistics.median(cpu["before"])
                rows.append([f"{what}: wall", b_w, a_w, a_w / b_w])
                rows.append([f"{what}: CPU", b_c, a_c, a_c / b_c])
            else:
                rows += [[f"{what}: wall", "", a_w, ""], [f"{what}: CPU", "", a_c, ""]]
        if "before" in trees:
            same = "yes" if pages["before"] == pages["after"] else "NO"
            rows.append([f"same page count ({pages['after']})", "", same, ""])
    print_table(["what (s)", "before", "after", "after/before"], rows)
    print(f"   load average now: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
