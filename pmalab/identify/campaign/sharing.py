"""A batch's tasks shared with an idle sibling of a kept pool's worker.

The diagnosis scores its candidates on a :class:`~pmalab.identify.campaign.batch.ContextPool`,
one candidate per worker.  At the end of a round the last candidates run while the other
workers have nothing to do until the round is judged; a candidate is itself batches of
independent tasks (one per-run fit per identification run, one refinement per structure),
so a waiting worker can take some of them:

* the pool hands each worker left without a task a *helper* task (:func:`help_siblings`),
  which waits for an offer;
* a worker that runs a batch through :func:`map_shared` while a helper waits offers it the
  rest of the batch; both then take the tasks one at a time, in order, from a counter they
  share, and the helper sends its results back;
* when the pool's tasks are done, it stops its helpers (:meth:`Sharing.stop`).

The results are those of ``[fn(t) for t in tasks]`` bit for bit: each task is the same
computation in either process (the pool's context — the same records in every worker —
travels as places in it, so a task's runs are the helper's own copies of them), results
travel pickled, the warnings a helper's task raised are raised again in the owner, and an
error is raised as the plain loop raises it: the first failing task in task order, run
again in the owner if the helper ran it (its traceback is then the owner's own).
"""

from __future__ import annotations

import io
import os
import pickle
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: per slot in :attr:`Sharing.claims`: the batch's number, the next task to take, the count
_BATCH, _NEXT, _COUNT = 0, 1, 2
_PER_SLOT = 3


@dataclass
class Sharing:
    """What a kept pool's workers share to hand tasks to an idle sibling (made by the pool
    with :func:`new_sharing`, passed to every worker as an initializer argument; fields are
    multiprocessing objects of the pool's start method).

    A worker takes a *slot* when it starts (:func:`attach`); offers, claims and results are
    addressed by the offering worker's slot."""

    #: offers ``(slot, batch, payload)`` from busy workers to helpers; None stops a helper
    offers: Any
    #: per slot: the (reader, writer) of the pipe carrying helpers' results to the worker
    results: list[tuple[Any, Any]]
    #: per slot: a lock held while a helper writes a result to that slot's pipe
    locks: list[Any]
    #: per slot: the batch's number, the next task to take and the batch's task count
    claims: Any
    #: helpers waiting for an offer
    idle: Any
    #: slots handed out so far
    taken: Any
    #: this worker's slot (-1 outside a worker)
    slot: int = -1
    #: ``id`` of each object of the worker's context → its place (:func:`attach`)
    places: dict[int, int] = field(default_factory=dict, repr=False)
    #: the worker's context objects, by place
    objects: list[Any] = field(default_factory=list, repr=False)

    def stop(self, helpers: int) -> None:
        """Stop ``helpers`` helper tasks (the pool's parent, when its tasks are done)."""
        for _ in range(helpers):
            self.offers.put(None)

    def __getstate__(self) -> dict[str, Any]:
        # the per-process parts stay behind (a worker sets its own in attach)
        state = dict(self.__dict__)
        state.update(slot=-1, places={}, objects=[])
        return state


#: this worker's :class:`Sharing` (empty outside a kept pool's worker)
_MINE: list[Sharing] = []
#: the process that attached :data:`_MINE` (a child forked from a worker inherits the
#: worker's slot, which the worker may be sharing through at the same moment), and whether
#: a shared batch runs in it now (a batch inside it would reopen the slot's counters)
_OWNER = {"pid": -1, "busy": False}


def new_sharing(ctx: Any, workers: int) -> Sharing:
    """The shared objects for a pool of ``workers`` processes, made with the
    multiprocessing context ``ctx`` (the pool's start method)."""
    pipes = [ctx.Pipe(duplex=False) for _ in range(workers)]
    return Sharing(
        offers=ctx.SimpleQueue(),
        results=[(r, w) for r, w in pipes],
        locks=[ctx.Lock() for _ in range(workers)],
        claims=ctx.Array("q", _PER_SLOT * workers),
        idle=ctx.Value("i", 0),
        taken=ctx.Value("i", 0),
    )


