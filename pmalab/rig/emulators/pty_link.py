"""Pseudo-terminals standing in for serial cables.

* :class:`Pty` — one pty pair: the emulator holds the master fd, a driver opens the slave
  path (``/dev/pts/N``) with pyserial exactly as it would open ``/dev/ttyUSB0``;
* :class:`PtyBridge` — two pty pairs joined by a thread ("null-modem cable"), for a peer
  that itself wants a port *path* (pymodbus' serial server).  It can pace bytes at the baud
  rate (10 bit times per 8N1 byte, plus the 3.5-character Modbus RTU inter-frame gap), so
  the emulated bus is as slow as a real one;
* :func:`link_path` — a stable symlink (``/tmp/pmalab-emulator/itv`` → ``/dev/pts/7``) that
  rig files can name.

A pty's slave is put in raw mode at once (no echo, no line editing), and the emulator
keeps it open so the master never reads EIO while no driver is attached.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from pathlib import Path


class Pty:
    """A pty pair: ``master`` fd for the emulator, ``path`` of the slave for the driver."""

    def __init__(self) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        os.set_blocking(self.master, False)

    def read(self, timeout: float) -> bytes:
        """Bytes the driver sent (``b""`` after ``timeout`` s with none)."""
        r, _, _ = select.select([self.master], [], [], timeout)
        if not r:
            return b""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            return b""

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                select.select([], [self.master], [], 0.1)
                continue
            view = view[n:]

    def close(self) -> None:
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


def byte_time(baudrate: int) -> float:
    """Seconds per byte on an 8N1 line (start + 8 data + stop bits)."""
    return 10.0 / float(baudrate)


class PtyBridge:
    """Two ptys joined back to back: ``server_path`` ↔ ``client_path``.

    With ``baudrate`` set, each chunk is delivered ``len × 10 / baud`` s after it was read;
    a request reaches the server only after the 3.5-character silence that ends an RTU frame
    (≥ 1.75 ms above 19200 baud) — a real device cannot start answering earlier.  So a
    request/reply costs what it costs on a real RS-485 bus.
    """

    def __init__(self, baudrate: int | None = None) -> None:
        self.a = Pty()  # server side
        self.b = Pty()  # client side
        self.baudrate = baudrate
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(
                target=self._pump, args=(self.b, self.a, True), daemon=True, name="pty-bridge-c2s"
            ),
            threading.Thread(
                target=self._pump, args=(self.a, self.b, False), daemon=True, name="pty-bridge-s2c"
            ),
        ]

    @property
    def server_path(self) -> str:
        return self.a.path

    @property
    def client_path(self) -> str:
        return self.b.path

    def start(self) -> PtyBridge:
        for t in self._threads:
            t.start()
        return self

    def _pump(self, src: Pty, dst: Pty, frame_gap: bool) -> None:
        gap = 0.0
        if self.baudrate and frame_gap:
            gap = 1.75e-3 if self.baudrate > 19200 else 3.5 * byte_time(self.baudrate)
        while not self._stop.is_set():
            data = src.read(0.05)
            if not data:
                continue
            if self.baudrate:
                # the bytes take this long on the wire, then the silence that ends a frame
                wire_sleep(len(data) * byte_time(self.baudrate) + gap)
            dst.write(data)

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=1.0)
        self.a.close()
        self.b.close()


def wire_sleep(dt: float) -> None:
    """Sleep ``dt`` s (a byte's time on the wire).

    A plain sleep, late by the kernel's timer slack (~0.05–0.1 ms): it holds no CPU and no
    interpreter lock meanwhile.  Spinning for the last millisecond, as this once did, was
    more exact on an idle machine but burnt a CPU per byte chunk and kept the driver (and
    the Modbus server) of the same process off the interpreter; on a busy machine the
    spinning thread was preempted holding the lock and every read waited for it.
    """
    if dt > 0:
        time.sleep(dt)


def link_path(target: str, link: str | Path) -> Path:
    """Make ``link`` a symlink to ``target`` (replacing an old link; never a regular file)."""
    link = Path(link)
    link.parent.mkdir(parents=True, exist_ok=True)
    if link.is_symlink():
        link.unlink()
    elif link.exists():
        raise FileExistsError(f"{link}: exists and is not a symlink; not replacing it")
    link.symlink_to(target)
    return link
