"""The parallel paths (candidate scoring, per-run fits) under every start method.

Python 3.14 starts worker processes with forkserver on Linux and macOS uses spawn: a worker
then inherits nothing from the parent, so any state it needs must travel as an argument.
Each start method must give the same numbers as the in-process path."""

from __future__ import annotations

import multiprocessing
import os

import numpy as np
import pytest
from identify_synth import make_run

from pmalab.identify.campaign import ModelSpec
from pmalab.identify.campaign.batch import START_METHOD_ENV, map_with_context
from pmalab.identify.campaign.fit import fit_runs
from pmalab.identify.diagnosis.ranking import score_all

METHODS = [m for m in ("fork", "forkserver", "spawn") if m in multiprocessing.get_all_start_methods()]


def _runs():
    train = [make_run("bouc-wen", p, f=0.5, n=3000, seed=i, name=f"id{i}")[0]
             for i, p in enumerate((0.3, 0.45, 0.6))]
    held = [make_run("bouc-wen", 0.4, f=0.4, n=3000, seed=9, name="held")[0]]
    return train, held


SPECS = [ModelSpec("bouc-wen", ()), ModelSpec("bouc-wen", ("viscous-friction",))]


@pytest.fixture(scope="module")
def serial():
    train, held = _runs()
    return score_all(train, held, SPECS, jobs=1)


def _scale(context: tuple[float, float], x: float) -> float:
    return context[0] * x + context[1]


@pytest.mark.parametrize("method", METHODS)
def test_score_all_parallel(method, monkeypatch, serial):
    monkeypatch.setenv(START_METHOD_ENV, method)
    train, held = _runs()
    par = score_all(train, held, SPECS, jobs=2)
    assert [s.effects for s in par] == [s.effects for s in serial]
    for a, b in zip(par, serial):
        np.testing.assert_allclose(a.nrmse, b.nrmse, rtol=1e-9)
        assert a.n_params == b.n_params


@pytest.mark.parametrize("method", METHODS)
def test_fit_runs_parallel(method, monkeypatch):
    monkeypatch.setenv(START_METHOD_ENV, method)
    train, _ = _runs()
    spec = ModelSpec("bouc-wen", ("viscous-friction",))  # an effect: the pool is used
    par = fit_runs(train, spec, jobs=2)
    one = fit_runs(train, spec, jobs=1)
    assert [r.label for r in par] == ["id0", "id1", "id2"]
    for a, b in zip(par, one):
        np.testing.assert_allclose(a.nrmse, b.nrmse, rtol=1e-9)


def test_unknown_start_method_is_one_line(monkeypatch):
    from pmalab.errors import PmalabError

    monkeypatch.setenv(START_METHOD_ENV, "teleport")
    with pytest.raises(PmalabError, match="teleport"):
        map_with_context(_scale, (1.0, 0.0), [1.0, 2.0], jobs=2)


#: what a worker process has seen (a stand-in for the caches a worker keeps between maps)
_SEEN: list[float] = []


def _remember(context: tuple[float, float], x: float) -> tuple[int, float, tuple[float, ...]]:
    import os

    _SEEN.append(x)
    return os.getpid(), _scale(context, x), tuple(_SEEN)


@pytest.mark.parametrize("method", METHODS)
def test_context_pool_keeps_its_workers_across_maps(method, monkeypatch):
    """The ladder's pool: the same results as map_with_context, in task order, and the same
    worker processes (with what they hold) serve every map until it is closed."""
    from pmalab.identify.campaign.batch import ContextPool

    monkeypatch.setenv(START_METHOD_ENV, method)
    with ContextPool((2.0, 1.0), jobs=2) as pool:
        first = pool.map(_remember, [1.0, 2.0, 3.0, 4.0])
        second = pool.map(_remember, [5.0, 6.0, 7.0])
        # the executor's live workers after both maps (it may start its second worker only
        # when the first is busy, so one worker can serve a whole quick map alone)
        workers = set(pool._ex._processes)
        assert pool.map(_remember, [8.0])[0][1] == 17.0  # one task: in this process
    assert [v for _, v, _ in first] == [3.0, 5.0, 7.0, 9.0]
    assert [v for _, v, _ in second] == [11.0, 13.0, 15.0]
    assert [v for _, v, _ in second] == map_with_context(_scale, (2.0, 1.0), [5.0, 6.0, 7.0], jobs=2)
    first_pids, second_pids = {p for p, _, _ in first}, {p for p, _, _ in second}
    # every worker of the first map still alive and serving, none started per map, none
    # this process
    assert first_pids | second_pids <= workers and len(workers) <= 2
    assert os.getpid() not in workers
    # a worker that served both maps still holds what it saw in the first
    for pid, _, seen in second:
        if pid in first_pids:
            assert set(seen) & {1.0, 2.0, 3.0, 4.0}
    assert pool._ex is None  # shut down on exit


@pytest.mark.parametrize("method", METHODS[:1])
def test_score_all_through_a_kept_pool(method, monkeypatch, serial):
    from pmalab.identify.campaign.batch import ContextPool

    monkeypatch.setenv(START_METHOD_ENV, method)
    train, held = _runs()
    with ContextPool((train, held), jobs=2) as pool:
        par = score_all(train, held, SPECS, jobs=2, pool=pool)
        again = score_all(train, held, SPECS[::-1], jobs=2, pool=pool)
    for a, b in zip(par, serial):
        np.testing.assert_allclose(a.nrmse, b.nrmse, rtol=1e-9)
    for a, b in zip(again[::-1], serial):
        np.testing.assert_allclose(a.nrmse, b.nrmse, rtol=1e-9)
