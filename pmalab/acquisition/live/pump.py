"""The display thread of ``pmalab run --live``: drains the :class:`LiveFeed` 20 times a
second, decimates the samples for display, tracks limit margins and publishes to the
:class:`Hub`.  It runs at normal priority beside the SCHED_FIFO sample loop and holds the
GIL for well under a millisecond per pass (a few hundred samples through numpy), less than
the sample loop's spin margin, so the loop's deadlines do not move.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from pmalab.acquisition.live.feed import LiveFeed
from pmalab.acquisition.live.hub import Hub
from pmalab.acquisition.live.margins import Margins
from pmalab.acquisition.protocol import Protocol, RunSpec

#: display rate of the plotted points (Hz): 50 points per cycle at 1 Hz
DISPLAY_HZ = 50.0
#: how often the pump wakes (s): ≥ 10 page updates per second with margin
PUMP_INTERVAL_S = 0.05
#: how often the status (progress, counters, margins) is re-sent (s)
STATUS_INTERVAL_S = 0.2


def run_info(spec: RunSpec, n_runs: int) -> dict[str, Any]:
    """The timeline of a run as the page needs it (s, Hz, MPa)."""
    return {"name": spec.name, "n_runs": n_runs, "role": spec.role,
            "muscle_pressure_MPa": spec.muscle_pressure_MPa, "waveform": spec.waveform,
            "frequency_Hz": spec.frequency_Hz, "cycles": spec.cycles,
            "settle_s": spec.settle_s, "ramp_s": spec.ramp_s,
            "steady_start_s": spec.steady_start_s, "steady_end_s": spec.steady_end_s,
            "duration_s": spec.duration_s}


def decimated_points(rows: np.ndarray, stride: int) -> dict[str, list[float]]:
    """Display points from sample rows ``(seq, run, t, x, f, pm, pc, cmd)``: every
    ``stride``-th sample by sequence number (so consecutive batches stay on one grid)."""
    keep = rows[rows[:, 0] % stride == 0]
    return {"t": np.round(keep[:, 2], 4).tolist(), "x": np.round(keep[:, 3], 3).tolist(),
            "f": np.round(keep[:, 4], 2).tolist(), "pm": np.round(keep[:, 5], 4).tolist(),
            "pc": np.round(keep[:, 6], 4).tolist(), "cmd": np.round(keep[:, 7], 4).tolist()}


def safety_text(status: str, stop_requested: bool) -> dict[str, str]:
    """The page's safety badge for a run status."""
    if status.startswith("aborted"):
        return {"state": "aborted", "text": status}
    if status == "completed":
        return {"state": "completed", "text": "completed; regulator commanded to 0 MPa"}
    if stop_requested:
        return {"state": "stopping", "text": "stop requested: the runner vents and closes "
                "the run at its next sample"}
    if status == "waiting":
        return {"state": "waiting", "text": "waiting for the muscle pressure to settle"}
    return {"state": "ok", "text": "within limits"}


class Pump(threading.Thread):
    """Feed → hub, every :data:`PUMP_INTERVAL_S`."""

    def __init__(self, feed: LiveFeed, hub: Hub, protocol: Protocol, rate_Hz: float,
                 margins: Margins | None) -> None:
        super().__init__(name="pmalab-live-pump", daemon=True)
        self.feed, self.hub, self.protocol = feed, hub, protocol
        self.stride = max(1, round(rate_Hz / DISPLAY_HZ))
        self.margins = margins
        self.stop_requested = False
        self.dropped = 0
        self._last_seq = -1
        self._quit = threading.Event()
        self._writer: Any = None
        self._index = -1
        self._status = "waiting"
        self._message = ""
        self._t = 0.0
        self._before = [0.0]  # protocol time before each run (s)
        for r in protocol.runs:
            self._before.append(self._before[-1] + r.duration_s)

    def close(self) -> None:
        """Drain what is left, publish a last status and stop the thread."""
        self._quit.set()
        if self.is_alive():
            self.join(timeout=2.0)
        self.pump()

    def run(self) -> None:
        next_status = 0.0
        clock = 0.0
        while not self._quit.wait(PUMP_INTERVAL_S):
            clock += PUMP_INTERVAL_S
            changed = self.pump(publish_status=clock >= next_status)
            if changed or clock >= next_status:
                next_status = clock + STATUS_INTERVAL_S

    def pump(self, publish_status: bool = True) -> bool:
        """One pass; True when a run started or ended (status published at once)."""
        q = self.feed.samples
        batch = [q.popleft() for _ in range(len(q))]
        ev = self.feed.events
        events = [ev.popleft() for _ in range(len(ev))]
        n_runs = len(self.protocol.runs)
        changed = False
        for e in events:
            if e[0] == "start":
                _, index, spec, writer = e
                self.hub.start_run(index, run_info(spec, n_runs))
                self._writer, self._index, self._status = writer, index, "waiting"
                self._message, self._t = "", 0.0
                if self.margins is not None:
                    self.margins.reset()
                changed = True
        if batch:
            rows = np.asarray(batch, dtype=np.float64)
            seq = rows[:, 0].astype(np.int64)
            gaps = np.diff(seq, prepend=self._last_seq) - 1
            self.dropped += int(gaps.sum())
            self._last_seq = int(seq[-1])
            for index in np.unique(rows[:, 1]).astype(int).tolist():
                part = rows[rows[:, 1] == index]
                self.hub.add_points(index, decimated_points(part, self.stride))
                if index == self._index:
                    if self._status == "waiting":
                        self._status = "recording"
                    self._t = float(part[-1, 2])
                    if self.margins is not None:
                        self.margins.update(part[:, 3], part[:, 4], part[:, 5], part[:, 6])
        for e in events:
            if e[0] == "end":
                _, index, status, message = e
                self.hub.end_run(index, status)
                if index == self._index:
                    self._status, self._message = status, message
                changed = True
        if publish_status or changed:
            self.hub.set_status(self.status())
        return changed

    def status(self) -> dict[str, Any]:
        """Progress, counters, margins and the safety state of the current run."""
        runs = self.protocol.runs
        i = self._index
        w = self._writer
        out: dict[str, Any] = {"index": i, "n_runs": len(runs), "dropped": self.dropped,
                               "stride": self.stride, "stop_requested": self.stop_requested}
        if i < 0:
            out["safety"] = {"state": "waiting", "text": "starting"}
            return out
        spec = runs[i]
        total = self._before[-1] or 1.0
        out.update({
            "run": spec.name, "t": self._t, "duration_s": spec.duration_s,
            "progress_run": min(1.0, self._t / spec.duration_s) if spec.duration_s else 0.0,
            "progress_protocol": min(1.0, (self._before[i] + self._t) / total),
            "samples": int(w.n + w.buffered) if w is not None else 0,
            "late": int(getattr(w, "n_late", 0)), "missed": int(getattr(w, "n_missed", 0)),
            "phase": self._status, "message": self._message,
            "safety": safety_text(self._status, self.stop_requested),
            "margins": self.margins.rows() if self.margins is not None else [],
        })
        return out
