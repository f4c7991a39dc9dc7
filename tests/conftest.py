"""Shared pytest fixtures, and the order the test files are handed to xdist's workers."""

from __future__ import annotations

import os

import matplotlib
import pytest

matplotlib.use("Agg")
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".venv", "numba-cache"))

#: the longest test files, longest first (summed test time per file of a whole-suite run;
#: the docs site's cold build is one test of ~2 min).  ``make test`` runs the suite with
#: ``--dist loadfile --no-loadscope-reorder``: the files are handed to the workers in
#: collection order, so these start first and the short files fill in around them; a
#: long file handed out last would run alone at the end, on one core.  test_reports_laws
#: is not here: it reads the laws test_laws_elements makes (tests/shared_work.py), so it
#: comes later instead of waiting beside it for them; test_real_data reads what the docs
#: build made (the import tutorial) and comes late for the same reason
LONGEST_FIRST = (
    "test_docs_site.py",
    "test_diagnosis_invariant.py",
    "test_wheel.py",
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


@pytest.fixture(autouse=True, scope="session")
def _reports_render_in_process():
    """A report asked for no particular number of page workers renders in the test's own
    process: the suite already runs one worker per core, so a pool of page workers per
    report buys no time here and costs 10-14 % more CPU (interleaved runs of the report
    test files).  The pool is tested where a test asks for it (``jobs=2``: the default
    start method in test_reports_build, spawn and forkserver in test_reports_parallel,
    the control and pair reports)."""
    from pmalab.reports import parallel

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(parallel, "default_jobs", lambda: 1)
        yield


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The files of :data:`LONGEST_FIRST` first, in that order; within a file, and for every
    other file, the collection order (a stable sort: no test's order changes in its file)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda it: rank.get(it.path.name, len(rank)))
