"""What the page shows, held once for every connected browser, as ready-made SSE text.

Producers (the live pump, or the file follower of ``pmalab view``) call
:meth:`Hub.start_run`, :meth:`Hub.add_points`, :meth:`Hub.end_run`, :meth:`Hub.set_status`
and :meth:`Hub.finish`; each encodes its JSON once.  Every browser's SSE thread keeps a
:class:`Cursor` and asks :meth:`Hub.updates` for the bytes it has not sent yet, so a browser
that connects late receives the current run's points so far, and a slow or vanished one
only ever holds up its own thread.

Events (``event:`` name, ``data:`` JSON):

* ``hello`` — mode (``live`` | ``view``), source file, protocol, run list, whether this
  client may stop the run;
* ``run`` — the run now shown: name, index, timeline (settle, steady window, frequency,
  cycles, duration), status;
* ``points`` — decimated samples of that run: ``t`` s from the run's start, ``x`` mm
  (contraction), ``f`` N (tension), ``pm``/``pc``/``cmd`` MPa (muscle, cylinder, command);
* ``status`` — progress, late/missed/dropped counts, limit margins, safety state (~5 Hz);
* ``end`` — the source is finished (the recording ended; the server is about to close).
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field
from typing import Any


def sse(event: str, payload: Any) -> bytes:
    """One Server-Sent Event (compact JSON; never contains a newline)."""
    text = json.dumps(payload, separators=(",", ":"), allow_nan=False)
    return f"event: {event}\ndata: {text}\n\n".encode()


@dataclass
class RunHistory:
    """One run's encoded ``points`` frames and its description."""

    index: int
    info: dict[str, Any]
    frames: list[bytes] = field(default_factory=list)
    n_points: int = 0
    status: str = "waiting"


@dataclass
class Cursor:
    """How far one browser has got: ``follow`` the newest run, or stay on ``run``."""

    follow: bool = True
    run: int = -1
    sent_run: int = -2
    frame: int = 0
    status_version: int = -1
    ended: bool = False


class Hub:
    """Thread-safe store of runs, status and the end flag, with a change condition."""

    def __init__(self, hello: dict[str, Any]) -> None:
        self.hello = dict(hello)
        self.runs: dict[int, RunHistory] = {}
        self.current = -1
        self.cond = threading.Condition()
        self.version = 0
        self._status = b""
        self._status_version = 0
        self.end_message: str | None = None
        #: browsers connected now (event streams open)
        self.clients = 0

    # ----------------------------------------------------------------- producers
    def _changed(self) -> None:
        self.version += 1
        self.cond.notify_all()

    def start_run(self, index: int, info: dict[str, Any], status: str = "waiting") -> None:
        with self.cond:
            self.runs[index] = RunHistory(index, dict(info), status=status)
            self.current = max(self.current, index)
            self._changed()

    def add_points(self, index: int, points: dict[str, list[float]]) -> None:
        """Append decimated points (equal-length lists ``t x f pm pc cmd``) to a run."""
        n = len(points.get("t", ()))
        if not n:
            return
        frame = sse("points", {"run": index, **points})
        with self.cond:
            run = self.runs.get(index)
            if run is None:
                return
            run.frames.append(frame)
            run.n_points += n
            if run.status == "waiting":
                run.status = "recording"
            self._changed()

    def end_run(self, index: int, status: str) -> None:
        with self.cond:
            run = self.runs.get(index)
            if run is not None:
                run.status = status
                self._changed()

    def set_status(self, status: dict[str, Any]) -> None:
        frame = sse("status", status)
        with self.cond:
            self._status = frame
            self._status_version += 1
            self._changed()

    def finish(self, message: str) -> None:
        """The source is done (recording ended, file complete): tell every browser."""
        with self.cond:
            self.end_message = message
            self._changed()

    # ----------------------------------------------------------------- consumers
    def hello_for(self, stop_allowed: bool) -> bytes:
        with self.cond:
            runs = [
                {"index": r.index, "name": r.info.get("name", str(r.index)), "status": r.status}
                for r in self.runs.values()
            ]
            return sse("hello", {**self.hello, "stop_allowed": stop_allowed, "runs": runs})

    def wait(self, seen_version: int, timeout: float) -> int:
        """Block this (browser's) thread until something changed or ``timeout`` s."""
        with self.cond:
            self.cond.wait_for(lambda: self.version != seen_version, timeout)
            return self.version

    def updates(self, cur: Cursor) -> bytes:
        """Everything ``cur`` has not sent yet (possibly b""), and advance it."""
        out: list[bytes] = []
        with self.cond:
            target = self.current if cur.follow else cur.run
            run = self.runs.get(target)
            if run is not None and target != cur.sent_run:
                out.append(sse("run", {"index": run.index, **run.info, "status": run.status}))
                cur.run, cur.sent_run, cur.frame = target, target, 0
            run = self.runs.get(cur.run)
            if run is not None and cur.frame < len(run.frames):
                out.extend(run.frames[cur.frame :])
                cur.frame = len(run.frames)
            if self._status and cur.status_version != self._status_version:
                out.append(self._status)
                cur.status_version = self._status_version
            if self.end_message is not None and not cur.ended:
                out.append(sse("end", {"message": self.end_message}))
                cur.ended = True
        return b"".join(out)