def attach(sharing: Sharing, context: Any) -> None:
    """In a new worker: take a slot and know the worker's context objects (``context``
    and, where it is a tuple or list of sequences, their items), which tasks and results
    name by place instead of carrying them."""
    with sharing.taken.get_lock():
        slot = sharing.taken.value
        sharing.taken.value += 1
    if slot >= len(sharing.results):
        return  # a worker started in place of a lost one: it runs its batches alone
    objects: list[Any] = [context]
    if isinstance(context, (tuple, list)):
        for part in context:
            objects.append(part)
            if isinstance(part, (tuple, list)):
                objects.extend(part)
    sharing.slot = slot
    sharing.objects = objects
    sharing.places = {id(o): i for i, o in enumerate(objects)}
    _MINE[:] = [sharing]
    _OWNER.update(pid=os.getpid(), busy=False)


def _mine() -> Sharing | None:
    """This worker's :class:`Sharing`, or None: outside a kept pool's worker, in a child
    forked from one, or inside a batch this worker shares or helps with (a task that runs
    a batch of its own runs it as the plain loop)."""
    if not _MINE or _OWNER["busy"] or _OWNER["pid"] != os.getpid():
        return None
    return _MINE[0]


def sharing_here() -> bool:
    """Whether this process is a kept pool's worker that can share its batches."""
    return _mine() is not None


class _Pickler(pickle.Pickler):
    """Pickles the worker's context objects as their places (:func:`attach`)."""

    def __init__(self, file: io.BytesIO, places: dict[int, int]) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.places = places

    def persistent_id(self, obj: Any) -> int | None:
        return self.places.get(id(obj))


class _Unpickler(pickle.Unpickler):
    """Unpickles places as this worker's own context objects."""

    def __init__(self, file: io.BytesIO, objects: list[Any]) -> None:
        super().__init__(file)
        self.objects = objects

    def persistent_load(self, pid: Any) -> Any:
        return self.objects[int(pid)]


def _dumps(s: Sharing, obj: Any) -> bytes:
    f = io.BytesIO()
    _Pickler(f, s.places).dump(obj)
    return f.getvalue()


def _loads(s: Sharing, data: bytes) -> Any:
    return _Unpickler(io.BytesIO(data), s.objects).load()


def map_shared(fn: Callable[[T], R], tasks: Sequence[T]) -> list[R]:
    """``[fn(t) for t in tasks]``, the same results; in a kept pool's worker, the tasks
    left when a sibling is waiting for work are shared with it (module docstring).

    ``fn`` must be a module-level function; tasks and results must pickle (a task that does
    not is run here).  A batch that a shared task runs, or that a child forked from the
    worker runs, is the plain loop (the worker's slot is taken by the batch it shares)."""
    tasks = list(tasks)
    s = _mine()
    out: list[R] = []
    for i, t in enumerate(tasks):
        if s is not None and len(tasks) - i >= 2 and s.idle.value > 0:
            shared = _share(s, fn, tasks[i:])
            if shared is not None:
                return out + shared
        out.append(fn(t))
    return out


def _take_helper(s: Sharing) -> bool:
    """Claim one waiting helper for an offer (False: none waits any more)."""
    with s.idle.get_lock():
        if s.idle.value <= 0:
            return False
        s.idle.value -= 1
        return True


def _open_batch(s: Sharing, count: int) -> int:
    """Start a batch of ``count`` tasks in this worker's slot; returns its number."""
    with s.claims.get_lock():
        raw, b = s.claims.get_obj(), _PER_SLOT * s.slot
        raw[b + _BATCH] += 1
        raw[b + _NEXT], raw[b + _COUNT] = 0, count
        return int(raw[b + _BATCH])


def _claim(s: Sharing, slot: int, batch: int) -> int | None:
    """The next task of ``slot``'s batch ``batch`` to run (None: none left, or the batch is
    over)."""
    with s.claims.get_lock():
        raw, b = s.claims.get_obj(), _PER_SLOT * slot
        if raw[b + _BATCH] != batch or raw[b + _NEXT] >= raw[b + _COUNT]:
            return None
        i = int(raw[b + _NEXT])
        raw[b + _NEXT] = i + 1
        return i


def _close_batch(s: Sharing) -> int:
    """No more tasks of this worker's batch are taken; returns how many were."""
    with s.claims.get_lock():
        raw, b = s.claims.get_obj(), _PER_SLOT * s.slot
        raw[b + _COUNT] = raw[b + _NEXT]
        return int(raw[b + _NEXT])


#: a finished task: (ran here, succeeded, value or exception, the helper's warnings)
_Done = tuple[bool, bool, Any, list[tuple[Any, ...]]]


