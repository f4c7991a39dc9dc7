"""Run many independent jobs (one fit per run) in parallel, with a progress bar.

Three back-ends behind one function, :func:`map_tasks`:

* in process (``jobs=1``, or a single task);
* a local :class:`concurrent.futures.ProcessPoolExecutor` with ``jobs`` workers (default 2:
  the machine's cores are shared);
* a Dask distributed cluster (``scheduler="tcp://host:8786"``), the same work shipped to
  its workers; the client is closed afterwards, the cluster left running.

The progress bar (tqdm) goes to stderr so stdout stays clean for results.  Results come
back in task order whatever order they finish in.  An error in any task is re-raised.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from pmalab.arguments import DEFAULT_JOBS
from pmalab.errors import PmalabError

T = TypeVar("T")
R = TypeVar("R")
C = TypeVar("C")

#: how long to try reaching a Dask scheduler before giving up (s)
SCHEDULER_TIMEOUT_S = 10.0
#: environment variable choosing the worker start method (fork, forkserver, spawn); unset:
#: the platform's default (fork on Linux before Python 3.14, forkserver after, spawn on macOS)
START_METHOD_ENV = "PMALAB_START_METHOD"

#: the shared state of :func:`map_with_context` inside a worker process (set by the pool's
#: initializer from arguments, never inherited from the parent: valid under every start method)
_WORKER_CONTEXT: list[Any] = []


def _mp_context() -> Any:
    """The start method's context (:data:`START_METHOD_ENV`), or None for the default.

    Unset, where the default is ``fork`` but a GNU OpenMP runtime may have started threads
    here (:func:`gnu_openmp_started`), ``forkserver``: the workers then start from a clean
    process (the same results: a worker receives its context as the initializer's
    arguments under every start method)."""
    import multiprocessing

    name = os.environ.get(START_METHOD_ENV, "").strip()
    if not name:
        # the method in force, without fixing it (the platform's default is listed first)
        now = multiprocessing.get_start_method(allow_none=True)
        if (now or multiprocessing.get_all_start_methods()[0]) == "fork" and gnu_openmp_started():
            return multiprocessing.get_context("forkserver")
        return None

    if name not in multiprocessing.get_all_start_methods():
        raise PmalabError(
            f"{START_METHOD_ENV}={name}: not a start method here (one of "
            f"{', '.join(multiprocessing.get_all_start_methods())})"
        )
    return multiprocessing.get_context(name)


def _init_worker(*context: Any) -> None:
    """Worker initializer: pin BLAS, keep freed memory, and keep the shared state passed in
    (if any)."""
    _pin_blas()
    keep_freed_memory()
    _WORKER_CONTEXT[:] = context


#: glibc ``mallopt`` parameters (malloc.h) and the values a worker sets: blocks up to 32 MiB
#: (the largest glibc takes) from the heap, and freed memory kept in it
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
_KEEP_MALLOC = ((_M_MMAP_THRESHOLD, 32 << 20), (_M_TRIM_THRESHOLD, 1 << 30), (_M_TOP_PAD, 64 << 20))


def keep_freed_memory() -> bool:
    """Have this process's C allocator (glibc) keep the memory it frees; True if it does.

    A fit allocates and frees the same few arrays (a Jacobian, its scaled copy, an SVD's
    factors: up to megabytes each) thousands of times.  By default glibc hands blocks above
    128 KiB back to the system at every free, and the next allocation maps fresh pages the
    kernel must zero again (about 190,000 page faults in a diagnosis, 0.2–0.3 CPU-s).  Kept
    in the heap, they are reused.  Only the addresses change, never a number.  For worker
    processes, which exit when their batch is done; elsewhere (not glibc) nothing is done."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # pragma: no cover - not glibc (musl has no mallopt)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return all(mallopt(p, v) == 1 for p, v in _KEEP_MALLOC)


def _init_kept_worker(context: Any, sharing: Any) -> None:
    """A :class:`ContextPool` worker's initializer: :func:`_init_worker`, and a slot among
    the workers that share their batches (:func:`~pmalab.identify.campaign.sharing.attach`)."""
    from pmalab.identify.campaign.sharing import attach

    _init_worker(context)
    attach(sharing, context)


def _call_in_context(fn: Callable[[Any, Any], Any], task: Any) -> Any:
    """Run one task of :func:`map_with_context` in a worker, with the worker's state."""
    return fn(_WORKER_CONTEXT[0], task)


def in_worker() -> bool:
    """Whether this process is a worker of :func:`map_with_context` or a
    :class:`ContextPool` (holding its context)."""
    return bool(_WORKER_CONTEXT)


