"""The runner's side of the live view: a bounded, never-blocking hand-off.

The 500 Hz loop calls :meth:`LiveFeed.run_started` once per run; it replaces the run
writer's ``add`` by a tap that stores the sample as before and appends a tuple to a
``collections.deque(maxlen=...)``.  ``deque.append`` is one C call under the GIL: it never
blocks and, when the display side has fallen behind, silently pushes out the oldest
sample.  Drops are counted by the display side from gaps in the tuples' sequence numbers,
so the loop pays no bookkeeping for them.  Nothing here touches a socket or a lock.
"""

from __future__ import annotations

import itertools
from collections import deque
from typing import Any

from pmalab.acquisition.protocol import RunSpec
from pmalab.acquisition.recorder import RunWriter
from pmalab.acquisition.runner import RunObserver

#: samples held for the display thread: 8 s at 500 Hz (it drains every 50 ms)
QUEUE_SAMPLES = 4096

#: a sample as handed on: (seq, run index, t s, x mm, F N, p_muscle MPa, p_cyl MPa, cmd MPa)
Sample = tuple[int, int, float, float, float, float, float, float]


class LiveFeed(RunObserver):
    """Bounded queues from the sample loop to the live view's pump thread."""

    def __init__(self, maxlen: int = QUEUE_SAMPLES) -> None:
        self.samples: deque[Sample] = deque(maxlen=maxlen)
        #: run starts and ends, in order (a few per run: never dropped in practice)
        self.events: deque[tuple[Any, ...]] = deque(maxlen=10_000)
        self._seq = itertools.count()

    def run_started(self, index: int, spec: RunSpec, writer: RunWriter) -> None:
        self.events.append(("start", index, spec, writer))
        add, put, seq = writer.add, self.samples.append, self._seq

        def tap(t: float, x: float, f: float, pm: float, pc: float, cmd: float,
                lateness: float) -> None:
            add(t, x, f, pm, pc, cmd, lateness)
            put((next(seq), index, t, x, f, pm, pc, cmd))

        writer.add = tap  # type: ignore[method-assign]

    def run_ended(self, index: int, spec: RunSpec, status: str, message: str) -> None:
        self.events.append(("end", index, status, message))