def _share(s: Sharing, fn: Callable[[T], R], tasks: list[T]) -> list[R] | None:
    """Run ``tasks`` here and in a waiting helper; None when they cannot be offered (they
    do not pickle, or no helper waits any more)."""
    try:
        payload = _dumps(s, (fn, tasks))
    except Exception:  # a task that does not travel: the batch stays here
        return None
    if not _take_helper(s):
        return None
    _OWNER["busy"] = True
    try:
        return _shared(s, fn, tasks, payload)
    finally:
        _OWNER["busy"] = False


def _shared(s: Sharing, fn: Callable[[T], R], tasks: list[T], payload: bytes) -> list[R]:
    """:func:`_share` once a helper is taken: offer the batch, run it, gather it."""
    batch = _open_batch(s, len(tasks))
    s.offers.put((s.slot, batch, payload))
    done: dict[int, _Done] = {}
    while (i := _claim(s, s.slot, batch)) is not None:
        try:
            done[i] = (True, True, fn(tasks[i]), [])
        except Exception as exc:  # the loop stops here, as a plain loop would
            done[i] = (True, False, exc, [])
            break
        finally:
            _receive(s, batch, done, wait=False)
    taken = _close_batch(s)
    while len(done) < taken:
        _receive(s, batch, done, wait=True)
    return _in_order(fn, tasks, done, taken)


def _receive(s: Sharing, batch: int, done: dict[int, _Done], wait: bool) -> None:
    """Take the helpers' results that arrived for ``batch`` (with ``wait``, at least one)."""
    reader = s.results[s.slot][0]
    while reader.poll(None if wait else 0):
        got, i, ok, value, caught = _loads(s, reader.recv_bytes())
        if got == batch:  # a result of an abandoned batch is dropped
            done[i] = (False, ok, value, caught)
            wait = False


def _in_order(fn: Callable[[T], R], tasks: list[T], done: dict[int, _Done], taken: int) -> list[R]:
    """The results in task order; the first failure raised as the plain loop raises it."""
    from pmalab.identify.reading import replay_warning

    out: list[R] = []
    for i in range(taken):
        here, ok, value, caught = done[i]
        if ok:
            for m in caught:
                replay_warning(warnings.WarningMessage(*m))
            out.append(value)
        elif here:
            raise value
        else:  # failed in the helper: run again here, where it raises with this traceback
            # (and raises its warnings again: the helper's record of them is not replayed)
            out.append(fn(tasks[i]))
    if taken < len(tasks):  # pragma: no cover - only after a failure, raised above
        raise RuntimeError("a shared batch stopped without a failure")
    return out


def help_siblings(_context: Any = None, _task: Any = None) -> int:
    """A pool task for a worker left without one: wait for the siblings' offers and run
    their tasks (:func:`map_shared`) until stopped; returns how many tasks it ran."""
    s = _mine()
    if s is None:
        return 0
    ran = 0
    with s.idle.get_lock():
        s.idle.value += 1
    while True:
        offer = s.offers.get()
        if offer is None:
            with s.idle.get_lock():
                s.idle.value -= 1
            return ran
        _OWNER["busy"] = True
        try:
            ran += _run_offer(s, *offer)
        finally:
            _OWNER["busy"] = False
        with s.idle.get_lock():  # waiting again (the offer's owner took this helper)
            s.idle.value += 1


def _run_offer(s: Sharing, slot: int, batch: int, payload: bytes) -> int:
    """Run tasks of ``slot``'s batch ``batch`` until none is left; returns how many."""
    try:
        fn, tasks = _loads(s, payload)
    except Exception:  # pragma: no cover - it pickled in the owner: the owner runs it all
        return 0
    ran = 0
    while (i := _claim(s, slot, batch)) is not None:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")  # the owner's filters decide what is shown
            try:
                ok, value = True, fn(tasks[i])
            except Exception:  # the owner runs it again and raises it
                ok, value = False, None
        kept = [(m.message, m.category, m.filename, m.lineno) for m in caught]
        try:
            data = _dumps(s, (batch, i, ok, value, kept))
        except Exception:  # a result that does not travel: the owner runs the task again
            data = _dumps(s, (batch, i, False, None, []))
        with s.locks[slot]:
            s.results[slot][1].send_bytes(data)
        ran += 1
    return ran
