"""Load-cell indicator (weighing-terminal style) streaming ASCII weight lines over RS-232C.

Each line is ``H1,H2,±VVVVV.VVUU`` + CR LF, e.g. ``ST,GS,+0012.34kg``:

* H1 — ``ST`` stable, ``US`` unstable (still settling), ``OL`` overload (value meaningless);
* H2 — ``GS`` gross, ``NT`` net (after the indicator's own tare);
* value with sign, then the unit: ``kg`` (converted with g₀ = 9.80665 m/s²) or ``N``.

Such indicators stream 10–80 lines/s (HX711-class converters), far below a 500 Hz loop, so
:class:`LoadCellIndicator` reads the stream on a thread and keeps the newest reading; the
sampler samples that (a zero-order hold — the recorded force is then stepwise, and the rig
info says so).  Sign: the indicator shows tension as positive (force = tension in N).

Faults: an unparsable line is counted (``bad_frames``) and skipped; no line for
``stale_after_s`` → :class:`RigError` (disconnected indicator); an ``OL`` line →
:class:`RigError` at the next reading even if a normal line followed it (overload is a
safety event, latched: the runner vents and aborts).
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass

from pmalab.errors import RigError
from pmalab.rig.drivers.adapters import Adapter, TransportClosed, TransportError, TransportTimeout
from pmalab.rig.drivers.modbus_link import LinkStats, one_line

G0 = 9.80665  # standard gravity, N per kgf
LINE_RE = re.compile(r"^(ST|US|OL),(GS|NT),([+-]\s*[0-9]*\.?[0-9]+)\s*(kg|N)$")


@dataclass(frozen=True)
class WeightReading:
    """One parsed line: force in N (tension positive) and the indicator's flags."""

    force_N: float
    stable: bool
    overload: bool
    net: bool
    received_at: float  # time.perf_counter() when the line arrived


def parse_line(line: bytes, received_at: float = 0.0) -> WeightReading:
    """Parse one weight line; raise ``ValueError`` for a garbled one."""
    text = line.decode("ascii").strip()
    if text.startswith("OL,"):  # overload lines carry no usable number on many indicators
        net = text[3:5] == "NT"
        return WeightReading(float("nan"), False, True, net, received_at)
    m = LINE_RE.match(text)
    if m is None:
        raise ValueError(f"not a weight line: {text!r}")
    h1, h2, number, unit = m.groups()
    value = float(number.replace(" ", ""))
    force = value * G0 if unit == "kg" else value
    return WeightReading(force, h1 == "ST", False, h2 == "NT", received_at)


class LoadCellIndicator:
    """Reads the indicator's stream on a thread; :meth:`force` returns the newest value."""

    def __init__(
        self, adapter: Adapter, stale_after_s: float = 0.5, name: str = "load-cell indicator"
    ) -> None:
        self.adapter = adapter
        self.stale_after_s = float(stale_after_s)
        self.name = name
        self.stats = LinkStats()
        self.lines = 0
        self.latest: WeightReading | None = None
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._error: str | None = None
        self._t_first: float | None = None
        self._overload_latched = False

    def connect(self, wait_s: float = 1.0) -> None:
        """Open the port, start reading, and wait for a first valid line (one clear line if none)."""
        try:
            self.adapter.open()
        except (OSError, TransportError) as exc:
            raise RigError(
                f"{self.name} {self.adapter.name}: cannot open ({one_line(exc)})"
            ) from exc
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="loadcell-reader", daemon=True)
        self._thread.start()
        deadline = time.perf_counter() + wait_s
        while time.perf_counter() < deadline:
            if self.latest is not None:
                return
            time.sleep(0.005)
        self.close()
        raise RigError(
            f"{self.name} {self.adapter.name}: no weight line within {wait_s} s (wrong port or baud rate?)"
        )

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                if not self.adapter.is_open:
                    self.adapter.open()
                    self.stats.reconnects += 1
                raw = self.adapter.read_until(b"\n", 0.1)
            except TransportTimeout:
                continue
            except (TransportClosed, OSError) as exc:
                self.stats.disconnects += 1
                self.adapter.close()
                self._error = one_line(exc)
                time.sleep(0.05)
                continue
            except TransportError as exc:
                self.stats.count(exc)
                continue
            now = time.perf_counter()
            try:
                reading = parse_line(raw, now)
            except (ValueError, UnicodeDecodeError):
                self.stats.bad_frames += 1
                continue
            with self._lock:
                self.latest = reading
                self.lines += 1
                if reading.overload:
                    self._overload_latched = True  # even one OL line between two samples
                if self._t_first is None:
                    self._t_first = now

    def reading(self) -> WeightReading:
        """The newest reading; RigError when it is stale or an overload."""
        with self._lock:
            r = self.latest
            overload, self._overload_latched = self._overload_latched, False
        now = time.perf_counter()
        if r is None or now - r.received_at > self.stale_after_s:
            self.stats.timeouts += 1
            self.stats.failures += 1
            extra = f" ({self._error})" if self._error else ""
            raise RigError(
                f"{self.name} {self.adapter.name}: no weight line for more than {self.stale_after_s} s{extra}"
            )
        if overload or r.overload:
            self.stats.out_of_range += 1
            self.stats.failures += 1
            raise RigError(f"{self.name} {self.adapter.name}: load cell OVERLOAD")
        return r

    def force(self) -> float:
        """Newest force reading, N (tension positive)."""
        return self.reading().force_N

    def line_rate_Hz(self) -> float:
        """Lines per second received since the first one."""
        with self._lock:
            if self._t_first is None or self.latest is None or self.lines < 2:
                return 0.0
            return (self.lines - 1) / max(self.latest.received_at - self._t_first, 1e-9)

    def stats_dict(self) -> dict[str, float]:
        d: dict[str, float] = dict(self.stats.as_dict())
        d["lines"] = self.lines
        d["line_rate_Hz"] = round(self.line_rate_Hz(), 2)
        return d

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        self.adapter.close()
