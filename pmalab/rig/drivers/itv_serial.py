"""SMC ITV electro-pneumatic regulator with the RS-232C option (9600 baud, 8N1, ASCII).

Protocol (one command per line, CR LF terminated, one reply line each):

* ``SET n``  — set the pressure to n/1023 of the range (n = 0…1023) → ``OK``
* ``MON``    — read the output pressure back → ``MON n`` (n = 0…1023 of the range)
* anything else → ``UNKNOWN COMMAND``; n outside 0…1023 → ``OUT OF RANGE``

A 0.9 MPa ITV1050 therefore has a resolution of 0.9/1023 ≈ 0.88 kPa.  A reply other than the
expected one is counted and the command retried (bounded, re-opening the port after a
timeout); past the bound a :class:`RigError` names the port and the last reply.

At 9600 baud ``SET 1023`` plus its ``OK`` take about 15 ms on the wire, so a 500 Hz runner
cannot wait for each one.  :meth:`ItvSerialRegulator.set_pressure` therefore hands the
newest setpoint to a writer thread that sends only changed counts (the 1023-step
quantization makes most 2 ms updates no-ops) and returns at once; a failure in that thread
is raised by the next ``set_pressure``.  ``vent`` is synchronous and reports its outcome:
*confirmed* when ``SET 0`` is answered ``OK`` and ``MON`` then reads the output at or below
``vent_threshold_MPa`` within ``vent_confirm_s`` (the regulator exhausts its volume in a
fraction of a second); no ``OK``, or an output still above the threshold, is a FAILED vent.
A ``MON`` that no longer answers after the ``OK`` leaves the acknowledgement as the
confirmation (said so in the result).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from pmalab.errors import RigError
from pmalab.rig.base import PressureRegulator, VentResult
from pmalab.rig.drivers.adapters import (
    Adapter,
    DeviceExceptionReply,
    FrameError,
    TransportError,
    TransportTimeout,
)
from pmalab.rig.drivers.modbus_link import (
    LinkStats,
    RetriesExhausted,
    exchange_with_retries,
    one_line,
)

FULL_SCALE = 1023
ERROR_REPLIES = ("UNKNOWN COMMAND", "OUT OF RANGE", "ERROR")


class ItvSerialRegulator(PressureRegulator):
    """ITV regulator on a serial adapter; setpoints in MPa gauge."""

    def __init__(
        self,
        adapter: Adapter,
        max_pressure_MPa: float = 0.9,
        timeout: float = 0.2,
        retries: int = 2,
        name: str = "ITV regulator",
        vent_threshold_MPa: float = 0.02,
        vent_confirm_s: float = 2.0,
    ) -> None:
        self.adapter = adapter
        self.max_pressure_MPa = float(max_pressure_MPa)
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.name = name
        self.stats = LinkStats()
        self.last_command_MPa = 0.0
        #: a vent is confirmed when MON reads at most this (MPa) ...
        self.vent_threshold_MPa = float(vent_threshold_MPa)
        #: ... within this long after ``SET 0`` was acknowledged (s)
        self.vent_confirm_s = float(vent_confirm_s)
        self._io = threading.Lock()  # one command on the wire at a time
        self._cv = threading.Condition()
        self._pending: int | None = None
        self._sent: int | None = None
        self._error: RigError | None = None
        self._worker: threading.Thread | None = None
        self._stop = False

    # ----------------------------------------------------------------- protocol
    def counts_for(self, mpa: float) -> int:
        """Setpoint counts 0…1023 for ``mpa`` MPa (rounded to the nearest step)."""
        return min(max(round(mpa / self.max_pressure_MPa * FULL_SCALE), 0), FULL_SCALE)

    def _command(self, text: str) -> str:
        """Send one command line, return its reply line (retried on faults)."""
        with self._io:
            return self._command_locked(text)

    def _command_locked(self, text: str) -> str:
        def exchange() -> str:
            self.adapter.write(text.encode("ascii") + b"\r\n")
            raw = self.adapter.read_until(b"\r\n", self.timeout)
            try:
                reply = raw.decode("ascii").strip()
            except UnicodeDecodeError as exc:
                raise FrameError(f"{self.adapter.name}: garbled reply {raw!r}") from exc
            if reply in ERROR_REPLIES:
                raise DeviceExceptionReply(f"{self.adapter.name}: {text!r} → {reply}")
            return reply

        try:
            return exchange_with_retries(
                self.adapter, self.stats, self.retries, exchange, recover=self._recover
            )
        except RetriesExhausted as exc:
            raise RigError(
                f"{self.name} {self.adapter.name}: {text!r} failed after {self.retries + 1} "
                f"attempts (last: {one_line(exc.last)})"
            ) from None

    def _recover(self, exc: TransportError) -> None:
        time.sleep(0.005)  # let a late reply land, then drop it
        self.adapter.discard_input()

    def set_counts(self, n: int) -> None:
        """Send ``SET n`` and wait for ``OK`` (synchronous)."""
        reply = self._command(f"SET {int(n)}")
        if reply != "OK":
            self.stats.bad_frames += 1
            raise RigError(
                f"{self.name} {self.adapter.name}: SET {n} answered {reply!r}, expected 'OK'"
            )
        self._sent = int(n)

    def _run_writer(self) -> None:
        while True:
            with self._cv:
                while not self._stop and (self._pending is None or self._pending == self._sent):
                    self._cv.wait()
                if self._stop:
                    return
                n = self._pending
            assert n is not None  # the wait ends on stop (returned above) or a pending value
            try:
                self.set_counts(n)
            except RigError as exc:
                with self._cv:
                    self._error = exc
                    self._stop = True
                return

    def monitor_counts(self) -> int:
        reply = self._command("MON")
        parts = reply.split()
        if len(parts) != 2 or parts[0] != "MON" or not parts[1].isdigit():
            self.stats.bad_frames += 1
            raise RigError(
                f"{self.name} {self.adapter.name}: MON answered {reply!r}, expected 'MON n'"
            )
        return int(parts[1])

    # ----------------------------------------------------------------- regulator API
    def connect(self) -> None:
        """Open the port and check that an ITV answers (one clear line if not)."""
        try:
            self.adapter.open()
        except (OSError, TransportError) as exc:
            raise RigError(
                f"{self.name} {self.adapter.name}: cannot open ({one_line(exc)})"
            ) from exc
        try:
            self.monitor_pressure()
        except RigError:
            self.adapter.close()
            raise

    def set_pressure(self, mpa: float) -> None:
        """Queue ``mpa`` MPa for the writer thread; raise a fault the thread met earlier."""
        if not -1e-9 <= mpa <= self.max_pressure_MPa + 1e-9:
            raise RigError(
                f"{self.name}: command {mpa:.4f} MPa outside 0–{self.max_pressure_MPa} MPa"
            )
        with self._cv:
            if self._error is not None:
                raise self._error
            if self._worker is None:
                self._stop = False
                self._worker = threading.Thread(
                    target=self._run_writer, name="itv-writer", daemon=True
                )
                self._worker.start()
            self._pending = self.counts_for(mpa)
            self._cv.notify()
        self.last_command_MPa = float(mpa)

    def flush(self, timeout: float = 1.0) -> None:
        """Wait until the newest setpoint is on the device (tests, start of a run)."""
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            with self._cv:
                if self._error is not None:
                    raise self._error
                if self._pending is None or self._pending == self._sent:
                    return
            time.sleep(0.001)
        raise RigError(
            f"{self.name} {self.adapter.name}: setpoint not acknowledged within {timeout} s"
        )

    def _stop_writer(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify()
            worker, self._worker = self._worker, None
        if worker is not None and worker is not threading.current_thread():
            worker.join(timeout=2.0)

    def monitor_pressure(self) -> float:
        """The regulator's own output-pressure reading (MPa)."""
        return self.monitor_counts() / FULL_SCALE * self.max_pressure_MPa

    def vent(self) -> VentResult:
        """``SET 0``, then watch ``MON`` fall; the result says what was confirmed (never raises)."""
        return self.start_vent()()

    def start_vent(self) -> Callable[[], VentResult]:
        """Send ``SET 0`` now; the returned confirmation watches ``MON`` fall."""
        self._stop_writer()
        try:
            self.set_counts(0)
        except Exception as exc:  # must never raise
            res = VentResult.failed(
                f"SET 0 not acknowledged by {self.adapter.name}: {one_line(exc)}"
            )
            return lambda: res
        self.last_command_MPa = 0.0
        deadline = time.perf_counter() + self.vent_confirm_s
        return lambda: self._confirm_vent(deadline)

    def _confirm_vent(self, deadline: float) -> VentResult:
        where = self.adapter.name
        while True:
            try:
                p = self.monitor_pressure()
            except Exception as exc:
                return VentResult.confirmed(
                    f"SET 0 acknowledged by {where}; MON read-back failed: {one_line(exc)}"
                )
            if p <= self.vent_threshold_MPa:
                return VentResult.confirmed(
                    f"SET 0 acknowledged by {where}, output reads {p:.3f} MPa"
                )
            if time.perf_counter() >= deadline:
                return VentResult.failed(
                    f"SET 0 acknowledged by {where}, but the output still reads {p:.3f} MPa "
                    f"after {self.vent_confirm_s:g} s"
                )
            time.sleep(0.02)

    def close(self) -> None:
        self._stop_writer()
        self.adapter.close()

    def stats_dict(self) -> dict[str, Any]:
        return self.stats.as_dict()


__all__ = ["ERROR_REPLIES", "FULL_SCALE", "ItvSerialRegulator", "TransportTimeout"]
