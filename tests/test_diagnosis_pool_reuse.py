"""What a diagnosis's worker processes do once instead of once per candidate or per worker:
each context run's signals are filtered and differentiated once per worker
(pmalab.identify.signals.keep_run_signals), the base-law fits one worker made serve the
candidates of later rounds on every worker (pmalab.identify.diagnosis.ranking.score_all's
``base_fits``), and a worker keeps the memory it frees.  Every number stays that of one
process, bit for bit."""

from __future__ import annotations

import multiprocessing
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from identify_synth import make_run
from user_shell import shell_env

from pmalab.identify.campaign import ModelSpec
from pmalab.identify.campaign.batch import START_METHOD_ENV, ContextPool


def _python(code: str, cwd: Path) -> subprocess.CompletedProcess:
    env = shell_env("PYTHONPATH")
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


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


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(),
                    reason="the test's workers inherit its patched cache by forking")
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


def _echo(context: float, task: tuple[int, int]) -> tuple[int, int]:
    """(the task, how many results the parent had seen when it handed this task out)."""
    import time

    time.sleep(0.05)
    return task


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_fed_map_hands_each_task_out_with_the_results_before_it(jobs, monkeypatch):
    monkeypatch.setenv(START_METHOD_ENV, "spawn" if jobs > 1 else "fork")
    seen: list[int] = []
    with ContextPool(0.0, jobs=jobs) as pool:
        out = pool.map(_echo, list(range(8)), fed=lambda t: (t, len(seen)),
                       done=lambda r: seen.append(r[0]))
    assert [t for t, _ in out] == list(range(8))  # task order
    assert sorted(seen) == list(range(8))  # every result went to done, once
    known = [k for _, k in out]
    assert known == sorted(known)  # handed out in order, each knowing at least as much
    # at most jobs + 1 out at once: the task handed out last knew of all but those
    assert known[-1] >= 8 - 1 - jobs
    assert known[0] == 0


def test_values_of_a_kept_runs_signals_are_derived_once_and_equal(tmp_path):
    """The measured-side metrics and the loop direction of a kept run are computed once
    (every later fit of the run takes them) and equal what each fit computed before."""
    from pmalab.identify.metrics import loop_direction, measured_parts, metrics
    from pmalab.identify.signals import Signals, keep_run_signals, kept_derived

    a, _ = make_run("bouc-wen", 0.3, f=0.5, n=2000, seed=3, name="a")
    b, _ = make_run("bouc-wen", 0.5, f=0.5, n=2000, seed=4, name="b")
    calls: list[str] = []

    def counted(name, fn):
        def make():
            calls.append(name)
            return fn()
        return make

    try:
        keep_run_signals([a])
        sa, sb = Signals.from_run(a), Signals.from_run(b)
        for _ in range(3):
            got = kept_derived(sa, a.force, "ld", counted("a", lambda: loop_direction(a.force, sa.x)))
            other = kept_derived(sb, b.force, "ld", counted("b", lambda: loop_direction(b.force, sb.x)))
        assert calls == ["a", "b", "b", "b"]  # a's kept; b's (not named) every time
        assert got == loop_direction(a.force, sa.x) and other == loop_direction(b.force, sb.x)
        # another force with the same signals is another value
        assert kept_derived(sa, a.force * 2, "ld", counted("a2", lambda: 0.0)) == 0.0
        assert calls[-1] == "a2"
    finally:
        keep_run_signals([])
    # the metrics with the measured parts handed in are the metrics, to the last bit
    pred = a.force + np.sin(np.arange(len(a)) / 50.0)
    parts = measured_parts(a.force, sa.x)
    assert metrics(a.force, pred, sa.x, parts) == metrics(a.force, pred, sa.x)
