"""Byte transports ("adapters", as PyMeasure calls them): TCP socket and serial port.

A device driver (:mod:`.modbus_link`, :mod:`.itv_serial`, :mod:`.loadcell_serial`) speaks its
protocol through an :class:`Adapter` and never touches sockets or ports itself, so the same
driver runs over a real link, an emulator on a pty, or the recorded request/reply pairs of
:mod:`.testing`.

Failures surface as :class:`TransportError` subclasses (timeouts, closed links, garbled
frames, device exception replies); the driver decides whether to retry, reconnect or give
up with a :class:`pmalab.errors.RigError`.
"""

from __future__ import annotations

import os
import socket
import time
from abc import ABC, abstractmethod

import serial


# --------------------------------------------------------------------------- errors
class TransportError(Exception):
    """A link-level failure that a bounded retry may fix."""


class TransportTimeout(TransportError):
    """No (complete) reply within the timeout."""


class TransportClosed(TransportError):
    """The link went away (peer closed the socket, port unplugged)."""


class FrameError(TransportError):
    """A reply arrived but is corrupt: bad CRC, wrong length, wrong header."""


class DeviceExceptionReply(TransportError):
    """The device answered with an error (Modbus exception code, ``UNKNOWN COMMAND``...)."""

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


class ValueOutOfRange(TransportError):
    """A raw reading lies outside the sensor's physically possible range."""


# --------------------------------------------------------------------------- adapters
class Adapter(ABC):
    """A byte pipe to one device: open/close, write, read with a deadline."""

    #: human-readable endpoint, used in every error message
    name: str = "adapter"

    @abstractmethod
    def open(self) -> None:
        """Open (or re-open) the link.  Raise ``OSError``/``TransportError`` on failure."""

    @abstractmethod
    def close(self) -> None:
        """Close the link; safe to call when closed."""

    @property
    @abstractmethod
    def is_open(self) -> bool: ...

    @abstractmethod
    def write(self, data: bytes) -> None:
        """Send all of ``data``."""

    @abstractmethod
    def read_exact(self, n: int, timeout: float) -> bytes:
        """Return exactly ``n`` bytes or raise :class:`TransportTimeout` after ``timeout`` s."""

    @abstractmethod
    def read_until(self, terminator: bytes, timeout: float) -> bytes:
        """Return bytes up to and including ``terminator`` or raise :class:`TransportTimeout`."""

    @abstractmethod
    def discard_input(self) -> None:
        """Drop whatever has been received but not read (resynchronise after a bad frame)."""


