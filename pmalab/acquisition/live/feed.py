"""The runner's side of the live view: samples into a shared-memory ring, nothing else.

The live page is served by a separate *process* (:mod:`.process`): a thread in the
recording process would share its interpreter lock with the 500 Hz loop, and a display
thread preempted by the OS while holding it keeps the loop waiting (priority inversion).
So the loop's only extra work is :meth:`RingFeed.run_started`'s tap: after the writer
stores a sample, two ``struct.pack_into`` calls (~1 µs) copy it into a ring in shared
memory and advance the ring's head.  It never blocks and never waits for the reader: a
reader that falls more than :data:`RING_ROWS` samples behind finds its rows overwritten
and counts them as dropped (each row carries its sequence number).

Layout (native byte order): a header of 4 int64 — next sequence number, the run's late
and missed counts, samples recorded in the run — then ``RING_ROWS`` rows of 8 float64:
``(seq, run index, t s, x mm, F N, p_muscle MPa, p_cyl MPa, command MPa)``.
Run starts and ends (a few per run, outside the sample loop) go through a pipe.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pmalab.acquisition.protocol import RunSpec
from pmalab.acquisition.recorder import RECORDED, RunWriter
from pmalab.acquisition.runner import RunObserver

#: samples the ring holds: 16 s at 500 Hz (the reader drains it every 50 ms)
RING_ROWS = 8192
HEADER_BYTES = 64
ROW = struct.Struct("8d")
HEAD = struct.Struct("4q")
N_COLS = 8


def ring_bytes(rows: int = RING_ROWS) -> int:
    return HEADER_BYTES + rows * ROW.size


def run_info(spec: RunSpec, n_runs: int) -> dict[str, Any]:
    """The timeline of a run as the page needs it (s, Hz, MPa)."""
    return {
        "name": spec.name,
        "n_runs": n_runs,
        "role": spec.role,
        "muscle_pressure_MPa": spec.muscle_pressure_MPa,
        "waveform": spec.waveform,
        "frequency_Hz": spec.frequency_Hz,
        "cycles": spec.cycles,
        "settle_s": spec.settle_s,
        "ramp_s": spec.ramp_s,
        "steady_start_s": spec.steady_start_s,
        "steady_end_s": spec.steady_end_s,
        "duration_s": spec.duration_s,
    }


class RingFeed(RunObserver):
    """Writes every recorded sample into ``buf`` (a shared-memory ring); run events go
    to ``send`` (a pipe to the display process; failures are the runner's to ignore)."""

    def __init__(
        self, buf: Any, n_runs: int, send: Callable[[tuple], None], rows: int = RING_ROWS
    ) -> None:
        self.buf = buf
        self.rows = rows
        self.n_runs = n_runs
        self.send = send
        self._next = [0]  # next sequence number (shared by the taps of every run)

    def run_started(self, index: int, spec: RunSpec, writer: RunWriter) -> None:
        append, buf, rows, nxt = writer.append, self.buf, self.rows, self._next
        pack_row, pack_head = ROW.pack_into, HEAD.pack_into
        count = [0]
        if tuple(writer.channels) != RECORDED:
            # the ring's rows are the single-muscle channels; another declaration (a pair
            # of muscles) is recorded as usual and the page shows its run events only
            self.send(("start", index, run_info(spec, self.n_runs)))
            return

        def tap(row: Sequence[float], lateness: float) -> None:
            append(row, lateness)
            s = nxt[0]
            pack_row(buf, HEADER_BYTES + (s % rows) * 64, s, index, *row)
            nxt[0] = s + 1
            count[0] += 1
            pack_head(buf, 0, s + 1, writer.n_late, writer.n_missed, count[0])

        writer.append = tap  # type: ignore[method-assign]
        self.send(("start", index, run_info(spec, self.n_runs)))

    def run_ended(self, index: int, spec: RunSpec, status: str, message: str) -> None:
        self.send(("end", index, status, message))


class RingReader:
    """The display side: what the ring gained since the last :meth:`drain`."""

    def __init__(self, buf: Any, rows: int = RING_ROWS) -> None:
        self.rows = rows
        self._head = np.ndarray((4,), dtype=np.int64, buffer=buf)
        self._data = np.ndarray((rows, N_COLS), dtype=np.float64, buffer=buf, offset=HEADER_BYTES)
        self.next = 0
        self.dropped = 0
        #: (late, missed, samples) of the current run, as of the last drain
        self.counters = (0, 0, 0)

    def drain(self) -> np.ndarray:
        """New rows ``(n, 8)`` in order; rows the writer overwrote are counted as dropped."""
        head = int(self._head[0])
        self.counters = tuple(int(v) for v in self._head[1:4])
        if head <= self.next:
            return np.empty((0, N_COLS))
        start = max(self.next, head - self.rows)
        seqs = np.arange(start, head)
        rows = self._data[seqs % self.rows].copy()
        # rows the writer reached again while we copied (it lapped us) are not trusted
        after = int(self._head[0])
        ok = (rows[:, 0] == seqs) & (seqs >= after - self.rows)
        rows = rows[ok]
        self.dropped += (head - self.next) - len(rows)
        self.next = head
        return rows
