"""Live view: page update rate with 2 clients, and the 500 Hz loop's lateness with --live vs without.

A real-time sine run on the simulated rig (RealClock, the runner's SCHED_FIFO scheduling)
of ``PMALAB_BENCH_LIVE_SECONDS`` (default 12) s is recorded without the live view and with
it and two clients connected, in ``PMALAB_BENCH_LIVE_REPS`` (default 4) interleaved pairs
(the first of each pair alternates), so both modes see the same background load of a
shared machine.  Clients (``PMALAB_BENCH_LIVE_CLIENTS``): ``sse`` (default) — two separate
processes reading the event stream as a browser does, counting page updates (``points``
events) per second and the longest gap; ``chromium`` — two headless Chromium pages of the
real page, counting its redraws while points flowed (``pmalabStats.pointDraws``).
Lateness (actual − scheduled time of each sample, the runner's ``lateness`` dataset) is
pooled over the pairs of each mode; on a busy machine the p99 is set by the other
processes as much as by pmalab, so look at the per-pair values too.  Goals: ≥ 10 updates/s
per client; p99 lateness with --live ≤ 1.1 × without.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

from bench.bench_acquisition import sine_protocol
from bench.table import print_table
from pmalab.acquisition.live.session import LiveSession
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.rig.base import RealClock
from pmalab.rig.loader import load_rig

# one browser's worth of reading: update times of the "points" events until "end"
SSE_CLIENT = r"""
import http.client, json, sys, time
port, limit = int(sys.argv[1]), float(sys.argv[2])
c = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
c.request("GET", "/events")
r = c.getresponse()
times, points, ev = [], 0, b""
print("connected", flush=True)
deadline = time.monotonic() + limit
while time.monotonic() < deadline:
    line = r.fp.readline()
    if not line:
        break
    if line.startswith(b"event: "):
        ev = line[7:].strip()
    elif line.startswith(b"data: ") and ev == b"points":
        times.append(time.monotonic())
        points += len(json.loads(line[6:])["t"])
    elif line.startswith(b"data: ") and ev == b"end":
        break
