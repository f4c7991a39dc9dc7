"""Faults injected into the emulators on demand (tests, demos of the drivers' recovery).

A :class:`FaultPlan` holds how many of each fault the next replies should carry; every
emulator asks it with :meth:`FaultPlan.take` before answering, so a test arms
``plan.arm("drop", 2)`` and the next two replies of the device it is attached to vanish.
Kinds:

* ``drop`` — no reply at all (the client times out);
* ``garble`` — the reply is corrupted (Modbus RTU: CRC; TCP: MBAP header; ASCII: bytes);
* ``exception`` — a Modbus exception reply (``exception_code``, default 4 SERVER DEVICE
  FAILURE) or ``UNKNOWN COMMAND`` for the ITV;
* ``disconnect`` — the TCP connection is closed / the serial stream stops for a while;
* ``out_of_range`` — one analog channel reads far outside its electrical range;
* ``delay`` — the reply comes ``delay_s`` late.

Injected counts are kept in :attr:`FaultPlan.injected`, to compare with the drivers'
counters.
"""

from __future__ import annotations

import threading
from collections import Counter

KINDS = ("drop", "garble", "exception", "disconnect", "out_of_range", "delay", "stream_overflow")


class FaultPlan:
    """Thread-safe counts of faults still to inject, and of those injected."""

    def __init__(self, exception_code: int = 4, delay_s: float = 0.2) -> None:
        self._armed: Counter[str] = Counter()
        self.injected: Counter[str] = Counter()
        self.exception_code = exception_code
        self.delay_s = delay_s
        self._lock = threading.Lock()

    def arm(self, kind: str, n: int = 1) -> None:
        """Inject ``kind`` into the next ``n`` replies."""
        if kind not in KINDS:
            raise ValueError(f"unknown fault {kind!r} (known: {', '.join(KINDS)})")
        with self._lock:
            self._armed[kind] += n

    def take(self, kind: str) -> bool:
        """True (and count it) when a ``kind`` fault is due now."""
        with self._lock:
            if self._armed[kind] > 0:
                self._armed[kind] -= 1
                self.injected[kind] += 1
                return True
            return False

    def pending(self) -> int:
        with self._lock:
            return sum(self._armed.values())

    def clear(self) -> None:
        with self._lock:
            self._armed.clear()
