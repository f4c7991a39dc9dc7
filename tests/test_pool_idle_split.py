"""A diagnosis pool's last task on two cores: once the pool's other worker has nothing left
(the batch's tail) and the machine has a core to spare, a candidate's independent parts —
its per-run fits and its structure refinements — are shared with a forked child
(pmalab.identify.campaign.batch.map_split_when_idle).  The numbers are those of one
process, bit for bit; outside a pool's worker nothing is split."""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from identify_synth import make_run
from user_shell import shell_env

from pmalab.identify.campaign import ModelSpec, batch
from pmalab.identify.campaign.batch import START_METHOD_ENV, ContextPool
from pmalab.identify.diagnosis.ranking import score

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux") or len(os.sched_getaffinity(0)) < 2,
    reason="a task is split by forking, on Linux with two cores or more",
)

METHODS = [m for m in ("fork", "spawn") if m in multiprocessing.get_all_start_methods()]


def _python(code: str, cwd: Path) -> subprocess.CompletedProcess:
    env = shell_env("PYTHONPATH")
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def _watch(context: float, task: float) -> tuple[bool, bool]:
    """A pool task of ``task`` seconds: (a worker waited when it started, one waited at some
    point before it ended)."""
    start = batch.pool_worker_waiting()
    later = start
    end = time.monotonic() + task
    while time.monotonic() < end:
        later = later or batch.pool_worker_waiting()
        time.sleep(0.01)
    return start, later


@pytest.mark.parametrize("method", METHODS)
def test_a_pool_task_sees_a_waiting_worker_only_in_the_batch_tail(method, monkeypatch):
    monkeypatch.setenv(START_METHOD_ENV, method)
    assert not batch.pool_worker_waiting() and not batch.idle_core()  # not a pool's worker
    with ContextPool(0.0, jobs=2) as pool:
        # three tasks on two workers: the first two start with three unfinished; the long
        # one outlives the others, so a worker waits while it runs
        first = pool.map(_watch, [0.3, 0.05, 2.0])
        # the count starts again with every map
        second = pool.map(_watch, [0.3, 0.3])
    assert first[0][0] is False and first[1][0] is False
    assert first[2][1] is True
    assert second[0][0] is False and second[1][0] is False