def _pin_blas() -> None:
    """Worker initializer: one BLAS thread per worker process (we parallelise over runs)."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1, user_api="blas")
    except Exception:  # pragma: no cover - best effort
        pass


class _NoBar:
    """The progress bar when none is shown (tqdm is not even imported)."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _bar(total: int, desc: str, progress: bool) -> Any:
    """A tqdm bar on stderr (runs done of ``total``), or a silent stand-in."""
    if not progress:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, file=sys.stderr, unit="run", leave=False)


def map_tasks(
    fn: Callable[[T], R],
    tasks: Sequence[T],
    *,
    jobs: int = DEFAULT_JOBS,
    scheduler: str | None = None,
    progress: bool = False,
    desc: str = "",
) -> list[R]:
    """``[fn(t) for t in tasks]``, in parallel; ``fn`` and tasks must be picklable."""
    tasks = list(tasks)
    if not tasks:
        return []
    bar = _bar(len(tasks), desc, progress)
    try:
        if scheduler:
            return _map_dask(fn, tasks, scheduler, bar)
        if jobs <= 1 or len(tasks) == 1:
            out = []
            for t in tasks:
                out.append(fn(t))
                bar.update(1)
            return out
        return _map_pool(fn, tasks, min(jobs, len(tasks)), bar)
    finally:
        bar.close()


def fork_is_safe() -> bool:
    """Whether :func:`map_split` may fork here: Linux, two cores or more, no other Python
    thread running (a forked child gets only the calling thread) and no GNU OpenMP runtime
    that may have started threads (:func:`gnu_openmp_started`).  OpenBLAS's own pthreads
    (NumPy's and SciPy's wheels) are re-created by its fork handler."""
    import threading

    return (
        sys.platform.startswith("linux")
        and hasattr(os, "fork")
        and len(os.sched_getaffinity(0)) >= 2
        and threading.active_count() == 1
        and not gnu_openmp_started()
    )


def gnu_openmp_started() -> bool:
    """Whether a GNU OpenMP runtime (libgomp) may have started threads in this process.

    True when libgomp is loaded — on its own (numba's ``omp`` layer, an extension module) or
    as a BLAS's threading layer (OpenBLAS built with OpenMP, MKL's ``gnu`` layer), as
    ``threadpoolctl`` finds the loaded libraries — and the process runs threads Python did
    not start (whose they are cannot be told, so any counts).  libgomp keeps a team's
    threads after its parallel region and has no fork handler: a forked child's next
    parallel region waits forever for threads that do not exist in it.  Where the libraries
    cannot be listed, True (the caller then does not fork)."""
    import threading

    try:
        if len(os.listdir("/proc/self/task")) <= threading.active_count():
            return False  # no thread but Python's: no runtime has started any
    except OSError:
        pass  # cannot count them: look at the libraries
    try:
        from threadpoolctl import threadpool_info

        libs = threadpool_info()
    except Exception:  # an unreadable library list: assume the worst
        return True
    return any(
        lib.get("user_api") == "openmp" and str(lib.get("prefix", "")) == "libgomp" for lib in libs
    )


def map_split(fn: Callable[[T], R], tasks: Sequence[T], first_here: int = 1) -> list[R]:
    """``[fn(t) for t in tasks]`` on two cores, for tasks too short for a process pool.

    The first ``first_here`` tasks run here (they load what every task needs: numba's
    compiled code, once); then a forked child runs the second half of the rest while this
    process runs the first half, and sends its results back pickled, so they arrive bit
    for bit.  Where forking is not safe (:func:`fork_is_safe`), or the child fails in any
    way, every task runs here (a task's own error is raised here, as in a plain loop).
    ``fn`` and the results must be picklable."""
    import pickle
    import warnings

    from pmalab.identify.reading import replay_warning

    tasks = list(tasks)
    out = [fn(t) for t in tasks[:first_here]]
    rest = tasks[first_here:]
    if len(rest) < 2 or not fork_is_safe():
        return out + [fn(t) for t in rest]
    half = (len(rest) + 1) // 2  # the child, paying its copy-on-write faults, takes fewer
    mine, theirs = rest[:half], rest[half:]
    sys.stdout.flush()
    sys.stderr.flush()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: its half, sent back; never the parent's exit handlers
        code = 1
        try:
            os.close(r)
            with warnings.catch_warnings(record=True) as caught:
                got = [fn(t) for t in theirs]
            data = pickle.dumps((got, caught), protocol=pickle.HIGHEST_PROTOCOL)
            with os.fdopen(w, "wb") as f:
                f.write(data)
            code = 0
        except BaseException:
            pass
        finally:
            os._exit(code)
    os.close(w)
    reader = os.fdopen(r, "rb")
    data = b""
    try:
        out += [fn(t) for t in mine]
        data = reader.read()
    finally:
        reader.close()  # a child still writing gets a broken pipe, and exits
        _, status = os.waitpid(pid, 0)
    if data and os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0:
        try:
            got, caught = pickle.loads(data)
        except Exception:
            got = None
        if got is not None:
            for m in caught:  # the child's warnings, after this half's (the tasks' order)
                replay_warning(m)
            return out + got
    return out + [fn(t) for t in theirs]  # the child failed: its half here


