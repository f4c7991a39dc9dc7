"""A kept pool's worker left without a task helps a sibling with its batches
(pmalab.identify.campaign.sharing): the results, errors and warnings are those of the plain
loop, and a diagnosis's scores stay those of one process, bit for bit."""

from __future__ import annotations

import multiprocessing
import os
import time
import warnings

import numpy as np
import pytest
from identify_synth import make_run

from pmalab.identify.campaign import ModelSpec, sharing
from pmalab.identify.campaign.batch import START_METHOD_ENV, ContextPool
from pmalab.identify.diagnosis.ladder import cost_order
from pmalab.identify.diagnosis.ranking import score_all

#: fork (the default on Linux before Python 3.14) and spawn (a worker inherits nothing: the
#: most different; forkserver passes its arguments the same way)
METHODS = [m for m in ("fork", "spawn") if m in multiprocessing.get_all_start_methods()]
#: tasks in the long batch (each sleeps, so a loaded machine still runs the helper in time)
N_TASKS = 40


def _slow(x: int) -> tuple[int, int]:
    """A task: its square, and which process ran it."""
    time.sleep(0.05)
    if x == 7 and os.environ.get("SHARING_TEST_FAIL"):
        raise ValueError(f"task {x} failed")
    warnings.warn(f"task {x}", UserWarning, stacklevel=1)
    return x * x, os.getpid()


def _when_a_sibling_waits(context: object, n: int) -> tuple[list, list[str], int]:
    """A pool task: with ``n`` > 0, wait until a sibling helps (at most 60 s), then run a
    batch of ``n`` tasks through map_shared; its results, the warnings seen here and this
    process's id."""
    if n:
        deadline = time.monotonic() + 60.0
        while sharing._MINE[0].idle.value <= 0 and time.monotonic() < deadline:
            time.sleep(0.01)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = sharing.map_shared(_slow, list(range(n)))
    return out, [str(m.message) for m in caught], os.getpid()


def _is_context_run(x: object) -> bool:
    """Whether ``x`` is one of this worker's own context objects (not a copy)."""
    from pmalab.identify.campaign.batch import _WORKER_CONTEXT

    time.sleep(0.05)
    return any(x is r for r in _WORKER_CONTEXT[0][0])


def _context_batch(context: tuple[list, list], n: int) -> list[bool]:
    if n:
        deadline = time.monotonic() + 60.0
        while sharing._MINE[0].idle.value <= 0 and time.monotonic() < deadline:
            time.sleep(0.01)
    return sharing.map_shared(_is_context_run, [context[0][i % 2] for i in range(n)])


@pytest.mark.filterwarnings("ignore:task")
def test_outside_a_pool_it_is_the_plain_loop():
    assert not sharing.sharing_here()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = sharing.map_shared(_slow, [1, 2, 3])
    assert [v for v, _ in got] == [1, 4, 9]
    assert {pid for _, pid in got} == {os.getpid()}
    assert [str(m.message) for m in caught] == ["task 1", "task 2", "task 3"]


@pytest.mark.parametrize("method", METHODS)
def test_an_idle_worker_takes_part_of_a_batch_with_the_same_results(method, monkeypatch):
    """Under every start method (the shared queues, pipes and counters travel to the
    workers as the pool's initializer arguments)."""
    monkeypatch.setenv(START_METHOD_ENV, method)
    with ContextPool(("context",), jobs=2) as pool:
        (got, seen, owner), (empty, _, _) = pool.map(_when_a_sibling_waits, [N_TASKS, 0])
        helped = pool.helped
    assert empty == []
    assert [v for v, _ in got] == [x * x for x in range(N_TASKS)]
    pids = [pid for _, pid in got]
    assert 0 < helped < N_TASKS and sum(p != owner for p in pids) == helped
    # the helper's warnings are raised again in the worker whose batch it was: each once
    assert sorted(seen) == sorted(f"task {x}" for x in range(N_TASKS))


@pytest.mark.filterwarnings("ignore:task")
def test_a_failing_task_is_raised_as_the_plain_loop_raises_it(monkeypatch):
    monkeypatch.setenv("SHARING_TEST_FAIL", "1")
    with pytest.raises(ValueError, match="task 7 failed"):
        sharing.map_shared(_slow, list(range(10)))
    with ContextPool(("context",), jobs=2) as pool:
        with pytest.raises(ValueError, match="task 7 failed"):
            pool.map(_when_a_sibling_waits, [N_TASKS, 0])


