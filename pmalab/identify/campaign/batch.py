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
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from pmalab.errors import PmalabError

T = TypeVar("T")
R = TypeVar("R")

DEFAULT_JOBS = 2
#: how long to try reaching a Dask scheduler before giving up (s)
SCHEDULER_TIMEOUT_S = 10.0


def _pin_blas() -> None:
    """Worker initializer: one BLAS thread per worker process (we parallelise over runs)."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1, user_api="blas")
    except Exception:  # pragma: no cover - best effort
        pass


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
    from tqdm import tqdm

    bar = tqdm(
        total=len(tasks), desc=desc, file=sys.stderr, disable=not progress, unit="run", leave=False
    )
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


def _map_pool(fn: Callable[[T], R], tasks: list[T], jobs: int, bar: Any) -> list[R]:
    out: list[Any] = [None] * len(tasks)
    with ProcessPoolExecutor(max_workers=jobs, initializer=_pin_blas) as ex:
        futs = {ex.submit(fn, t): i for i, t in enumerate(tasks)}
        try:
            for f in as_completed(futs):
                out[futs[f]] = f.result()
                bar.update(1)
        except BaseException:
            for f in futs:
                f.cancel()
            raise
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
