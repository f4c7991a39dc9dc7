"""``$PMALAB_JOBS``: the default of every command's ``--jobs`` (identify, diagnose, the active
loop, report pages).  Unset, identify and diagnose start 2 workers and a report one per
CPU; ``--jobs`` given always wins; a value that is not a whole number ≥ 1 is one line
naming the variable, before any output is written."""

from __future__ import annotations

import contextlib
import io
import os

import pytest
from identify_synth import make_run

from pmalab.arguments import JOBS_ENV, default_jobs
from pmalab.cli import main as pmalab_main
from pmalab.errors import PmalabError
from pmalab.identify.cli import DEFAULT_JOBS, resolve_jobs
from pmalab.runfile import write_runs


def test_the_variable_sets_the_default_and_the_option_wins(monkeypatch):
    monkeypatch.delenv(JOBS_ENV, raising=False)
    assert default_jobs(7) == 7 and resolve_jobs(None) == DEFAULT_JOBS == 2
    monkeypatch.setenv(JOBS_ENV, " 3 ")
    assert default_jobs(7) == 3 and resolve_jobs(None) == 3
    assert resolve_jobs(1) == 1 and resolve_jobs(4) == 4  # --jobs given
    monkeypatch.setenv(JOBS_ENV, "")
    assert resolve_jobs(None) == 2  # set but empty: as unset
    with pytest.raises(PmalabError, match="--jobs 0: must be at least 1"):
        resolve_jobs(0)


def test_the_report_pages_default_is_the_variable_else_the_cpus(monkeypatch):
    from pmalab.reports.parallel import default_jobs as report_jobs

    monkeypatch.delenv(JOBS_ENV, raising=False)
    assert report_jobs() == len(os.sched_getaffinity(0))
    monkeypatch.setenv(JOBS_ENV, "1")
    assert report_jobs() == 1


@pytest.mark.parametrize("value", ["0", "two", "-1", "1.5"])
def test_a_bad_value_is_one_line_naming_the_variable_and_nothing_is_written(
    monkeypatch, tmp_path, value
):
    camp = write_runs(tmp_path / "c.h5", [make_run("bouc-wen", 0.4, n=2000)[0]])
    monkeypatch.setenv(JOBS_ENV, value)
    for verb in (["identify", str(camp), "--model", "bouc-wen"],
                 ["diagnose", str(camp), "--model", "bouc-wen"]):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = pmalab_main([*verb, "--out", str(tmp_path / "o")])
        assert code != 0 and err.getvalue().count("\n") == 1, err.getvalue()
        assert f"PMALAB_JOBS={value}: give a whole number >= 1" in err.getvalue()
        assert "Traceback" not in err.getvalue() and not (tmp_path / "o").exists()


def test_the_library_identify_follows_the_variable_and_an_explicit_jobs_wins(monkeypatch):
    """``pmalab.identify.api.identify`` without ``jobs`` starts the workers the command line
    would: ``$PMALAB_JOBS`` when set, else 2 (a notebook inside a parallel test suite, or on
    a shared machine, no longer forks a pool the user's setting says not to)."""
    import pmalab.identify.api as api

    seen: list[int] = []

    def fit_and_validate(*args, jobs, **kwargs):
        seen.append(jobs)
        raise RuntimeError("stop here: only the worker count is under test")

    monkeypatch.setattr(api, "fit_and_validate", fit_and_validate)
    run = make_run("bouc-wen", 0.4, n=2000)[0]
    for env, given, want in ((None, None, 2), ("3", None, 3), ("3", 1, 1), ("1", None, 1)):
        if env is None:
            monkeypatch.delenv(JOBS_ENV, raising=False)
        else:
            monkeypatch.setenv(JOBS_ENV, env)
        with pytest.raises(RuntimeError, match="stop here"):
            api.identify(run, "bouc-wen", jobs=given)
        assert seen[-1] == want, (env, given, seen)
    monkeypatch.setenv(JOBS_ENV, "two")
    with pytest.raises(PmalabError, match="PMALAB_JOBS=two"):
        api.identify(run, "bouc-wen")