def test_context_runs_travel_as_their_place_in_the_context():
    runs = [make_run("bouc-wen", p, f=0.5, n=500, seed=i, name=f"r{i}")[0]
            for i, p in enumerate((0.3, 0.5))]
    with ContextPool((runs, []), jobs=2) as pool:
        got, empty = pool.map(_context_batch, [12, 0])
        assert pool.helped > 0
    assert got == [True] * 12 and empty == []


def test_a_round_with_a_helper_scores_as_one_process_bit_for_bit():
    """A long candidate (an element law choosing its structure) beside a short one: the
    worker done first may help the other — whether it gets there in time depends on the
    machine's scheduling (on a loaded machine it may not; the batches that it helps with are
    tested above with a helper made to wait) — and every score is the one-process score
    either way."""
    train = [make_run("bouc-wen", p, f=0.5, n=1200, seed=i, name=f"id{i}")[0]
             for i, p in enumerate((0.3, 0.45, 0.6))]
    held = [make_run("bouc-wen", 0.4, f=0.4, n=1200, seed=9, name="held")[0]]
    specs = [ModelSpec("maxwell-slip", ("viscous-friction",)), ModelSpec("duhem", ())]
    alone = score_all(train, held, specs, jobs=1)
    with ContextPool((train, held), jobs=2) as pool:
        par = score_all(train, held, specs, jobs=2, pool=pool, base_fits={})
    for a, b in zip(par, alone, strict=True):
        assert a.nrmse == b.nrmse and a.n_params == b.n_params
        for x, y in zip(a.predictions, b.predictions, strict=True):
            np.testing.assert_array_equal(x, y)


def test_later_rounds_start_the_dearest_effects_first():
    specs = [ModelSpec("maxwell-slip", ("viscous-friction", e))
             for e in ("inertia", "sensor-delay", "sensor-drift")]
    # nothing measured yet: the given order (same law, same number of effects)
    assert cost_order(specs) == [0, 1, 2]
    took = {"inertia": 0.1, "sensor-delay": 0.4, "sensor-drift": 0.2}
    assert cost_order(specs, took) == [1, 2, 0]
    # a law with structures still goes before one without, whatever was measured
    mixed = [ModelSpec("bouc-wen", ("sensor-delay",)), ModelSpec("maxwell-slip", ("inertia",))]
    assert cost_order(mixed, took) == [1, 0]


def _inner(x: int) -> int:
    return x * x


def _outer(x: int) -> int:
    """A task that runs a batch of its own through map_shared (a nested batch)."""
    return sum(sharing.map_shared(_inner, [x, x + 1, x + 2]))


@pytest.fixture
def attached(monkeypatch):
    """This process as a kept pool's worker (slot 0 of 2) whose siblings' helpers are
    said to wait (``idle``), none of them running: every task it offers runs here."""
    import signal

    s = sharing.new_sharing(multiprocessing.get_context("fork"), 2)
    sharing.attach(s, ("context",))

    def too_long(*_):
        raise TimeoutError("the batch waited for results no helper was running")

    old = signal.signal(signal.SIGALRM, too_long)
    signal.alarm(10)
    try:
        yield s
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
        sharing._MINE[:] = []


def test_a_batch_inside_a_shared_batch_runs_here(attached):
    # the inner batch must not take the slot the outer batch is shared through: it runs
    # as the plain loop, and the outer batch's results are all there
    attached.idle.value = 2
    got = sharing.map_shared(_outer, [0, 1, 2, 3])
    assert got == [sum(_inner(x + i) for i in range(3)) for x in range(4)]


def test_a_forked_child_of_a_worker_does_not_share_its_slot(attached, monkeypatch):
    # a process forked from a worker inherits its slot: it must not offer batches in it
    # (the worker may be sharing through it at the same moment)
    attached.idle.value = 1
    assert sharing.sharing_here()
    real = os.getpid()
    monkeypatch.setattr(os, "getpid", lambda: real + 1)
    assert not sharing.sharing_here()
    assert sharing.map_shared(_inner, [1, 2, 3]) == [1, 4, 9]
    assert attached.idle.value == 1 and attached.offers.empty()


def _warns_then_fails(x: int) -> int:
    warnings.warn(f"task {x}", UserWarning, stacklevel=1)
    raise ValueError(f"task {x} failed")


def test_a_task_that_failed_in_the_helper_warns_once():
    # the helper ran task 0, which warned and then raised: the owner runs it again, and the
    # run again warns as the plain loop would, once (the helper's record of it is dropped)
    caught_there = [(UserWarning("task 0"), UserWarning, __file__, 1)]
    done = {0: (False, False, None, caught_there)}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(ValueError, match="task 0 failed"):
            sharing._in_order(_warns_then_fails, [0], done, 1)  # pyright: ignore[reportArgumentType]
    assert [str(m.message) for m in caught] == ["task 0"]