def map_with_context(
    fn: Callable[[C, T], R],
    context: C,
    tasks: Sequence[T],
    *,
    jobs: int = DEFAULT_JOBS,
    scheduler: str | None = None,
    progress: bool = False,
    desc: str = "",
) -> list[R]:
    """``[fn(context, t) for t in tasks]``, in parallel, with ``context`` shipped once per
    worker process (by the pool's initializer) rather than once per task.

    The worker state travels as an argument, so this works under every start method (fork,
    forkserver, spawn); on a Dask cluster each task carries ``context``."""
    tasks = list(tasks)
    if scheduler:
        from functools import partial

        return map_tasks(
            partial(fn, context), tasks, scheduler=scheduler, progress=progress, desc=desc
        )
    if jobs <= 1 or len(tasks) <= 1:
        return map_tasks(lambda t: fn(context, t), tasks, jobs=1, progress=progress, desc=desc)
    from functools import partial

    bar = _bar(len(tasks), desc, progress)
    try:
        return _map_pool(
            partial(_call_in_context, fn), tasks, min(jobs, len(tasks)), bar, (context,)
        )
    finally:
        bar.close()


class ContextPool:
    """Local worker processes holding one shared ``context``, kept across several maps.

    :func:`map_with_context` starts its workers for one map; a caller that maps several
    batches over the same context (the diagnosis ladder's rounds) keeps them here instead:
    the context is shipped once per worker, and what a worker has computed and cached in
    its process (compiled laws, base-law fits of the same records) serves the next batch.
    Results are those of :func:`map_with_context` (each task is the same computation in any
    process); ``jobs`` ≤ 1 or a single task runs in this process.  Use as a context manager
    (the workers are shut down on exit)."""

    def __init__(self, context: Any, jobs: int = DEFAULT_JOBS) -> None:
        self.context, self.jobs = context, jobs
        self._ex: Any = None
        self._sharing: Any = None
        self._lent: _Helpers | None = None

    def map(
        self,
        fn: Callable[[Any, Any], R],
        tasks: Sequence[T],
        *,
        progress: bool = False,
        desc: str = "",
        fed: Callable[[T], Any] | None = None,
        done: Callable[[R], None] | None = None,
    ) -> list[R]:
        """``[fn(context, t) for t in tasks]`` on the pool's workers, in task order.

        ``fed``: the tasks are handed out as workers become free (one queued ahead of the
        workers), each as ``fed(t)`` made at that moment, and every result is passed to
        ``done`` as it arrives — so a task can carry what the results before it made (the
        results are the same: ``fed`` only adds what a task may reuse)."""
        tasks = list(tasks)
        if fed is not None:
            return self._map_fed(fn, tasks, fed, done, progress, desc)
        if self.jobs <= 1 or len(tasks) <= 1:
            return map_with_context(fn, self.context, tasks, jobs=1, progress=progress, desc=desc)
        ex = self._executor()
        from functools import partial

        bar = _bar(len(tasks), desc, progress)
        try:
            return _collect_fed(
                ex,
                partial(_call_in_context, fn),
                tasks,
                None,
                None,
                len(tasks),
                bar,
                self._helpers(),
            )
        finally:
            bar.close()

    def _map_fed(
        self,
        fn: Callable[[Any, Any], R],
        tasks: list[T],
        fed: Callable[[T], Any],
        done: Callable[[R], None] | None,
        progress: bool,
        desc: str,
    ) -> list[R]:
        """:meth:`map` with ``fed`` (see there)."""
        from functools import partial

        bar = _bar(len(tasks), desc, progress)
        try:
            if self.jobs <= 1 or len(tasks) <= 1:
                out = []
                for t in tasks:
                    out.append(fn(self.context, fed(t)))
                    if done is not None:
                        done(out[-1])
                    bar.update(1)
                return out
            ex = self._executor()
            return _collect_fed(
                ex,
                partial(_call_in_context, fn),
                tasks,
                fed,
                done,
                self.jobs + 1,
                bar,
                self._helpers(),
            )
        finally:
            bar.close()

    def _executor(self) -> Any:
        """The pool's executor, its workers started on first use (each holding the context
        and the objects through which it shares batches with an idle sibling,
        :mod:`~pmalab.identify.campaign.sharing`)."""
        if self._ex is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            from pmalab.identify.campaign.sharing import new_sharing

            ctx = _mp_context() or multiprocessing.get_context()
            self._sharing = new_sharing(ctx, self.jobs)
            self._ex = ProcessPoolExecutor(
                max_workers=self.jobs,
                mp_context=ctx,
                initializer=_init_kept_worker,
                initargs=(self.context, self._sharing),
            )
        return self._ex

    def _helpers(self) -> _Helpers:
        """How :func:`_collect_fed` puts this pool's idle workers to work on their
        siblings' batches (the tasks they ran are added to :attr:`helped`)."""
        from functools import partial

        from pmalab.identify.campaign.sharing import help_siblings

        self._lent = _Helpers(
            self.jobs, partial(_call_in_context, help_siblings), self._sharing.stop
        )
        return self._lent

    @property
    def helped(self) -> int:
        """Tasks of its batches a worker ran for a sibling in this pool's last map
        (:mod:`~pmalab.identify.campaign.sharing`)."""
        return self._lent.ran if self._lent is not None else 0

    def close(self) -> None:
        """Shut the workers down (queued tasks cancelled)."""
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=True)
            self._ex = None

    def __enter__(self) -> ContextPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _map_pool(
    fn: Callable[[T], R], tasks: list[T], jobs: int, bar: Any, initargs: tuple[Any, ...] = ()
) -> list[R]:
    # imported here: a command that fits in process (most campaigns) never loads them
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(
        max_workers=jobs, mp_context=_mp_context(), initializer=_init_worker, initargs=initargs
    ) as ex:
        return _collect(ex, fn, tasks, bar)