class SocketAdapter(Adapter):
    """A TCP connection (Nagle off: a Modbus request is one small segment)."""

    def __init__(self, host: str, port: int, connect_timeout: float = 1.0) -> None:
        self.host = host
        self.port = int(port)
        self.connect_timeout = connect_timeout
        self.name = f"tcp://{host}:{port}"
        self._sock: socket.socket | None = None
        self._buf = bytearray()

    def open(self) -> None:
        self.close()
        sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        self._buf.clear()

    def close(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
        self._sock = None
        self._buf.clear()

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    def _require(self) -> socket.socket:
        if self._sock is None:
            raise TransportClosed(f"{self.name}: not connected")
        return self._sock

    def write(self, data: bytes) -> None:
        sock = self._require()
        try:
            sock.sendall(data)
        except OSError as exc:
            self.close()
            raise TransportClosed(f"{self.name}: send failed ({exc})") from exc

    def _fill(self, deadline: float) -> None:
        sock = self._require()
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            raise TransportTimeout(f"{self.name}: no reply")
        sock.settimeout(remaining)
        try:
            chunk = sock.recv(4096)
        except TimeoutError as exc:
            raise TransportTimeout(f"{self.name}: no reply") from exc
        except OSError as exc:
            self.close()
            raise TransportClosed(f"{self.name}: receive failed ({exc})") from exc
        if not chunk:
            self.close()
            raise TransportClosed(f"{self.name}: connection closed by peer")
        self._buf += chunk

    def read_exact(self, n: int, timeout: float) -> bytes:
        deadline = time.perf_counter() + timeout
        while len(self._buf) < n:
            self._fill(deadline)
        out = bytes(self._buf[:n])
        del self._buf[:n]
        return out

    def read_until(self, terminator: bytes, timeout: float) -> bytes:
        deadline = time.perf_counter() + timeout
        while (i := self._buf.find(terminator)) < 0:
            self._fill(deadline)
        out = bytes(self._buf[: i + len(terminator)])
        del self._buf[: i + len(terminator)]
        return out

    def discard_input(self) -> None:
        self._buf.clear()
        if self._sock is None:
            return
        self._sock.setblocking(False)
        try:
            while self._sock.recv(4096):
                pass
        except (BlockingIOError, OSError):
            pass
        finally:
            if self._sock is not None:
                self._sock.setblocking(True)


#: the longest unfinished line :class:`SerialAdapter` keeps across a read's deadline (bytes;
#: a weight line is ~18, an ITV reply ~10, a Modbus ASCII frame at most 513)
MAX_PARTIAL_LINE = 1024


class SerialAdapter(Adapter):
    """A serial port through pyserial (RS-232/RS-485, or a pty for the emulators)."""

    def __init__(
        self,
        port: str,
        baudrate: int = 9600,
        bytesize: int = 8,
        parity: str = "N",
        stopbits: float = 1,
    ) -> None:
        self.port = port
        self.baudrate = int(baudrate)
        self.bytesize = int(bytesize)
        self.parity = parity
        self.stopbits = stopbits
        self.name = f"serial://{port}@{baudrate}"
        self._ser: serial.Serial | None = None
        #: the start of a line whose rest had not arrived when :meth:`read_until` timed out:
        #: the next call continues it (a line split across a read's deadline is one line,
        #: not a lost line and a garbled tail)
        self._partial = bytearray()

    def open(self) -> None:
        self.close()
        try:
            self._ser = serial.Serial(
                self.port,
                baudrate=self.baudrate,
                bytesize=self.bytesize,
                parity=self.parity,
                stopbits=self.stopbits,
                timeout=0.1,
                exclusive=True,
            )
        except (serial.SerialException, ValueError) as exc:
            errno = getattr(exc, "errno", None)
            if errno:
                raise OSError(errno, os.strerror(errno)) from exc
            raise OSError(f"cannot open port ({exc})") from exc

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except (OSError, serial.SerialException):
                pass
        self._ser = None
        self._partial.clear()

    @property
    def is_open(self) -> bool:
        return self._ser is not None

    def _require(self) -> serial.Serial:
        if self._ser is None:
            raise TransportClosed(f"{self.name}: not open")
        return self._ser

    def write(self, data: bytes) -> None:
        ser = self._require()
        try:
            ser.write(data)
        except (OSError, serial.SerialException) as exc:
            self.close()
            raise TransportClosed(f"{self.name}: write failed ({exc})") from exc

    def read_exact(self, n: int, timeout: float) -> bytes:
        ser = self._require()
        deadline = time.perf_counter() + timeout
        out = bytearray()
        try:
            while len(out) < n:
                remaining = deadline - time.perf_counter()
                if remaining <= 0:
                    raise TransportTimeout(f"{self.name}: no reply ({len(out)}/{n} bytes)")
                ser.timeout = remaining
                out += ser.read(n - len(out))
        except (OSError, serial.SerialException) as exc:
            self.close()
            raise TransportClosed(f"{self.name}: read failed ({exc})") from exc
        return bytes(out)

    def read_until(self, terminator: bytes, timeout: float) -> bytes:
        """Bytes up to and including ``terminator``; on a timeout the bytes of the
        unfinished line are kept and the next call continues that line."""
        ser = self._require()
        deadline = time.perf_counter() + timeout
        out, self._partial = self._partial, bytearray()
        try:
            while not out.endswith(terminator):
                remaining = deadline - time.perf_counter()
                if remaining <= 0:
                    # kept only while it can still be the start of one line: a device that
                    # never sends the terminator (a wrong line ending) must not grow it
                    self._partial = out if len(out) <= MAX_PARTIAL_LINE else bytearray()
                    raise TransportTimeout(f"{self.name}: no complete line")
                ser.timeout = remaining
                out += ser.read_until(terminator)
        except (OSError, serial.SerialException) as exc:
            self.close()
            raise TransportClosed(f"{self.name}: read failed ({exc})") from exc
        return bytes(out)

    def discard_input(self) -> None:
        self._partial.clear()
        if self._ser is not None:
            try:
                self._ser.reset_input_buffer()
            except (OSError, serial.SerialException):
                pass
