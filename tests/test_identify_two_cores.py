"""`pmalab identify` on two cores: a forked child reads the files while the command imports
the fitting code (pmalab.identify.reading), and a forked child fits half the runs once the
first fit has loaded numba (pmalab.identify.campaign.batch.map_split).  The runs and the
fits arrive bit for bit, the warnings of reading are shown as reading in process shows
them, and a child that fails hands its work back, so the errors are those of one process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from identify_synth import make_run
from user_shell import shell_env

from pmalab.errors import RunFileWarning
from pmalab.identify.reading import read_files, start_reading
from pmalab.runfile import write_runs

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux") or len(os.sched_getaffinity(0)) < 2,
    reason="the reading child is forked on Linux with two cores or more",
)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("reading")
    runs = []
    for i, p in enumerate((0.2, 0.4, 0.6)):
        r, _ = make_run("duhem", p, seed=i, n=3000, f=0.3, name=f"p{i}")
        runs.append(r)
    cut, _ = make_run("duhem", 0.5, seed=5, n=1200, f=0.3, name="cut")
    cut.attrs["status"] = "aborted: force limit"  # skipped with a warning when reading
    ident = write_runs(d / "ident.h5", [*runs, cut])
    v, _ = make_run("duhem", 0.3, seed=7, n=3000, f=0.2, waveform="triangle", name="v1")
    val = write_runs(d / "val.h5", [v])
    return ident, val


def _python(code: str, cwd: Path) -> subprocess.CompletedProcess:
    env = shell_env("PYTHONPATH")
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def test_the_child_reads_the_runs_bit_for_bit_with_the_warnings(campaign, tmp_path):
    ident, val = campaign
    # a fresh interpreter (NumPy not loaded yet, as `pmalab identify` from the shell)
    p = _python(f"""
        import sys, warnings
        from pmalab.identify.reading import read_files, start_reading
        shown = []
        warnings.showwarning = lambda m, c, f, l, file=None, line=None: shown.append(str(m))
        reading = start_reading([{str(ident)!r}], [{str(val)!r}])
        assert reading is not None, "no child forked"
        runs, val = reading.result()
        child = list(shown)
        shown.clear()
        here = read_files([{str(ident)!r}]), read_files([{str(val)!r}])
        assert child == shown and len(shown) == 1, (child, shown)
        assert [len(runs), len(val)] == [3, 1]
        for a, b in zip([*runs, *val], [*here[0], *here[1]]):
            assert (a.name, a.file, a.attrs) == (b.name, b.file, b.attrs)
            for ch in ("time", "position", "force", "muscle_pressure", "cylinder_pressure",
                       "cylinder_pressure_command", "branch"):
                x, y = getattr(a, ch), getattr(b, ch)
                assert (x is None) == (y is None), ch
                if x is not None:
                    assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), (a.name, ch)
                    assert x.flags.c_contiguous == y.flags.c_contiguous
        print("ok", child[0])
    """, tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("ok") and "cut" in p.stdout


def _identify(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = shell_env("PYTHONPATH")
    cli = "import sys; from pmalab.cli import main; sys.exit(main())"
    return subprocess.run([sys.executable, "-c", cli, "identify", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def test_identify_with_the_reading_child_equals_one_process(campaign, tmp_path):
    ident, val = campaign
    args = [str(ident), "--validate", str(val), "--model", "duhem"]
    two = _identify(tmp_path, *args, "--out", "two")
    one = _identify(tmp_path, *args, "--out", "one", "--jobs", "1")
    assert two.returncode == 0 == one.returncode, two.stderr + one.stderr
    docs = [json.loads((tmp_path / d / "identification.json").read_text()) for d in ("two", "one")]
    for d in docs:
        d.pop("created")
    assert docs[0] == docs[1]  # every number, to the last digit
    assert two.stdout.replace("two/", "one/") == one.stdout
    assert two.stderr == one.stderr and "'cut'" in two.stderr  # the skipped run, once


def _diagnose(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    """``pmalab diagnose ARGS`` from a fresh interpreter; its stdout starts with whether the
    command forked a reading child."""
    env = shell_env("PYTHONPATH")
    cli = textwrap.dedent("""
        import sys
        from pmalab.identify import reading
        real = reading.start_reading
        def spy(*a, **k):
            got = real(*a, **k)
            print("child" if got is not None else "no child", flush=True)
            return got
        reading.start_reading = spy
        from pmalab.cli import main
        sys.exit(main())
    """)
    cheap = ("--only", "viscous-friction", "--laws", "none", "--max-steps", "1")
    return subprocess.run([sys.executable, "-c", cli, "diagnose", *args, *cheap], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=300)


def test_diagnose_reads_in_a_child_and_equals_one_process(campaign, tmp_path):
    ident, val = campaign
    args = [str(ident), "--validate", str(val), "--model", "duhem"]
    two = _diagnose(tmp_path, *args, "--out", "two", "--jobs", "2")
    one = _diagnose(tmp_path, *args, "--out", "one", "--jobs", "1")
    assert two.returncode == 0 == one.returncode, two.stderr + one.stderr
    assert two.stdout.startswith("child\n")  # --jobs 2: the files read while importing
    assert "child" not in one.stdout  # --jobs 1: not even asked
    docs = [(tmp_path / d / "diagnosis.json").read_bytes() for d in ("two", "one")]
    assert docs[0] == docs[1]  # every byte
    assert two.stdout.removeprefix("child\n").replace("two/", "one/") == one.stdout
    assert two.stderr == one.stderr and "'cut'" in two.stderr  # the skipped run, once


@pytest.mark.parametrize("verb", ["identify", "diagnose"])
def test_a_file_the_child_cannot_read_is_reported_as_reading_here_reports_it(
    verb, campaign, tmp_path
):
    ident, _ = campaign
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not an HDF5 file" * 100)
    command = _identify if verb == "identify" else _diagnose
    runs = [command(tmp_path, str(ident), str(bad), "--model", "duhem", "--out", f"o{j}",
                    "--jobs", j) for j in ("2", "1")]
    assert runs[0].returncode == runs[1].returncode != 0
    assert runs[0].stderr == runs[1].stderr and "Traceback" not in runs[0].stderr
    # the skipped run's warning, then the one-line error naming the file
    warned, error = runs[0].stderr.strip().splitlines()
    assert "'cut' skipped" in warned and "bad.h5" in error
    assert not (tmp_path / "o2").exists() or not any((tmp_path / "o2").iterdir())


@pytest.mark.parametrize("verb", ["identify", "diagnose"])
def test_a_command_interrupted_while_importing_leaves_no_reading_child(campaign, tmp_path, verb):
    # Ctrl-C while the fitting code imports (the reading child at work): one line, exit
    # 130, and the child gone, reaped (not a zombie left in a user's long-lived process)
    ident, _ = campaign
    env = shell_env("PYTHONPATH")
    code = textwrap.dedent(f"""
        import os, time
        from contextlib import contextmanager
        from pmalab.identify import cli
        @contextmanager
        def interrupted():
            time.sleep(0.2)  # the child is reading
            raise KeyboardInterrupt
            yield
        cli._fitting_code = interrupted
        from pmalab.cli import main
        rc = main([{verb!r}, {str(ident)!r}, "--model", "duhem", "--out", "o", "--jobs", "2"])
        time.sleep(0.5)  # the child has finished, whatever it was doing
        try:
            left = os.waitpid(-1, os.WNOHANG)[0] != 0 or "running"
        except ChildProcessError:
            left = "none"
        print(rc, left, os.path.exists("o"))
    """)
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines()[-1].split() == ["130", "none", "False"], p.stdout
    assert p.stderr.strip() == f"pmalab {verb}: interrupted", p.stderr


def test_no_child_once_numpy_is_loaded(campaign):
    # pytest has NumPy (and BLAS's threads) loaded: reading stays in this process
    ident, val = campaign
    assert "numpy" in sys.modules
    assert start_reading([ident], [val]) is None
    with pytest.warns(RunFileWarning, match="'cut' skipped"):
        assert [r.name for r in read_files([ident])] == ["p0", "p1", "p2"]


def test_map_split_equals_a_loop_and_a_failing_child_hands_its_half_back(tmp_path):
    p = _python("""
        import os
        from pmalab.identify.campaign.batch import fork_is_safe, map_split
        assert fork_is_safe()
        parent = os.getpid()
        pids = map_split(lambda t: (t * t, os.getpid()), range(9))
        assert [v for v, _ in pids] == [t * t for t in range(9)]
        assert {pid for _, pid in pids[:5]} == {parent} and pids[-1][1] != parent
        def picky(t):  # fails in the child only: its half is done here again
            if os.getpid() != parent:
                raise RuntimeError("child")
            return -t
        assert map_split(picky, range(7)) == [-t for t in range(7)]
        def bad(t):
            if t == 2:
                raise ValueError("task 2")
            return t
        try:
            map_split(bad, range(7))
        except ValueError as e:
            print("raised", e)
    """, tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "raised task 2"


def test_map_split_shows_the_childs_warnings_as_one_process_would_and_never_hangs(tmp_path):
    (tmp_path / "noisy.py").write_text(textwrap.dedent("""
        import os
        import warnings

        def warn(t):
            warnings.warn("same" if t % 2 else f"task {t}", UserWarning)
            return t

        def big(t, parent):
            if os.getpid() == parent and t == 2:
                raise ValueError("task 2")
            return bytes(10**6)  # the child's half fills the pipe many times over
    """))
    p = _python("""
        import os, warnings
        from noisy import big, warn
        from pmalab.identify.campaign.batch import map_split
        with warnings.catch_warnings(record=True) as split:
            warnings.simplefilter("default")
            assert map_split(warn, range(9)) == list(range(9))
        with warnings.catch_warnings(record=True) as here:
            warnings.simplefilter("default")
            [warn(t) for t in range(9)]
        print([str(w.message) for w in split] == [str(w.message) for w in here])
        print(sorted({w.filename.endswith("noisy.py") for w in split}))
        parent = os.getpid()
        try:
            map_split(lambda t: big(t, parent), range(9))
        except ValueError as e:
            print(e)
    """, tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split("\n")[:3] == ["True", "[True]", "task 2"]


def test_fits_split_over_two_processes_equal_the_fits_in_one(campaign, tmp_path):
    ident, _ = campaign
    p = _python(f"""
        import warnings
        warnings.simplefilter("ignore")
        from pmalab.identify.api import load
        from pmalab.identify.campaign.fit import fit_runs
        from pmalab.identify.estimation import single
        runs = load({str(ident)!r}) * 4  # 12 fits: the child takes 5
        two = fit_runs(runs, "bouc-wen", jobs=2)
        kept = list(single._BASE_FITS.items())
        single._BASE_FITS.clear()
        one = fit_runs(runs, "bouc-wen", jobs=1)
        import numpy as np
        def same(a, b):  # every number to the last bit (NaN equals NaN)
            if isinstance(a, np.ndarray):
                return a.dtype == b.dtype and a.tobytes() == b.tobytes()
            if isinstance(a, dict):
                return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
            if isinstance(a, (list, tuple)):
                return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
            if hasattr(a, "__dict__"):
                return type(a) is type(b) and same(vars(a), vars(b))
            return a == b or (a != a and b != b)
        for a, b in zip(two, one):
            assert same(a, b), a.label
        # the base fits the child remembered are kept here, in the order one process keeps
        assert [k for k, _ in kept] == list(single._BASE_FITS)
        assert kept == list(single._BASE_FITS.items())
        print("ok", len(two))
    """, tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "ok 12"


def test_the_warm_up_loads_the_filter_a_run_uses_never_another(campaign, tmp_path):
    ident, _ = campaign
    p = _python(f"""
        import warnings
        warnings.simplefilter("ignore")
        from pmalab.identify import zero_phase
        from pmalab.identify.reading import read_files
        from pmalab.identify.signals import Signals
        zero_phase.load_compiled()
        assert len(zero_phase._biquad.signatures) == 1
        for run in read_files([{str(ident)!r}]):
            Signals.from_run(run)
        # the runs' filtering used the warmed-up machine code: no second specialisation
        print(len(zero_phase._biquad.signatures))
    """, tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "1"


def test_collection_paused_while_importing_resumes_as_it_was():
    import gc

    from pmalab.lazy import gc_paused

    # what the session froze already (tests/conftest.py: what collection made)
    frozen = gc.get_freeze_count()
    assert gc.isenabled()
    with gc_paused(freeze=False):
        assert not gc.isenabled()
    assert gc.isenabled() and gc.get_freeze_count() == frozen
    gc.disable()
    try:
        with gc_paused(freeze=True):
            pass
        assert not gc.isenabled() and gc.get_freeze_count() == frozen  # the caller's pause kept
    finally:
        gc.enable()
    try:
        with gc_paused(freeze=True):
            kept = [object() for _ in range(10)]
        assert gc.isenabled() and gc.get_freeze_count() >= frozen + len(kept)
    finally:
        gc.unfreeze()
        if frozen:
            gc.freeze()  # the session's frozen objects frozen again


def test_no_fork_once_a_gnu_openmp_runtime_has_started_threads(tmp_path):
    # libgomp (a BLAS's OpenMP layer, numba's omp layer) keeps its team's threads after a
    # parallel region and has no fork handler: a forked child's next region would wait for
    # threads it does not have.  map_split then runs every task here, the pool's workers
    # start from a fork server; OpenBLAS's pthreads alone (NumPy's wheel) still fork.
    import ctypes.util

    lib = ctypes.util.find_library("gomp")
    if lib is None:
        pytest.skip("no GNU OpenMP runtime (libgomp) on this machine")
    p = _python(f"""
        import ctypes, os
        import numpy
        from pmalab.identify.campaign import batch
        assert batch.fork_is_safe() and batch._mp_context() is None
        gomp, libc = ctypes.CDLL({lib!r}), ctypes.CDLL(None)
        before = len(os.listdir("/proc/self/task"))
        gomp.GOMP_parallel.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint,
                                       ctypes.c_uint]
        gomp.GOMP_parallel(ctypes.cast(libc.getpid, ctypes.c_void_p), None, 2, 0)
        assert len(os.listdir("/proc/self/task")) == before + 1  # the team's thread stays
        assert not batch.fork_is_safe() and batch.gnu_openmp_started()
        parent = os.getpid()
        assert batch.map_split(lambda t: (t * t, os.getpid()), range(9)) == [
            (t * t, parent) for t in range(9)]
        assert batch._mp_context().get_start_method() == "forkserver"
        print("ok")
    """, tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split()[-1:] == ["ok"]


def _blas_after_identify(
    cwd: Path, ident: Path, env_extra: dict[str, str], verb: tuple[str, ...] = ("identify",)
) -> list[str]:
    """Run `pmalab identify` (or ``verb``) in a fresh interpreter (as from the shell); print
    the threads BLAS reports and the threads the process holds once the command has
    returned."""
    env = shell_env("PYTHONPATH", "OPENBLAS_NUM_THREADS")
    code = textwrap.dedent(f"""
        import os
        import sys
        from pmalab.cli import main
        sys.argv = ["pmalab", *{verb!r}, {str(ident)!r}, "--model", "duhem", "--out", "o", "-q"]
        rc = main()  # as the pmalab command calls it
        from threadpoolctl import threadpool_info
        blas = sorted({{i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}})
        print(rc, blas, len(os.listdir("/proc/self/task")))
    """)
    p = subprocess.run([sys.executable, "-c", code], cwd=cwd, env={**env, **env_extra},
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    return p.stdout.splitlines()[-1].split()


def test_identify_loads_blas_with_one_thread_and_starts_no_thread(campaign, tmp_path):
    # OpenBLAS would start a busy-waiting thread per library (NumPy's, SciPy's) on a
    # machine with 2 cores: one thread, and the process holds no other thread
    ident, _ = campaign
    out = _blas_after_identify(tmp_path, ident, {})
    assert out == ["0", "[1]", "1"], out


def test_identify_keeps_the_users_blas_thread_count(campaign, tmp_path):
    ident, _ = campaign
    out = _blas_after_identify(tmp_path, ident, {"OPENBLAS_NUM_THREADS": "2"})
    assert out[:2] == ["0", "[2]"], out


def test_every_verb_loads_blas_with_one_thread(campaign, tmp_path):
    # not the fitting verbs only: `pmalab check` (NumPy loaded by the verb, no fit) from the
    # shell starts BLAS on one thread too (the pmalab command asks before any verb runs);
    # a count the user set is kept
    ident, _ = campaign
    env = shell_env("PYTHONPATH", "OPENBLAS_NUM_THREADS")
    code = textwrap.dedent(f"""
        import sys
        from pmalab.cli import main
        sys.argv = ["pmalab", "check", {str(ident)!r}]
        rc = main()  # as the pmalab command calls it
        from threadpoolctl import threadpool_info
        print(rc, sorted({{i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}}))
    """)
    for extra, blas in (({}, "[1]"), ({"OPENBLAS_NUM_THREADS": "2"}, "[2]")):
        p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env={**env, **extra},
                           capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stderr
        assert p.stdout.splitlines()[-1].split() == ["0", blas], (extra, p.stdout)


def test_main_called_from_python_leaves_the_users_blas_alone(campaign, tmp_path):
    # pmalab.cli.main(argv) called by a user's own program (a notebook, a script) is not the
    # pmalab command: it must not choose the BLAS thread count of the user's process, nor
    # put OPENBLAS_NUM_THREADS into the environment of the processes the user starts later
    ident, _ = campaign
    env = shell_env("PYTHONPATH", "OPENBLAS_NUM_THREADS")
    code = textwrap.dedent(f"""
        import os
        from pmalab.cli import main
        rc = main(["check", {str(ident)!r}])
        print(rc, os.environ.get("OPENBLAS_NUM_THREADS", "unset"))
    """)
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines()[-1].split() == ["0", "unset"], p.stdout


def test_main_called_from_python_freezes_none_of_the_users_objects(campaign, tmp_path):
    # the pmalab command freezes what its first imports made (gc.freeze: never walked
    # again); a user's program calling main([...]) keeps its collector as it was: frozen,
    # its own objects (and its cyclic garbage of that moment) would never be collected
    ident, _ = campaign
    env = shell_env("PYTHONPATH", "OPENBLAS_NUM_THREADS")
    for verb in ("identify", "report"):
        code = textwrap.dedent(f"""
            import gc, sys
            from pmalab.cli import main
            args = ["identify", {str(ident)!r}, "--model", "duhem", "--out", "o", "-q", "--force"]
            if {verb!r} == "report":
                main(args)  # its imports frozen? no: it is called from Python too
                args = ["report", "o", "--out", "r.pdf", "-q", "--force"]
            shell = len(sys.argv) > 1
            if shell:
                sys.argv = ["pmalab", *args]
            rc = main() if shell else main(args)
            print(rc, gc.get_freeze_count() > 0)
        """)
        for shell, frozen in ((False, "False"), (True, "True")):
            argv = [sys.executable, "-c", code, *(["shell"] if shell else [])]
            p = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True,
                               timeout=300)
            assert p.returncode == 0, p.stderr
            assert p.stdout.splitlines()[-1].split() == ["0", frozen], (verb, shell, p.stdout)


def test_diagnose_loads_blas_with_one_thread_and_starts_no_thread(campaign, tmp_path):
    ident, _ = campaign
    verb = ("diagnose", "--only", "viscous-friction", "--laws", "none", "--max-steps", "0")
    out = _blas_after_identify(tmp_path, ident, {}, verb)
    assert out == ["0", "[1]", "1"], out
