"""The display process of ``pmalab run --live``: pump, hub and web server, apart from
the recording process so that nothing the page does can hold the recording's
interpreter lock.

The parent (:class:`DisplayProcess`) creates the ring — a file in ``/dev/shm`` (memory,
where it exists) mapped by both processes — and starts ``python -m
pmalab.acquisition.live.display RING CONFIG`` (a fresh interpreter: nothing of the
recorder is copied or re-imported).  The child maps the ring, binds its server and
writes ``ready PORT`` (or ``error MESSAGE``) on its stdout; the parent then unlinks the
ring file (the mappings stay; nothing is left behind even after ``kill -9``).  After that
the parent writes run events as JSON lines to the child's stdin (a few per run, then
``finish``), and the child writes ``stop`` on its stdout for each STOP press, read by a
parent thread that sleeps in ``readline`` (no interpreter lock held) until then.  If the
recorder dies, the child sees its stdin close and exits; if the child dies, the
recorder's tap keeps writing into the ring and nobody reads it.
"""

from __future__ import annotations

import contextlib
import json
import mmap
import os
import select
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pmalab.errors import ConfigError

#: how long the parent waits for the display process to listen (s)
START_TIMEOUT_S = 60.0


def _say(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def child_main(ring_path: str, config: dict[str, Any]) -> int:
    """Entry point of the display process."""
    from pmalab.acquisition.live.feed import RingReader, ring_bytes
    from pmalab.acquisition.live.hub import Hub
    from pmalab.acquisition.live.margins import Margins
    from pmalab.acquisition.live.pump import Pump
    from pmalab.acquisition.live.server import LiveServer

    rows = int(config["rows"])
    with open(ring_path, "r+b") as fh:
        ring = mmap.mmap(fh.fileno(), ring_bytes(rows))
    hub = Hub(config["hello"])
    pump = Pump(
        RingReader(ring, rows),
        hub,
        config["durations"],
        config["rate_Hz"],
        Margins.from_limits(config["limits"], config["pressure_margin"]),
    )
    lock = threading.Lock()

    def on_stop() -> str:
        pump.stop_requested = True
        with lock:
            _say("stop")
        return (
            "stop requested: the runner vents the regulator and closes the run at its "
            "next sample, keeping the samples"
        )

    try:
        server = LiveServer(hub, config["host"], config["port"], on_stop=on_stop)
    except ConfigError as exc:
        _say("error " + str(exc))
        return 1
    server.start()
    pump.start()
    with lock:
        _say(f"ready {server.port}")
    message = "the recording process is gone"
    for line in sys.stdin:
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            continue
        if msg[0] == "finish":
            message = msg[1]
            break
        pump.events.append(tuple(msg))
    pump.close()
    hub.finish(message)
    server.close()
    return 0


def _ring_dir() -> str | None:
    """``/dev/shm`` where it exists (memory), else the temporary directory."""
    shm = Path("/dev/shm")
    return str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None


class DisplayProcess:
    """Parent side: the ring, the pipes and the child process."""

    def __init__(self, config: dict[str, Any], rows: int, on_stop: Callable[[], None]) -> None:
        from pmalab.acquisition.live.feed import ring_bytes

        size = ring_bytes(rows)
        fd, self._ring_path = tempfile.mkstemp(
            prefix="pmalab-live-", suffix=".ring", dir=_ring_dir()
        )
        try:
            os.ftruncate(fd, size)
            self.ring = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        self.config = {**config, "rows": rows}
        self.on_stop = on_stop
        self.proc: subprocess.Popen | None = None
        self.port: int | None = None
        self.lost_events = 0
        self._watcher: threading.Thread | None = None

    def start(self) -> int:
        """Start the child; return its port, or raise ConfigError (one line) when it
        cannot serve."""
        import pmalab

        env = dict(os.environ)
        root = str(Path(pmalab.__file__).resolve().parents[1])  # this pmalab, also uninstalled
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        try:
            self.proc = proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "pmalab.acquisition.live.display",
                    self._ring_path,
                    json.dumps(self.config),
                ],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                env=env,
            )
            assert proc.stdin is not None and proc.stdout is not None  # both are PIPEs
            ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT_S)
            line = proc.stdout.readline().decode(errors="replace").strip() if ready else ""
        finally:
            with contextlib.suppress(OSError):
                os.unlink(self._ring_path)  # both processes have it mapped now (or never will)
        kind, _, rest = line.partition(" ")
        if kind != "ready":
            self.close("")
            why = (
                rest
                if kind == "error"
                else (
                    "the live view did not start"
                    + (f" within {START_TIMEOUT_S:g} s" if not line else f" ({line})")
                )
            )
            raise ConfigError(why)
        self.port = int(rest)
        os.set_blocking(proc.stdin.fileno(), False)
        self._watcher = threading.Thread(
            target=self._watch, name="pmalab-live-control", daemon=True
        )
        self._watcher.start()
        return self.port

    def _watch(self) -> None:
        """Turn each ``stop`` from the page into the runner's stop request."""
        assert self.proc is not None and self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.strip() == b"stop":
                self.on_stop()

    def send(self, msg: tuple) -> None:
        """A run event to the page, never blocking the runner: the pipe is non-blocking
        and a line is at most ``PIPE_BUF`` bytes (written whole or not at all), so a
        display process that stopped reading loses the event (counted), not the run."""
        if self.proc is None or self.proc.stdin is None:
            return
        line = json.dumps(msg).encode() + b"\n"
        if len(line) > select.PIPE_BUF:
            short = tuple(m[:200] if isinstance(m, str) else m for m in msg)
            line = json.dumps(short).encode()[: select.PIPE_BUF - 1] + b"\n"
        try:
            os.write(self.proc.stdin.fileno(), line)
        except BlockingIOError:
            self.lost_events += 1

    def close(self, message: str, timeout_s: float = 3.0) -> None:
        """Tell the page how the recording ended, let it deliver that, and stop."""
        proc = self.proc
        if proc is not None:
            lost, deadline = self.lost_events, time.monotonic() + 1.0
            with contextlib.suppress(Exception):
                self.send(("finish", message))
                while self.lost_events > lost and time.monotonic() < deadline:
                    time.sleep(0.05)  # the last line may wait a moment for room
                    lost = self.lost_events
                    self.send(("finish", message))
            with contextlib.suppress(Exception):
                if proc.stdin is not None:
                    proc.stdin.close()
            try:
                proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                proc.terminate()
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(2.0)
            if self._watcher is not None:
                self._watcher.join(1.0)
            with contextlib.suppress(Exception):
                if proc.stdout is not None:
                    proc.stdout.close()
        with contextlib.suppress(OSError):
            os.unlink(self._ring_path)
