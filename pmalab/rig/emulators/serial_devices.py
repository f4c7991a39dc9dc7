"""The two RS-232C devices on ptys: SMC ITV regulator and load-cell indicator.

Both run a thread on the master side of a :class:`~.pty_link.Pty`; the drivers open the
slave path with pyserial.  Replies are paced at the line's baud rate (10 bit times per
byte at 9600 8N1 ≈ 1.04 ms/byte) when ``pace`` is on, like a real RS-232C link.

ITV protocol (see :mod:`pmalab.rig.drivers.itv_serial`): ``SET n`` → ``OK`` and the
simulated regulator's setpoint becomes n/1023 of the range; ``MON`` → ``MON n`` with the
regulator's actual output pressure; otherwise ``UNKNOWN COMMAND`` / ``OUT OF RANGE``.

Indicator: streams ``ST,GS,+0012.34kg`` lines at ``rate_Hz`` with the simulated load cell's
reading in kgf; ``US`` while the force is still changing (> ``unstable_N`` between lines),
``OL`` beyond ``capacity_N``.
"""

from __future__ import annotations

import threading
import time

from pmalab.rig.drivers.itv_serial import FULL_SCALE
from pmalab.rig.drivers.loadcell_serial import G0
from pmalab.rig.emulators.faults import FaultPlan
from pmalab.rig.emulators.plant import EmulatedPlant
from pmalab.rig.emulators.pty_link import Pty, byte_time, wire_sleep


class _PtyDevice:
    def __init__(self, faults: FaultPlan | None, baudrate: int, pace: bool) -> None:
        self.pty = Pty()
        self.faults = faults or FaultPlan()
        self.baudrate = baudrate
        self.pace = pace
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def path(self) -> str:
        return self.pty.path

    def send(self, data: bytes) -> None:
        if self.pace:
            wire_sleep(len(data) * byte_time(self.baudrate))
        self.pty.write(data)

    def start(self):
        self._thread = threading.Thread(target=self._run, daemon=True, name=type(self).__name__)
        self._thread.start()
        return self

    def _run(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        self.pty.close()


class ItvEmulator(_PtyDevice):
    """SMC ITV with RS-232C on a pty, commanding the plant's cylinder (or muscle) regulator."""

    def __init__(
        self,
        plant: EmulatedPlant,
        max_pressure_MPa: float = 0.9,
        faults: FaultPlan | None = None,
        baudrate: int = 9600,
        pace: bool = True,
        target: str = "cylinder",
    ) -> None:
        super().__init__(faults, baudrate, pace)
        self.plant = plant
        self.max_pressure_MPa = max_pressure_MPa
        self.target = target
        self.setpoint_counts = 0
        self.commands = 0

    def reply_to(self, line: str) -> str:
        """The ITV's answer to one command line (without CR LF)."""
        parts = line.strip().upper().split()
        if parts == ["MON"]:
            if self.target == "cylinder":
                p = self.plant.cylinder_pressure_true()
            else:
                p = self.plant.physics.muscle_supply
            return f"MON {round(min(max(p / self.max_pressure_MPa, 0.0), 1.0) * FULL_SCALE)}"
        if len(parts) == 2 and parts[0] == "SET" and parts[1].isdigit():
            n = int(parts[1])
            if not 0 <= n <= FULL_SCALE:
                return "OUT OF RANGE"
            self.setpoint_counts = n
            mpa = n / FULL_SCALE * self.max_pressure_MPa
            (
                self.plant.command_cylinder
                if self.target == "cylinder"
                else self.plant.command_muscle
            )(mpa)
            return "OK"
        return "UNKNOWN COMMAND"

    def _run(self) -> None:
        buf = b""
        while not self._stop.is_set():
            data = self.pty.read(0.05)
            if not data:
                continue
            buf += data
            while b"\n" in buf or b"\r" in buf:
                cut = min(i for i in (buf.find(b"\r"), buf.find(b"\n")) if i >= 0)
                raw, buf = buf[:cut], buf[cut + 1 :]
                if not raw.strip():
                    continue
                self.commands += 1
                try:
                    line = raw.decode("ascii")
                except UnicodeDecodeError:
                    line = ""
                f = self.faults
                if f.take("drop"):
                    continue
                if f.take("exception"):
                    self.send(b"UNKNOWN COMMAND\r\n")
                    continue
                reply = self.reply_to(line).encode("ascii") + b"\r\n"
                if f.take("garble"):
                    reply = b"\xff" + reply[1:]
                self.send(reply)


class IndicatorEmulator(_PtyDevice):
    """A load-cell indicator streaming weight lines of the plant's load cell."""

    def __init__(
        self,
        plant: EmulatedPlant,
        rate_Hz: float = 50.0,
        faults: FaultPlan | None = None,
        baudrate: int = 9600,
        pace: bool = True,
        capacity_N: float = 2500.0,
        unstable_N: float = 5.0,
    ) -> None:
        super().__init__(faults, baudrate, pace)
        self.plant = plant
        self.period = 1.0 / rate_Hz
        self.capacity_N = capacity_N
        self.unstable_N = unstable_N
        self.lines = 0
        self._last = 0.0
        #: s of silence a ``disconnect`` fault causes (cable pulled)
        self.silence_s = 1.0

    def line_for(self, force_N: float) -> bytes:
        """One weight line for ``force_N`` newtons of tension."""
        if abs(force_N) > self.capacity_N:
            return b"OL,GS,+9999.99kg\r\n"
        flag = "US" if abs(force_N - self._last) > self.unstable_N else "ST"
        self._last = force_N
        kg = force_N / G0
        return f"{flag},GS,{'+' if kg >= 0 else '-'}{abs(kg):07.2f}kg\r\n".encode("ascii")

    def _run(self) -> None:
        next_t = time.perf_counter()
        while not self._stop.is_set():
            next_t += self.period
            line = self.line_for(self.plant.sample()["force"])
            f = self.faults
            if f.take("disconnect"):
                self._stop.wait(self.silence_s)
                next_t = time.perf_counter()
                continue
            if f.take("out_of_range"):
                line = b"OL,GS,+9999.99kg\r\n"
            if f.take("garble"):
                line = line[:3] + b"#?" + line[5:]
            if not f.take("drop"):
                self.send(line)
                self.lines += 1
            delay = next_t - time.perf_counter()
            if delay > 0:
                self._stop.wait(delay)
