"""Wiring of ``pmalab run --live``: the recording process writes samples into a
shared-memory ring (:class:`~.feed.RingFeed`, the runner's observer); a separate display
process (:mod:`.process`) serves the page.  Started before the recording (a port that
cannot be served stops everything before anything moves) and closed after it (also on an
abort, telling the page how the recording ended)."""

from __future__ import annotations

import sys
from typing import Any

from pmalab.acquisition.live.address import is_loopback
from pmalab.acquisition.live.feed import RING_ROWS, RingFeed
from pmalab.acquisition.live.process import DisplayProcess
from pmalab.acquisition.protocol import Protocol
from pmalab.acquisition.runner import RunnerOptions
from pmalab.acquisition.safety import SafetyMonitor, effective_limits
from pmalab.rig.base import Rig


class LiveSession:
    """The live view of one recording; ``options.observer`` is set to its feed."""

    def __init__(
        self,
        rig: Rig,
        protocol: Protocol,
        out: str,
        options: RunnerOptions,
        host: str,
        port: int,
        rows: int = RING_ROWS,
    ) -> None:
        limits = effective_limits(rig)
        config = {
            "hello": {
                "mode": "live",
                "file": str(out),
                "protocol": protocol.name,
                "clock": "virtual" if rig.clock.virtual else "real",
            },
            "durations": [r.duration_s for r in protocol.runs],
            "rate_Hz": protocol.sample_rate_Hz,
            "limits": dict(limits.__dict__),
            "pressure_margin": SafetyMonitor(limits).pressure_margin,
            "host": host,
            "port": port,
        }
        self.options = options
        self.display = DisplayProcess(config, rows, on_stop=options.request_stop)
        self.feed = RingFeed(self.display.ring, len(protocol.runs), self.display.send, rows)
        self.host = host
        self.url = ""

    def start(self) -> str:
        from pmalab.acquisition.live.address import url_host

        port = self.display.start()
        self.options.observer = self.feed
        self.url = f"http://{url_host(self.host)}:{port}/"
        remote = not is_loopback(self.host) and self.host != "localhost"
        note = "; stop button from 127.0.0.1 only" if remote else ""
        print(f"pmalab: live view on {self.url}{note}", file=sys.stderr, flush=True)
        return self.url

    def close(self, message: str) -> None:
        """Tell the page how the recording ended (``message``), then stop serving."""
        if self.options.observer is self.feed:
            self.options.observer = None
        self.display.close(message)

    def __enter__(self) -> LiveSession:
        try:
            self.start()
        except BaseException:
            self.display.close("")
            raise
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc is None:
            message = "recording finished"
        else:
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self.close(message)
