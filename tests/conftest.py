"""Shared pytest fixtures, and the order the test files are handed to xdist's workers."""

from __future__ import annotations

import os

import matplotlib
import pytest
from threadpoolctl import threadpool_limits

from pmalab.lazy import gc_paused

matplotlib.use("Agg")
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".venv", "numba-cache"))
# every command and report the suite runs (in process, and the docs build's commands in
# subprocesses) works in its own process unless a test asks for workers (``jobs=2``,
# ``--jobs 2``): xdist already runs one pytest worker per core, so a pool of fitting or
# page workers per test buys no time here and costs 10-25 % more CPU (interleaved runs of
# the diagnosis and report test files).  Results are the same under any number of
# workers (test_identify_campaign, test_reports_parallel, test_start_methods); tests of
# what a user's shell gets (the wheel, the reading child, the active loop over the wire)
# remove the variable from their subprocesses' environment (``user_shell.shell_env``)
os.environ.setdefault("PMALAB_JOBS", "1")
# for the same reason one BLAS thread, here and in the commands the tests start: a second
# OpenBLAS thread buys nothing beside a busy second worker, and after each call it spins
# for its next work on the core the other worker needs (``pmalab identify`` and
# ``diagnose`` ask for one thread themselves; every fit runs on one already).  NumPy is
# loaded already in this process, so its pool is limited here (threadpoolctl); commands
# started with the suite's environment read the variable.  Tests of what a user's shell
# gets do not have it (``user_shell.SUITE_ONLY``)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
threadpool_limits(limits=1, user_api="blas")

#: the order the test files are handed out in (the rest follow in collection order).
#: ``make test`` runs the suite with ``--dist loadfile --no-loadscope-reorder``: the files
#: go to the workers in this order, the first to the first worker, the second to the
#: second, and whichever worker frees up takes the next.  The long files come early, so
#: the short ones fill in around them: a long file handed out last would run alone at the
#: end, on one core.  Three rules shape it:
#:
#: * **The docs build first** (the first worker): one test of ~2 min that makes its
#:   tutorial units several processes at once, at a lower priority on an otherwise idle
#:   machine (nice 10: test_docs_site's ``_lower_priority``).  xdist hands that worker a
#:   second file at once (the docs file holds two tests), which it runs only after the
#:   build: a short one (test_acq_fakes), so that no long file waits behind a build that
#:   takes longer than planned (at load 15: 18 minutes, then test_diagnosis_invariant
#:   alone on one core for 3.5 more while the other worker had finished).
#: * **The wheel second**: the second worker starts with it.  Its commands run the
#:   installed wheel's code, whose compiled laws are cached apart from the checkout's
#:   (numba keys its cache by source file), while the docs build's first commands compile
#:   the checkout's laws and the simulator into the empty shared cache (NUMBA_CACHE_DIR);
#:   any other file there would compile the same at the same moment, each process its own
#:   copy (~6 CPU-s of a cold run).
#: * **Then the files that mostly wait** (:data:`WAITING`: real-time recordings against
#:   emulated devices), on the second worker while the docs build still runs: they leave
#:   most of their core idle, and the build, at nice 10, takes it and gives it back the
#:   moment a recording or an emulator wakes.  Beside a one-process file they idled ~40
#:   core-s of the run; by then the simulator is in the cache (no recording waits for a
#:   compile).  test_diagnosis_invariant follows them, by then with the laws the docs
#:   build's first commands compiled in the cache.
#:
#: test_reports_laws is not listed: it reads the laws test_laws_elements makes
#: (tests/shared_work.py), so it comes later instead of waiting beside it for them;
#: test_real_data reads what the docs build made (the import tutorial) and comes late for
#: the same reason.
WAITING = (
    "test_rig_t7_stream.py",
    "test_emulate_faults.py",
    "test_emulate_reduced.py",
    "test_emulate_run.py",
    "test_rig_nidaqmx.py",
    "test_live.py",
    # measured idle (the suite's processes sampled: no runnable one in the worker) 2-4 s
    # each: kill tests and dead links waiting out their real-time seconds, pools whose
    # tasks sleep, the browser and the emulator on a port
    "test_acq_crash.py",
    "test_vent_dead_link.py",
    "test_pool_sharing.py",
    "test_emulate_port.py",
    "test_live_browser.py",
    "test_drivers_independent.py",
)
LONGEST_FIRST = (
    "test_docs_site.py",
    "test_wheel.py",
    "test_acq_fakes.py",
    *WAITING,
    "test_diagnosis_invariant.py",
    "test_first_hour.py",
    "test_active.py",
    "test_static_identify.py",
    "test_reports_parallel.py",
    "test_laws_elements.py",
    "test_diagnose_dask.py",
    "test_reports_build.py",
    "test_identify_two_cores.py",
    "test_active_emulated.py",
    "test_identify_joint.py",
    "test_pair.py",
)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The files of :data:`LONGEST_FIRST` first, in that order; within a file, and for every
    other file, the collection order (a stable sort: no test's order changes in its file)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda it: rank.get(it.path.name, len(rank)))


@pytest.hookimpl(wrapper=True)
def pytest_collection(session: pytest.Session):
    """Collection with the cyclic garbage collector paused, and what it made frozen.

    Collecting imports every test module and with them NumPy, SciPy, numba, matplotlib and
    all of pmalab: hundreds of thousands of long-lived objects, which the collector would
    walk again and again while they pile up (about a third of collection's CPU in a
    worker), and at every full collection of the tests after.  Frozen
    (:func:`gc.freeze`, as ``pmalab identify`` does with its imports) no later collection
    walks them; the tests' own garbage is collected as before."""
    with gc_paused(freeze=True):
        return (yield)
