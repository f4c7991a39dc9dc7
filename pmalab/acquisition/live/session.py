"""Wiring of ``pmalab run --live``: feed → pump → hub → server, started before the
recording and closed after it (also on an abort)."""

from __future__ import annotations

import sys
from typing import Any

from pmalab.acquisition.live.address import is_loopback
from pmalab.acquisition.live.feed import LiveFeed
from pmalab.acquisition.live.hub import Hub
from pmalab.acquisition.live.margins import Margins
from pmalab.acquisition.live.pump import Pump
from pmalab.acquisition.live.server import LiveServer
from pmalab.acquisition.protocol import Protocol
from pmalab.acquisition.runner import RunnerOptions
from pmalab.acquisition.safety import SafetyMonitor, effective_limits
from pmalab.rig.base import Rig


class LiveSession:
    """The live view of one recording; ``options.observer`` is set to its feed."""

    def __init__(self, rig: Rig, protocol: Protocol, out: str, options: RunnerOptions,
                 host: str, port: int) -> None:
        limits = effective_limits(rig)
        margin = SafetyMonitor(limits).pressure_margin
        self.feed = LiveFeed()
        self.hub = Hub({"mode": "live", "file": str(out), "protocol": protocol.name,
                        "clock": "virtual" if rig.clock.virtual else "real"})
        self.pump = Pump(self.feed, self.hub, protocol, protocol.sample_rate_Hz,
                         Margins.from_limits(limits.__dict__, margin))
        self.options = options
        self.server = LiveServer(self.hub, host, port, on_stop=self._stop)
        options.observer = self.feed
        self.warn_remote = not is_loopback(host) and host not in ("localhost",)

    def _stop(self) -> str:
        self.pump.stop_requested = True
        self.options.request_stop()
        return ("stop requested: the runner vents the regulator and closes the run at its "
                "next sample, keeping the samples")

    def start(self) -> str:
        url = self.server.start()
        self.pump.start()
        note = ("; stop button from 127.0.0.1 only" if self.warn_remote else "")
        print(f"pmalab: live view on {url}{note}", file=sys.stderr, flush=True)
        return url

    def close(self, message: str) -> None:
        """Publish what is left and ``message`` (how the recording ended), then close."""
        self.pump.close()
        self.hub.finish(message)
        self.server.close()

    def __enter__(self) -> LiveSession:
        self.start()
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc is None:
            message = "recording finished"
        else:
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self.close(message)
