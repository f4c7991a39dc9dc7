"""The display process's pump: drains the shared-memory ring (:class:`.feed.RingReader`)
20 times a second, decimates the samples for display, tracks the limit margins and
publishes to the :class:`Hub`; run starts and ends arrive in :attr:`Pump.events` (filled
from the pipe by :mod:`.process`).
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Any

import numpy as np

from pmalab.acquisition.live.feed import RingReader
from pmalab.acquisition.live.hub import Hub
from pmalab.acquisition.live.margins import Margins

#: display rate of the plotted points (Hz): 50 points per cycle at 1 Hz
DISPLAY_HZ = 50.0
#: how often the pump wakes (s): ≥ 10 page updates per second with margin
PUMP_INTERVAL_S = 0.05
#: how often the status (progress, counters, margins) is re-sent (s)
STATUS_INTERVAL_S = 0.2


def decimated_points(rows: np.ndarray, stride: int) -> dict[str, list[float]]:
    """Display points from sample rows ``(seq, run, t, x, f, pm, pc, cmd)``: every
    ``stride``-th sample by sequence number (so consecutive batches stay on one grid)."""
    keep = rows[rows[:, 0] % stride == 0]
    return {
        "t": np.round(keep[:, 2], 4).tolist(),
        "x": np.round(keep[:, 3], 3).tolist(),
        "f": np.round(keep[:, 4], 2).tolist(),
        "pm": np.round(keep[:, 5], 4).tolist(),
        "pc": np.round(keep[:, 6], 4).tolist(),
        "cmd": np.round(keep[:, 7], 4).tolist(),
    }


def safety_text(status: str, stop_requested: bool) -> dict[str, str]:
    """The page's safety badge for a run status."""
    if status.startswith("aborted"):
        return {"state": "aborted", "text": status}
    if status == "completed":
        return {"state": "completed", "text": "run completed"}
    if stop_requested:
        return {
            "state": "stopping",
            "text": "stop requested: the runner vents and closes the run at its next sample",
        }
    if status == "waiting":
        return {"state": "waiting", "text": "waiting for the muscle pressure to settle"}
    return {"state": "ok", "text": "within limits"}


class Pump(threading.Thread):
    """Ring + events → hub, every :data:`PUMP_INTERVAL_S`.

    ``durations`` are the protocol's run durations (s), for the progress bars.
    """

    def __init__(
        self,
        reader: RingReader,
        hub: Hub,
        durations: list[float],
        rate_Hz: float,
        margins: Margins | None,
    ) -> None:
        super().__init__(name="pmalab-live-pump", daemon=True)
        self.reader, self.hub = reader, hub
        self.events: deque[tuple[Any, ...]] = deque()
        self.durations = list(durations)
        self.stride = max(1, round(rate_Hz / DISPLAY_HZ))
        self.margins = margins
        self.stop_requested = False
        self._quit = threading.Event()
        self._index = -1
        self._info: dict[str, Any] = {}
        self._status = "waiting"
        self._message = ""
        self._t = 0.0
        self._before = [0.0]  # protocol time before each run (s)
        for d in self.durations:
            self._before.append(self._before[-1] + d)

    def close(self) -> None:
        """Stop the thread, then drain what is left and publish a last status."""
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
        """One pass; True when a run started or ended (status published at once).

        The ring is drained before the events: a sample of a run implies its start event
        was sent before it, so every drained sample's run is known; an end event may come
        before the run's last samples are drained (they are still added to that run)."""
        rows = self.reader.drain()
        ev = self.events
        events = [ev.popleft() for _ in range(len(ev))]
        changed = False
        for e in events:
            if e[0] == "start":
                _, index, info = e
                self.hub.start_run(index, info)
                self._index, self._info, self._status = index, info, "waiting"
                self._message, self._t = "", 0.0
                if self.margins is not None:
                    self.margins.reset()
                changed = True
        if len(rows):
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
        i = self._index
        late, missed, samples = self.reader.counters
        out: dict[str, Any] = {
            "index": i,
            "n_runs": len(self.durations),
            "dropped": self.reader.dropped,
            "stride": self.stride,
            "stop_requested": self.stop_requested,
        }
        if i < 0:
            out["safety"] = {"state": "waiting", "text": "starting"}
            return out
        dur = self.durations[i]
        total = self._before[-1] or 1.0
        out.update(
            {
                "run": self._info.get("name", str(i)),
                "t": round(self._t, 3),
                "duration_s": dur,
                "progress_run": min(1.0, self._t / dur) if dur else 0.0,
                "progress_protocol": min(1.0, (self._before[i] + self._t) / total),
                # the ring's counters are the last tapped run's until this one records
                **(
                    {"samples": 0, "late": 0, "missed": 0}
                    if self._status == "waiting"
                    else {"samples": samples, "late": late, "missed": missed}
                ),
                "phase": self._status,
                "message": self._message,
                "safety": safety_text(self._status, self.stop_requested),
                "margins": self.margins.rows() if self.margins is not None else [],
            }
        )
        return out
