"""The wheel is the product: built here, installed into a fresh virtual environment outside
the repository, it runs ``pmalab --version``, ``pmalab demo`` to the end (the shipped
protocols, rig files, truth files and controllers' identifications come from the wheel;
the suite's one run of the demo, so its checks of what the demo finds are here) and one
``identify``; the Bouc-Wen benchmark identified on position to its published goal (also
the suite's one run of it); one ``control`` run on the shipped identification and a truth by path.

The fresh environment gets pmalab only from the wheel (``pip install --no-deps``); its
third-party dependencies are the project environment's, made visible with a ``.pth`` line
(a path entry: the editable install's finder in that folder is NOT run), so the test needs
no network.  The test checks that ``pmalab`` is imported from the fresh environment.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest
from user_shell import shell_env

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def _run(cmd: list[str], cwd: Path, env: dict | None = None, timeout: int = 600) -> str:
    p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, f"{' '.join(map(str, cmd))}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    return p.stdout + p.stderr


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    # a copy of the tracked tree: the build must not write egg-info into the checkout
    src = tmp_path_factory.mktemp("src") / "pmalab-src"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                           check=True).stdout.decode().split("\0")
    for f in filter(None, files):
        s = ROOT / f
        d = src / f
        d.parent.mkdir(parents=True, exist_ok=True)
        if s.is_symlink():
            os.symlink(os.readlink(s), d)
        elif s.is_file():
            shutil.copy2(s, d)
    # both products, the wheel built from the sdist (so the sdist must hold the data too)
    _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out)], cwd=src)
    (whl,) = out.glob("pmalab-*-py3-none-any.whl")
    return whl


@pytest.fixture(scope="module")
def sdist(wheel) -> Path:
    (sd,) = wheel.parent.glob("pmalab-*.tar.gz")
    return sd


def _source_version() -> str:
    """The one literal version in pmalab/__init__.py (pyproject.toml declares it dynamic)."""
    init = (ROOT / "pmalab" / "__init__.py").read_text()
    (v,) = re.findall(r'^__version__[^=\n]*=\s*"([^"]*)"', init, flags=re.M)
    return v


def test_the_version_has_one_source(wheel):
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    # pyproject holds no version of its own: the build reads pmalab.__version__
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "pmalab.__version__"}
    assert wheel.name == f"pmalab-{_source_version()}-py3-none-any.whl"


def test_sdist_holds_the_data_and_what_tests_need(sdist):
    with tarfile.open(sdist) as tf:
        names = {n.split("/", 1)[1] for n in tf.getnames() if "/" in n}
        links = [m.name for m in tf.getmembers() if m.issym() or m.islnk()]
    for must in ("pmalab/data/truth/subtle/clean.toml", "pmalab/data/rigs/labjack-t7.toml",
                 "pmalab/data/control/seed-experiments.toml",
                 "pmalab/acquisition/live/assets/index.html", "tests/test_wheel.py",
                 "tests/fake_nidaqmx/nidaqmx/__init__.py", "CHANGELOG.md", "CONTRIBUTING.md",
                 "pyproject.toml", "LICENSE"):
        assert must in names, must
    assert not links and "data" not in names  # the clone's data/ link is not shipped twice


def test_wheel_holds_the_run_time_data(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for must in ("pmalab/data/protocols/seed-bouc-wen.toml", "pmalab/data/rigs/sim.toml",
                 "pmalab/data/truth/hidden-asymmetric-hysteresis.toml",
                 "pmalab/data/control/identification-bouc-wen.json",
                 "pmalab/data/real/zillen-oring257/LICENSE",
                 "pmalab/acquisition/live/assets/index.html"):
        assert must in names, must
    assert not any(n.startswith(("data/", "tests/")) for n in names)


def _check_the_demo(pmalab: str, work: Path, env: dict) -> None:
    """``pmalab demo``, the whole chain on the simulated rig, end to end (the one run of it
    in the suite: the installed wheel's): it finds the hidden effect at once, the error falls
    by more than half, the report is written, the hidden effect's name does not leak into
    the files a user sees, and a second run without --force is refused."""
    import json

    from pmalab.identify.headline import error_fall

    out = work / "demo"
    text = _run([pmalab, "demo", "--out", "demo"], cwd=work, env=env)
    assert "diagnosis: found it\n" in text, text  # at once: no experiment round needed
    diag = json.loads((out / "diagnose" / "diagnosis.json").read_text())
    assert diag["ranking"][0]["effect"] == "asymmetric-hysteresis"
    assert diag["ranking"][0]["significant"] is True
    ladder = [s["nrmse"] for s in diag["ladder"]]
    assert ladder[-1] < 0.5 * ladder[0]  # the error falls by more than half
    # one error-fall figure: the summary prints the sentence the report's pages draw
    fall = error_fall(*(json.loads((out / d / "identification.json").read_text())
                        for d in ("identify", "identify-improved")))
    assert fall.sentence() in text and fall.fall_percent > 50.0
    pdf = out / "report.pdf"
    assert pdf.stat().st_size > 50_000 and pdf.read_bytes()[:5] == b"%PDF-"
    assert "asymmetric" not in (out / "rig" / "rig.toml").read_text()
    again = subprocess.run([pmalab, "demo", "--out", "demo"], cwd=work, env=env,
                           capture_output=True, text=True, timeout=600)
    assert again.returncode != 0 and "Traceback" not in again.stderr  # never without --force


def _check_the_benchmark_identification(pmalab: str, work: Path, env: dict) -> None:
    """The Bouc-Wen benchmark written, identified on position (output error) and simulated,
    from the wheel (the suite's one run of it): the published goal met on both test records
    with the benchmark's own parameters, ``pmalab simulate`` reproducing identify's
    simulated position exactly, and the report drawing what the model was fitted on."""
    import json

    import h5py
    import numpy as np

    from pmalab.reports.build import plan_pages
    from pmalab.reports.data import load_report_dir
    from pmalab.rig.sim import bouc_wen_benchmark as bwb

    _run([pmalab, "benchmark", "bouc-wen", "--out", "bw"], cwd=work, env=env)
    text = _run([pmalab, "identify", "bw/train.h5", "--output", "position", "--model",
                 "bouc-wen", "--add", "inertia", "--add", "viscous-friction", "--validate",
                 "bw/test-multisine.h5", "bw/test-sweep.h5", "--out", "bwid"], cwd=work, env=env)
    assert "position rmse" in text, text
    out = work / "bwid"
    doc = json.loads((out / "identification.json").read_text())
    assert doc["output"] == "position"
    rows = {v["run"]: v for v in doc["validation"]}
    # the goal: <= 1.0e-5 m on the multisine test (published: PNLSS 1.2e-5 m)
    assert rows["multisine-test"]["rmse_position_m"] <= 1.0e-5
    assert rows["sweep-test"]["rmse_position_m"] <= 1.0e-5
    # <= 10 parameters: k, c0, A, beta, gamma, inertia_m, visc_c (n held at 1)
    fitted = [n for n in doc["parameter_names"] if n not in doc["runs"][0]["fixed"] and n != "h0"]
    assert len(fitted) <= 10
    # and they are the benchmark's own (noise 8e-6 m rms on the training output)
    q = {n: v[0] for n, v in doc["pressure_fits"].items()}
    for name, tol in (("k", 0.03), ("A", 0.03), ("beta", 0.03), ("gamma", 0.03),
                      ("inertia_m", 0.03), ("visc_c", 0.1)):
        truth = bwb.AS_PMALAB[name]
        assert abs(q[name] - truth) <= tol * abs(truth), (name, q[name], truth)
    # pmalab simulate, force in: the same integrator reproduces identify's position_model
    _run([pmalab, "simulate", "bwid", "bw/test-multisine.h5", "--out", "sim.h5"], cwd=work,
         env=env)
    with h5py.File(work / "sim.h5") as f, h5py.File(out / "predictions.h5") as g:
        xs = f["runs/multisine-test/position"][:]
        key = next(k for k in g["runs"] if g["runs"][k].attrs["run"] == "multisine-test")
        xm = g["runs"][key]["position_model"][:]
        assert g["runs"][key]["position_model"].attrs["units"] == "mm"
    np.testing.assert_array_equal(xs, xm)
    # the report draws what the model was fitted on: the simulated position
    titles = [p.title for p in plan_pages(load_report_dir(out))]
    assert any(t.startswith("Validation: simulated position") for t in titles), titles
    _run([pmalab, "report", "bwid", "--out", "bw.pdf"], cwd=work, env=env)
    assert (work / "bw.pdf").stat().st_size > 10_000


@pytest.mark.timeout(1800)  # the demo from a cold numba cache, on a loaded machine
def test_installed_wheel_runs_the_demo_outside_the_repository(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=tmp_path).strip())
    # the project's third-party packages, as a plain path entry
    (site / "zz-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    # the fresh environment's own interpreter installs it (pip itself comes via the .pth), so
    # the console script runs that interpreter
    # (--ignore-installed: pip must not touch the project environment's pmalab it can see)
    _run([str(py), "-m", "pip", "install", "--no-deps", "--ignore-installed", "--quiet",
          str(wheel)], cwd=tmp_path)
    work = tmp_path / "lab"
    work.mkdir()
    env = shell_env("PYTHONPATH", "VIRTUAL_ENV")  # a user's shell: the default workers too
    env["PATH"] = f"{env_dir / 'bin'}{os.pathsep}{env['PATH']}"
    where = _run([str(py), "-c", "import pmalab; print(pmalab.__file__)"], cwd=work, env=env)
    assert str(env_dir) in where and str(ROOT) not in where, where
    # the live page and the shipped files by name, read from the installed package
    probe = ("from pmalab.acquisition.live.server import ASSETS, asset\n"
             "from pmalab.paths import DATA_DIR, TRUTH_DIR, shipped\n"
             "from pmalab.rig.sim.truth import load_truth\n"
             "assert all(asset(n) for n in [*ASSETS, 'index.html'])\n"
             "assert load_truth('data/truth/subtle/clean.toml').values\n"
             "print(DATA_DIR, shipped('subtle/clean', TRUTH_DIR))")
    where = _run([str(py), "-c", probe], cwd=work, env=env)
    assert where.count(str(env_dir)) == 2 and str(ROOT) not in where, where
    pmalab = str(env_dir / "bin" / "pmalab")
    assert _run([pmalab, "--version"], cwd=work, env=env).strip() == f"pmalab {_source_version()}"
    _check_the_demo(pmalab, work, env)
    # a shipped protocol by name and a clone-style rig path, then one identify
    _run([pmalab, "run", "--rig", "data/rigs/sim.toml", "--protocol", "quick", "--out",
          "q.h5", "--quiet"], cwd=work, env=env)
    out = _run([pmalab, "identify", "q.h5", "--model", "bouc-wen", "--out", "ident", "--quiet"],
               cwd=work, env=env)
    assert (work / "ident" / "identification.json").exists(), out
    # the controllers' shipped identification and a truth, both by their clone paths
    out = _run([pmalab, "control", "--controller", "pid", "--reference", "sine:0.1Hz:15mm",
                "--truth", "data/truth/hidden-viscous-friction.toml", "--model",
                "data/control/identification-duhem.json", "--duration", "2", "--out", "c.h5"],
               cwd=work, env=env)
    assert (work / "c.h5").is_file() and "completed" in out, out
    # the model as a plant: the benchmark written, identified on position, simulated, and
    # the shipped identification as the manipulator's muscle (model in the loop)
    _check_the_benchmark_identification(pmalab, work, env)
    out = _run([pmalab, "control", "--controller", "sn-pid", "--reference", "sine:0.2Hz:20mm",
                "--plant", "data/control/identification-bouc-wen.json", "--duration", "2",
                "--out", "plant.h5"], cwd=work, env=env)
    assert "completed" in out, out


def _read_only(site: Path, argv: list[str]) -> list[str]:
    """``argv`` run with the installed ``pmalab`` package read-only (as a system-wide or
    managed install is): a non-root user loses the write bits; root, who ignores them,
    gets a read-only bind mount in a private mount namespace (``unshare``), if allowed."""
    pkg = site / "pmalab"
    if os.geteuid() != 0:
        return argv  # the caller removed the write bits
    if shutil.which("unshare") is None:
        pytest.skip("root without unshare: cannot make the installed package read-only")
    probe = subprocess.run(["unshare", "-m", "sh", "-c",
                            f"mount --bind -o ro '{pkg}' '{pkg}' && ! touch '{pkg}/.w'"],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip("no private mount namespace here: cannot make the package read-only")
    script = f"mount --bind -o ro '{pkg}' '{pkg}' && exec \"$0\" \"$@\""
    return ["unshare", "-m", "sh", "-c", script, *argv]


def test_numba_cache_of_a_read_only_install_is_warm_on_the_second_run(wheel, tmp_path):
    """Installed where the user cannot write (site-packages read-only), the compiled laws
    are cached in the user's cache directory: the second ``identify`` compiles nothing."""
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=tmp_path).strip())
    (site / "zz-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([str(py), "-m", "pip", "install", "--no-deps", "--ignore-installed", "--quiet",
          str(wheel)], cwd=tmp_path)
    work = tmp_path / "lab"
    work.mkdir()
    home = tmp_path / "home"
    env = shell_env("PYTHONPATH", "VIRTUAL_ENV", "NUMBA_CACHE_DIR", "XDG_CACHE_HOME")
    env["HOME"] = str(home)
    pmalab = str(env_dir / "bin" / "pmalab")
    env["NUMBA_DEBUG_CACHE"] = "1"  # numba says what it saved and what it loaded
    if os.geteuid() != 0:
        subprocess.run(["chmod", "-R", "a-w", str(site / "pmalab")], check=True)
    try:
        _run(_read_only(site, [pmalab, "run", "--rig", "sim", "--protocol", "quick", "--out",
                               "q.h5", "--quiet"]), cwd=work, env=env)
        logs = [
            _run(_read_only(site, [pmalab, "identify", "q.h5", "--model", "bouc-wen", "--out",
                                   f"id{k}", "--quiet"]), cwd=work, env=env)
            for k in (1, 2)
        ]
    finally:
        subprocess.run(["chmod", "-R", "u+w", str(site / "pmalab")], check=True)
    user_cache = home / ".cache" / "numba"
    assert "saved" in logs[0] and user_cache.is_dir(), logs[0][-2000:]
    assert any(user_cache.rglob("*.nbi")) and not any((site / "pmalab").rglob("*.nbi"))
    assert "data loaded" in logs[1] and "saved" not in logs[1], logs[1][-2000:]
    assert (work / "id2" / "identification.json").is_file()
