"""First hour: wall times a user waits for (identify from an installed wheel, report in 1 vs N processes)

``identify`` is timed as a wheel user meets it: the wheel is built from this tree and
installed into a fresh virtual environment outside the repository, the 14 + 4 run
``laws-pressure`` campaign is recorded, and ``pmalab identify c.h5 --model bouc-wen`` is run
from the shell (a fresh interpreter per call) once to warm numba's cache, then timed.
The same is done with a wheel of an earlier commit (``PMALAB_BENCH_BEFORE``, default: the
last commit before the start-up work; empty: skip), interleaved run by run, so a loaded
machine slows both alike: the ratio is the figure to read.  Both must write the same
identification (every number of identification.json but its time stamp).

The report is rendered from one demo output (``pmalab demo``; set ``PMALAB_BENCH_DEMO`` to
an existing demo directory to skip recording it), with ``--jobs 1`` (the one-process
renderer) and ``--jobs N`` (N = the CPUs available), interleaved and repeated.
``PMALAB_BENCH_SKIP_REPORT=1`` times identify only.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import time
import venv
from pathlib import Path

from bench.table import print_table

REPEATS = 3
#: identify runs per wheel (after one warm-up run each)
IDENTIFY_REPEATS = 5
ROOT = Path(__file__).resolve().parents[1]
#: the commit before identify's start-up work (one BLAS thread for the covariance, lazy
#: process-pool imports); compared with this tree's wheel
BEFORE_DEFAULT = "2d891d3"


def _pmalab(*args: str) -> float:
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "import sys; from pmalab.cli import main; sys.exit(main())", *args],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return time.perf_counter() - t0


def _quiet(cmd: list[str], cwd: Path, env: dict[str, str] | None = None) -> None:
    p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(f"{' '.join(cmd)}:\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")


def _source(ref: str | None, dest: Path) -> Path:
    """This tree's tracked files (``ref`` None) or commit ``ref``, copied to ``dest``."""
    dest.mkdir(parents=True)
    if ref:
        archive = subprocess.run(
            ["git", "archive", ref], cwd=ROOT, capture_output=True, check=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
        return dest
    files = (
        subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True)
        .stdout.decode()
        .split("\0")
    )
    for f in filter(None, files):
        s, d = ROOT / f, dest / f
        d.parent.mkdir(parents=True, exist_ok=True)
        if s.is_symlink():
            os.symlink(os.readlink(s), d)
        elif s.is_file():
            shutil.copy2(s, d)
    return dest


def _installed(ref: str | None, tmp: Path, name: str) -> Path:
    """The ``pmalab`` console script of a fresh environment holding the wheel of ``ref``.

    pmalab comes only from the wheel (``--no-deps``); its third-party packages are this
    environment's, as a plain path entry (no network), as in ``tests/test_wheel.py``.
    """
    src = _source(ref, tmp / f"src-{name}")
    dist = tmp / f"dist-{name}"
    _quiet(
        [sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(dist)], cwd=src
    )
    (whl,) = dist.glob("pmalab-*.whl")
    env_dir = tmp / f"venv-{name}"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = subprocess.run(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    (Path(site) / "zz-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _quiet(
        [str(py), "-m", "pip", "install", "--no-deps", "--ignore-installed", "--quiet", str(whl)],
        cwd=tmp,
    )
    return env_dir / "bin" / "pmalab"


def _identify_numbers(out: Path) -> dict:
    d = json.loads((out / "identification.json").read_text())
    d.pop("created", None)
    return d


def identify_from_wheel(tmp: Path) -> list[list[object]]:
    """Rows: identify of the 14 + 4 campaign from the installed wheel, before and after."""
    before = os.environ.get("PMALAB_BENCH_BEFORE", BEFORE_DEFAULT).strip()
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONPATH", "VIRTUAL_ENV", "NUMBA_CACHE_DIR")
    }
    wheels = {"after": _installed(None, tmp, "after")}
    if before:
        wheels["before"] = _installed(before, tmp, "before")
    lab = tmp / "lab"
    lab.mkdir()
    _quiet(
        [
            str(wheels["after"]),
            "run",
            "--rig",
            str(ROOT / "data" / "rigs" / "sim.toml"),
            "--protocol",
            "laws-pressure",
            "--out",
            "c.h5",
            "-q",
        ],
        cwd=lab,
        env=env,
    )
    times: dict[str, list[float]] = {k: [] for k in wheels}
    for k in range(IDENTIFY_REPEATS + 1):  # run 0 warms numba's cache: not timed
        for name, exe in wheels.items():
            out = f"o-{name}-{k}"
            t0 = time.perf_counter()
            _quiet(
                [str(exe), "identify", "c.h5", "--model", "bouc-wen", "--out", out, "-q"],
                cwd=lab,
                env=env,
            )
            if k:
                times[name].append(time.perf_counter() - t0)
    after = statistics.median(times["after"])
    what = f"identify laws-pressure campaign (wheel, shell, 2nd+ run, median of {IDENTIFY_REPEATS})"
    if "before" not in times:
        return [[what, "", after, ""]]
    same = _identify_numbers(lab / "o-before-1") == _identify_numbers(lab / "o-after-1")
    b = statistics.median(times["before"])
    return [
        [what, b, after, after / b],
        ["identification.json identical (but its time stamp)", "", "yes" if same else "NO", ""],
    ]


def main() -> None:
    from pmalab.reports.parallel import default_jobs

    jobs = default_jobs()
    rows: list[list[object]] = []
    with tempfile.TemporaryDirectory() as tmp:
        rows += identify_from_wheel(Path(tmp))
        if os.environ.get("PMALAB_BENCH_SKIP_REPORT", "") != "1":
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
            t1, tn = statistics.median(times["1"]), statistics.median(times[str(jobs)])
            rows.append([f"report, demo output: --jobs 1 -> --jobs {jobs}", t1, tn, tn / t1])
        start = [_pmalab("--help") for _ in range(REPEATS)]
    rows.append(["pmalab --help (start-up only)", "", statistics.median(start), ""])
    print_table(["what (s)", "before", "after", "after/before"], rows)
    print(f"   load average now: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