print(json.dumps({"times": times, "points": points}), flush=True)
"""


def _protocol(seconds: float):
    return sine_protocol(seconds, "live-bench")


def _lateness(out: Path) -> np.ndarray:
    with h5py.File(out, "r") as f:
        return np.asarray(f["runs/live-bench/lateness"][()], dtype=np.float64)


def _sse_clients(port: int, seconds: float) -> list[subprocess.Popen]:
    procs = [subprocess.Popen([sys.executable, "-c", SSE_CLIENT, str(port), str(seconds + 60)],
                              stdout=subprocess.PIPE, text=True) for _ in range(2)]
    for p in procs:  # both connected before the recording starts
        assert p.stdout.readline().strip() == "connected"
    return procs


def _sse_rates(clients: list[subprocess.Popen]) -> list[tuple[float, float, int]]:
    """Per client: updates per second while points arrived, longest gap (s), points."""
    out = []
    for p in clients:
        res = json.loads(p.communicate(timeout=120)[0].strip().splitlines()[-1])
        t = np.asarray(res["times"])
        # the first second holds the replay of what came before the client connected
        t = t[t > t[0] + 1.0] if len(t) > 2 else t
        rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 2 else 0.0
        gap = float(np.max(np.diff(t))) if len(t) > 2 else float("nan")
        out.append((rate, gap, int(res["points"])))
    return out


class _Browsers:
    """Two headless Chromium pages of the live page (via the tests' CDP helper)."""

    def __init__(self, url: str) -> None:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
        from cdp import Browser, chromium

        exe = chromium()
        if exe is None:
            raise SystemExit("PMALAB_BENCH_LIVE_CLIENTS=chromium: no Chromium found")
        self.pages = [Browser(exe, 1400, 1000) for _ in range(2)]
        for b in self.pages:
            b.navigate(url)

    def start(self) -> None:
        for b in self.pages:
            b.wait_for("window.pmalabStats !== undefined && "
                       "document.getElementById('conn').textContent === 'connected'", 60,
                       "the page connected")

    def rates(self) -> list[tuple[float, float, int]]:
        """Redraws per second of each page while the points flowed (first to last draw)."""
        out = []
        for b in self.pages:
            s = b.evaluate("({n: pmalabStats.pointDraws, a: pmalabStats.firstDrawAt, "
                           "z: pmalabStats.lastDrawAt, p: pmalabStats.points})")
            rate = (s["n"] - 1) / ((s["z"] - s["a"]) / 1e3) if (s["n"] or 0) > 1 else 0.0
            out.append((rate, float("nan"), int(s["p"])))
            b.close()
        return out


def _record(seconds: float, out: Path, live: bool, clients: str) -> tuple[np.ndarray, list]:
    rig = load_rig("sim", seed=2, clock=RealClock())
    opts = RunnerOptions(progress=False)
    proto = _protocol(seconds)
    with rig:
        if not live:
            run_protocol(rig, proto, out, force=True, options=opts)
            return _lateness(out), []
        session = LiveSession(rig, proto, str(out), opts, "127.0.0.1", 0)
        with session:
            if clients == "chromium":
                browsers = _Browsers(session.url)
            else:
                procs = _sse_clients(int(session.url.rsplit(":", 1)[1].strip("/")), seconds)
            try:
                if clients == "chromium":
                    browsers.start()
                run_protocol(rig, proto, out, force=True, options=opts)
            finally:
                if clients == "chromium":
                    rates = browsers.rates()
        if clients != "chromium":
            rates = _sse_rates(procs)
    return _lateness(out), rates


def _tap_cost() -> tuple[float, float]:
    """µs per sample of the writer's ``add`` alone and with the live tap (ring copy), in
    the recording process: the only work --live adds to the sample loop."""
    import timeit

    from pmalab.acquisition.live.feed import RingFeed, ring_bytes
    from pmalab.acquisition.recorder import RunWriter

    class Plain:  # RunWriter.add's work without the file
        add = RunWriter.add

        def __init__(self):
            self._buf = [[] for _ in range(6)]
            self._late_buf = []
            self.n_late = self.n_missed = 0

    n = 200_000
    plain = Plain()
    t_plain = timeit.timeit(lambda: plain.add(1.0, 2.0, 3.0, 0.4, 0.2, 0.2, 1e-5), number=n)
    tapped = Plain()
    RingFeed(bytearray(ring_bytes()), 1, lambda m: None).run_started(0, _protocol(5).runs[0],
                                                                      tapped)
    t_tap = timeit.timeit(lambda: tapped.add(1.0, 2.0, 3.0, 0.4, 0.2, 0.2, 1e-5), number=n)
    return t_plain / n * 1e6, t_tap / n * 1e6


def main() -> None:
    seconds = float(os.environ.get("PMALAB_BENCH_LIVE_SECONDS", "12"))
    reps = int(os.environ.get("PMALAB_BENCH_LIVE_REPS", "4"))
    clients = os.environ.get("PMALAB_BENCH_LIVE_CLIENTS", "sse")
    pooled: dict[bool, list[np.ndarray]] = {False: [], True: []}
    rates: list[tuple[float, float, int]] = []
    tmp = Path(tempfile.mkdtemp(prefix="pmalab-bench-live-"))
    try:
        for rep in range(reps):
            for live in ((False, True) if rep % 2 == 0 else (True, False)):
                lat, r = _record(seconds, tmp / f"{rep}-{live}.h5", live, clients)
                pooled[live].append(lat)
                rates += r
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    rows = []
    p99 = {}
    for live in (False, True):
        lat = np.concatenate(pooled[live])
        p50, p99[live], pmax = (float(v) * 1e3 for v in np.percentile(lat, [50, 99, 100]))
        per_rep = " ".join(f"{np.percentile(x, 99) * 1e3:.3f}" for x in pooled[live])
        rows.append(["with --live, 2 clients" if live else "without --live", len(lat),
                     f"{p50:.3f}", f"{p99[live]:.3f}", per_rep, f"{pmax:.2f}",
                     int(np.sum(lat > 0.5e-3))])
    print_table(["sim rig, real time", "samples", "p50 ms", "p99 ms", "p99 per pair ms",
                 "max ms", "late>0.5ms"], rows)
    ratio = p99[True] / p99[False] if p99[False] > 0 else float("nan")
    med = {live: float(np.median([np.percentile(x, 99) for x in pooled[live]]))
           for live in (False, True)}
    print(f"   lateness p99 ratio (with / without --live): pooled {ratio:.2f}, median of the "
          f"pairs {med[True] / med[False] if med[False] > 0 else float('nan'):.2f}   "
          "goal ≤ 1.10")
    rows = [[f"client {i % 2 + 1}" + (f" (pair {i // 2 + 1})" if reps > 1 else ""),
             f"{r:.1f}", "-" if g != g else f"{g * 1e3:.0f}", n]
            for i, (r, g, n) in enumerate(rates)]
    print_table([f"{clients} client", "updates/s", "longest gap ms", "points received"], rows)
    print(f"   slowest client: {min(r for r, _, _ in rates):.1f} updates/s   goal ≥ 10")
    plain, tapped = _tap_cost()
    print(f"   per-sample work --live adds to the loop: writer.add {plain:.2f} µs -> with the "
          f"ring tap {tapped:.2f} µs (+{tapped - plain:.2f} µs of the 2000 µs period)")


if __name__ == "__main__":
    main()