def test_map_split_when_idle_is_the_loop_and_splits_only_when_a_worker_waits(tmp_path):
    p = _python("""
        import multiprocessing, os
        from pmalab.identify.campaign import batch
        parent = os.getpid()
        sq = lambda t: (t * t, os.getpid())
        # outside a pool's worker: a plain loop
        assert [v for v, _ in batch.map_split_when_idle(sq, range(9))] == [t * t for t in range(9)]
        assert not batch.idle_core_possible()
        # a pool's worker whose pool has 3 unfinished tasks for 2 workers: no worker waits
        left = multiprocessing.Value("i", 3)
        batch._POOL_STATE[:] = [left, 2]
        batch.machine_has_idle_core = lambda: True
        out = batch.map_split_when_idle(sq, range(9))
        assert [v for v, _ in out] == [t * t for t in range(9)]
        assert {pid for _, pid in out} == {parent}
        # the other worker finishes during the first task: the rest goes on two cores
        def counted(t):
            if t == 0:
                left.value = 1
            return sq(t)
        left.value = 2
        out = batch.map_split_when_idle(counted, range(9))
        assert [v for v, _ in out] == [t * t for t in range(9)]
        pids = [pid for _, pid in out]
        assert pids[0] == parent and pids[-1] != parent and parent in pids[1:]
        # in the child's part, and in this process while its child runs, nothing splits again
        nested = batch.map_split_when_idle(
            lambda t: (batch.idle_core(), os.getpid()), range(6))
        assert not any(v for v, _ in nested)
        assert not batch._SPLITTING[0]
        print("ok")
    """, tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "ok"


def _runs():
    # four pressure levels: the leave-one-pressure-out structure choice is made
    train = [make_run("bouc-wen", p, f=0.5, n=3000, seed=i, name=f"id{i}")[0]
             for i, p in enumerate((0.3, 0.4, 0.5, 0.6))]
    held = [make_run("bouc-wen", 0.4, f=0.4, n=3000, seed=9, name="held")[0]]
    return train, held


SPEC = ModelSpec("maxwell-slip", ("viscous-friction",))


def _score_or_pass(context, task):
    """A pool task: nothing (``None``), or the candidate scored as the ladder scores it."""
    return None if task is None else score(context[0], context[1], task)


def test_a_split_candidate_scores_bit_for_bit_as_in_one_process(tmp_path, monkeypatch):
    """The candidate's per-run fits and its structure refinements are split (the other
    worker finishes at once), and every number equals the one-process score's."""
    monkeypatch.setenv(START_METHOD_ENV, "fork")  # the workers inherit the two patches
    log = tmp_path / "splits"
    real = batch.map_split

    def logged(fn, tasks, first_here=1):
        tasks = list(tasks)
        with log.open("a") as f:
            f.write(f"{fn.__name__} {len(tasks)} {batch.fork_is_safe()}\n")
        return real(fn, tasks, first_here)

    monkeypatch.setattr(batch, "map_split", logged)
    monkeypatch.setattr(batch, "machine_has_idle_core", lambda: True)
    train, held = _runs()
    alone = score(train, held, SPEC)
    assert not log.exists()  # in this process: never split
    with ContextPool((train, held), jobs=2) as pool:
        _, split = pool.map(_score_or_pass, [None, SPEC])
    done = [line.split() for line in log.read_text().splitlines()]
    assert {"_fit_task_remembering", "_refine_start"} <= {fn for fn, _, _ in done}
    assert all(forked == "True" for _, _, forked in done)  # each split a forked child
    assert split.error == alone.error == ""
    assert split.nrmse == alone.nrmse
    assert split.without_last == alone.without_last
    assert split.structure == alone.structure
    assert split.at_bounds == alone.at_bounds and split.n_params == alone.n_params
    for a, b in zip(split.predictions, alone.predictions, strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(split.block_mse, alone.block_mse, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_worker_keeps_the_memory_it_frees(tmp_path):
    """glibc takes the worker's allocator settings (blocks up to 32 MiB from the heap, freed
    memory kept): a fit's arrays are reused instead of mapped and zeroed again."""
    p = _python("""
        import platform
        from pmalab.identify.campaign.batch import keep_freed_memory
        print(keep_freed_memory() if platform.libc_ver()[0] == "glibc" else "not glibc")
    """, tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() in ("True", "not glibc")


def test_a_kept_runs_signals_are_computed_once_and_no_others(tmp_path):
    from pmalab.identify.signals import Signals, keep_run_signals

    a, _ = make_run("bouc-wen", 0.3, f=0.5, n=2000, seed=1, name="a")
    b, _ = make_run("bouc-wen", 0.5, f=0.5, n=2000, seed=2, name="b")
    try:
        keep_run_signals([a])
        sa = Signals.from_run(a)
        assert Signals.from_run(a) is sa  # kept: served again
        assert Signals.from_run(b) is not Signals.from_run(b)  # not named: computed anew
        fresh = Signals.from_run(a, cutoff_Hz=3.0)
        assert fresh is not sa and Signals.from_run(a, cutoff_Hz=3.0) is fresh
        keep_run_signals([b])  # another set: a's are forgotten
        assert Signals.from_run(a) is not sa
        for name in ("t", "x", "v", "a", "p", "x_raw"):
            np.testing.assert_array_equal(getattr(sa, name), getattr(Signals.from_run(a), name))
    finally:
        keep_run_signals([])


def _sharing_runs():
    train = [make_run("bouc-wen", p, f=0.5, n=3000, seed=20 + i, name=f"id{i}")[0]
             for i, p in enumerate((0.3, 0.45, 0.6))]
    held = [make_run("bouc-wen", 0.4, f=0.4, n=3000, seed=29, name="held")[0]]
    return train, held


def test_base_fits_one_worker_made_serve_the_others_with_the_same_scores(monkeypatch):
    """A round's candidates hand their base-law fits back; the next rounds' candidates get
    them, so a worker that never fitted the base law on these runs does not fit it again,
    and every score equals the one-process score bit for bit."""
    from pmalab.identify.diagnosis.ranking import _task_sharing, score_all
    from pmalab.identify.estimation import single

    monkeypatch.setenv(START_METHOD_ENV, "fork")
    monkeypatch.setattr(single, "_BASE_FITS", {})  # no fit of this process's earlier tests
    train, held = _sharing_runs()
    first = [ModelSpec("bouc-wen", ("viscous-friction",))]
    later = [ModelSpec("bouc-wen", ("inertia",)), ModelSpec("bouc-wen", ("sensor-drift",))]

    def plain(made: dict) -> int:  # the base law's own fits (not a structure's)
        return sum(1 for k in made if k[1] == ("bouc-wen",))

    base_fits: dict = {}
    with ContextPool((train, held), jobs=2) as pool:
        score_all(train, held, [*first, ModelSpec("duhem", ())], jobs=2, pool=pool,
                  base_fits=base_fits)
    assert plain(base_fits) == len(train)
    with ContextPool((train, held), jobs=2) as pool:  # new workers: they hold no fit
        shipped = pool.map(_task_sharing, [(s, dict(base_fits)) for s in later])
    with ContextPool((train, held), jobs=2) as pool:
        unshipped = pool.map(_task_sharing, [(s, {}) for s in later])
    alone = score_all(train, held, later, jobs=1)  # here, after the workers have forked
    assert [plain(made) for _, made in shipped] == [0, 0]
    assert all(plain(made) == len(train) for _, made in unshipped)
    for (got, _), (again, _), ref in zip(shipped, unshipped, alone, strict=True):
        assert got.nrmse == again.nrmse == ref.nrmse
        for a, b in zip(got.predictions, ref.predictions, strict=True):
            np.testing.assert_array_equal(a, b)