def _collect(ex: Any, fn: Callable[[T], R], tasks: list[T], bar: Any) -> list[R]:
    """Submit every task to the executor ``ex`` at once; results in task order (a failure
    cancels the tasks not started and is re-raised)."""
    return _collect_fed(ex, fn, tasks, None, None, max(len(tasks), 1), bar)


@dataclass
class _Helpers:
    """A kept pool's way to lend its idle workers to their siblings' batches
    (:mod:`~pmalab.identify.campaign.sharing`): ``workers`` processes; ``task`` the pool
    task that makes a worker a helper (it returns how many tasks it ran); ``stop(n)``
    stops ``n`` helpers; ``ran`` counts the tasks helpers ran."""

    workers: int
    task: Callable[[Any], int]
    stop: Callable[[int], None]
    ran: int = 0


def _collect_fed(
    ex: Any,
    fn: Callable[[Any], R],
    tasks: list[T],
    fed: Callable[[T], Any] | None,
    done: Callable[[R], None] | None,
    ahead: int,
    bar: Any,
    helpers: _Helpers | None = None,
) -> list[R]:
    """Submit the tasks to the executor ``ex`` at most ``ahead`` at a time, each as
    ``fed(t)`` made when it is submitted (``t`` itself without ``fed``); each result goes
    to ``done`` as it arrives; results in task order (a failure cancels the tasks not
    started and is re-raised).

    ``helpers``: once every task is handed out, each worker left without one is made a
    helper of the others (they share their batches with it) until the tasks are done."""
    from concurrent.futures import FIRST_COMPLETED, wait

    out: list[Any] = [None] * len(tasks)
    pending: dict[Any, int] = {}
    helping: list[Any] = []
    nxt = 0
    try:
        while pending or nxt < len(tasks):
            while nxt < len(tasks) and len(pending) < ahead:
                t = tasks[nxt]
                pending[ex.submit(fn, t if fed is None else fed(t))] = nxt
                nxt += 1
            if helpers is not None and nxt == len(tasks):
                while pending and len(pending) + len(helping) < helpers.workers:
                    helping.append(ex.submit(helpers.task, None))
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for f in sorted(finished, key=pending.__getitem__):
                i = pending.pop(f)
                out[i] = f.result()
                if done is not None:
                    done(out[i])
                bar.update(1)
    except BaseException:
        for f in pending:
            f.cancel()
        raise
    finally:
        if helpers is not None and helping:
            helpers.stop(len(helping))
            wait(helping)
            helpers.ran += sum(f.result() for f in helping if not f.exception())
    return out


def _map_dask(fn: Callable[[T], R], tasks: list[T], address: str, bar: Any) -> list[R]:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:  # pragma: no cover - dask[distributed] is a dependency
        raise PmalabError(
            "--scheduler needs dask[distributed] (pip install 'dask[distributed]')"
        ) from None
    try:
        client = Client(address, timeout=f"{SCHEDULER_TIMEOUT_S}s")
    except (OSError, TimeoutError) as exc:
        raise PmalabError(
            f"--scheduler {address}: cannot connect to the Dask scheduler ({exc})"
        ) from None
    try:
        futs = client.map(fn, tasks, pure=False)
        index = {f.key: i for i, f in enumerate(futs)}
        out: list[Any] = [None] * len(tasks)
        for f in dask_completed(futs):
            out[index[f.key]] = f.result()
            bar.update(1)
        return out
    finally:
        client.close()
