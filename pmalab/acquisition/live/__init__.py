"""Live view: watch a recording (or a run file) in a browser, without touching the loop.

``pmalab run ... --live [HOST:]PORT`` and ``pmalab view FILE.h5`` serve one local page
(``assets/``: the page, its script and the vendored uPlot — no internet needed) showing the
current run's force–position loop building up, force/position/pressures against time,
progress, limit margins, the safety state and late/missed samples, with a stop button.

Data path (see each module): the sample loop's :class:`~.feed.RingFeed` tap copies each
sample into a shared-memory ring (never blocks, never waits; a reader that falls behind
loses the oldest rows, counted) → in a separate display process (:mod:`.process`), the
:class:`~.pump.Pump` thread decimates to ~50 points/s, tracks :mod:`.margins` and encodes
SSE once into the :class:`~.hub.Hub` → one :mod:`.server` thread per browser streams it.
``pmalab view`` replaces ring and pump by a :class:`~.fileview.FileFollower` polling the
(SWMR) file, in the ``view`` process itself.
The runner knows only its :class:`~pmalab.acquisition.runner.RunObserver` interface; this
package is never imported by the recording code (import-linter contract).
"""

from __future__ import annotations

from pmalab.acquisition.live.address import parse_address
from pmalab.acquisition.live.fileview import FileFollower, open_run_file
from pmalab.acquisition.live.hub import Hub
from pmalab.acquisition.live.server import LiveServer
from pmalab.acquisition.live.session import LiveSession

__all__ = ["FileFollower", "Hub", "LiveServer", "LiveSession", "open_run_file", "parse_address"]
