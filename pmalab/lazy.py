"""Package attributes imported on first use (PEP 562), so that ``pmalab`` starts fast.

Every verb registers its options at start-up through its area's ``cli`` module, which
imports the area's package; a package that re-exported its API eagerly would make every
``pmalab`` command pay for numpy, h5py, scipy or matplotlib before the chosen verb runs.
The other start-up helpers: :func:`gc_paused` (imports without the cyclic collector),
:func:`with_stack_room` (a command's work without CPython's frame-stack chunk churn) and
:func:`one_blas_thread_from_the_start` (BLAS loaded without its spinning threads).
"""

from __future__ import annotations

import gc
import importlib
import os
import sys
import types
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any


def lazy_exports(
    package: str, exports: Mapping[str, str]
) -> tuple[Callable[[str], Any], list[str]]:
    """``(__getattr__, __all__)`` for ``package``: ``exports`` maps a name to its module."""
    table = dict(exports)

    def __getattr__(name: str) -> Any:
        mod = table.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(mod), name)

    return __getattr__, sorted(table)


#: whether this process is the ``pmalab`` command (:func:`the_command_starts`), not a user's
#: program that imported pmalab: only then may start-up helpers change process-wide state
_THE_COMMAND: list[bool] = [False]


def the_command_starts() -> None:
    """Mark this process as the ``pmalab`` command (:func:`pmalab.cli.main` run by the
    console script) and load BLAS on one thread (:func:`one_blas_thread_from_the_start`)."""
    _THE_COMMAND[0] = True
    one_blas_thread_from_the_start()


def is_the_command() -> bool:
    """Whether this process is the ``pmalab`` command (:func:`the_command_starts`; its
    forked children too), where freezing the first imports' objects
    (:func:`gc_paused`) touches nothing of a user's program."""
    return _THE_COMMAND[0]


def one_blas_thread_from_the_start() -> None:
    """Load BLAS with one thread (``OPENBLAS_NUM_THREADS=1``) when this process has not
    loaded NumPy yet (a command run from the shell) and the user has not chosen a count.

    pmalab parallelises over runs and pages in processes, never inside BLAS: every fit
    runs its linear algebra with one BLAS thread already
    (:func:`pmalab.identify.estimation.solver.one_blas_thread`: tall-skinny problems are
    slower threaded).  But OpenBLAS starts its threads when NumPy and SciPy load it (each
    its own library) and again after a fork, and after each call a thread busy-waits for
    work for about 0.1 s, on the core the command's other processes (forked children,
    report pages, a second command) need: 0.4-0.5 s of CPU in one identification of a
    small campaign, 2 of the demo's ~26 CPU-s, and on a loaded machine a call waits for a
    descheduled thread.  Asking for one thread before the library loads starts none.  The
    setting is inherited by the forked children and by any process this one starts; a
    count the user set (``OPENBLAS_NUM_THREADS``) is kept.
    """
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


@contextmanager
def gc_paused(freeze: bool) -> Iterator[None]:
    """Cyclic garbage collection paused while a command imports its heavy modules.

    Importing SciPy and numba, and numba's first load of its compiled code, create hundreds
    of thousands of long-lived objects that the collector would walk again and again: about
    a tenth of the import time and a third of that first load.

    Parameters
    ----------
    freeze
        Move every object alive at the end into the collector's permanent generation
        (:func:`gc.freeze`), so no later collection walks them again; else resuming would
        walk them all at the next collection.  For a process's first import of those
        modules (a command run from the shell: they live as long as the process); not for a
        process that already holds other work (a test session), whose garbage of the moment
        would be kept too.
    """
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            if freeze:
                gc.freeze()
            gc.enable()


#: bytes of CPython frame stack kept free for the work :func:`with_stack_room` runs
STACK_ROOM = 64 * 1024


def _call(fn: Callable[..., Any], args: tuple, kwargs: dict) -> Any:
    return fn(*args, **kwargs)


def _roomy_call(room: int = STACK_ROOM) -> Callable[[Callable[..., Any], tuple, dict], Any]:
    """:func:`_call` with a frame of ``room`` bytes more (a larger evaluation stack than it
    uses: the slots are reserved, never read), or :func:`_call` itself where code objects
    cannot be rebuilt so (not CPython, or a runtime that refuses the size: the work then
    runs as a plain call, never fails for want of room)."""
    if sys.implementation.name != "cpython":
        return _call
    code = _call.__code__
    try:
        roomy = code.replace(co_stacksize=code.co_stacksize + room // 8)
    except Exception:  # AttributeError, TypeError, ValueError, OverflowError, SystemError
        return _call
    return types.FunctionType(roomy, _call.__globals__, "_roomy_call")


_ROOMY_CALL = _roomy_call()


def with_stack_room(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` with :data:`STACK_ROOM` bytes of CPython's frame stack free
    above it, in one block that lives as long as the call.

    CPython (3.11 on) keeps its frames in chunks of 16 KiB and frees a chunk as soon as
    the frame at its base returns, so a loop that keeps calling across a chunk's end maps
    and unmaps a chunk on every call (CPython issue gh-142183; later 3.13 and 3.14 releases
    keep one chunk spare).  Where that end falls depends on every frame below: for
    ``pmalab identify`` run from the shell it fell inside numba's import, 27,000
    mmap/munmap pairs and page faults, about 0.15 s of system time.  This call's own frame
    is made larger than the room (its evaluation stack is reserved, never used), so it
    starts a block of twice the room and ``fn`` runs in the other half: nothing it calls
    within that depth reaches a chunk's end, wherever the caller stood.

    Parameters
    ----------
    fn
        The work (a command's body).
    args, kwargs
        Passed to ``fn``.

    Returns
    -------
    object
        What ``fn`` returns; what it raises propagates unchanged.
    """
    return _ROOMY_CALL(fn, args, kwargs)
