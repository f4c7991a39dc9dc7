"""Recorded request/reply testing for drivers, in the style of PyMeasure's ``expected_protocol``.

:class:`ProtocolAdapter` is an :class:`~.adapters.Adapter` that replays a list of
``(expected_write, reply)`` pairs: every ``write`` must be exactly the next expected bytes
(else ``AssertionError`` showing both), and the pair's reply becomes readable.  A reply of
``None`` (or shorter than the driver asks for) makes the read time out at once, as a dropped
reply would; ``(None, reply)`` is unsolicited data (a streaming device) and
``(CLOSE, None)`` makes the next read see a closed link.

    with expected_protocol(make_driver, [(b"SET 512\\r\\n", b"OK\\r\\n")]) as itv:
        itv.set_counts(512)

At exit every pair must have been used.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, TypeVar

from pmalab.rig.drivers.adapters import Adapter, TransportClosed, TransportTimeout

T = TypeVar("T")
CLOSE = b"<close>"


class ProtocolAdapter(Adapter):
    """An adapter that checks written bytes against a script and replies from it."""

    def __init__(
        self, pairs: Sequence[tuple[bytes | None, bytes | None]], name: str = "fake"
    ) -> None:
        self.pairs = list(pairs)
        self.name = name
        self.index = 0
        self._buf = bytearray()
        self._open = False
        self._closed_by_peer = False
        self.opens = 0
        self._feed_unsolicited()

    def _feed_unsolicited(self) -> None:
        while self.index < len(self.pairs) and self.pairs[self.index][0] is None:
            self._buf += self.pairs[self.index][1] or b""
            self.index += 1

    def open(self) -> None:
        if self.opens:  # a fresh connection: whatever the old one held is gone
            self._buf.clear()
        self._open = True
        self._closed_by_peer = False
        self.opens += 1

    def close(self) -> None:
        self._open = False

    @property
    def is_open(self) -> bool:
        return self._open

    def write(self, data: bytes) -> None:
        if self.index >= len(self.pairs):
            raise AssertionError(f"unexpected write {data!r}: the script is used up")
        expected, reply = self.pairs[self.index]
        if expected == CLOSE:
            self.index += 1
            self._closed_by_peer = True
            raise TransportClosed(f"{self.name}: closed by peer")
        if data != expected:
            raise AssertionError(f"pair {self.index}: wrote {data!r}, expected {expected!r}")
        self.index += 1
        self._buf += reply or b""
        self._feed_unsolicited()

    def _take(self, n: int) -> bytes:
        out = bytes(self._buf[:n])
        del self._buf[:n]
        return out

    def read_exact(self, n: int, timeout: float) -> bytes:
        if self._closed_by_peer:
            raise TransportClosed(f"{self.name}: closed by peer")
        if len(self._buf) < n:
            self._buf.clear()
            raise TransportTimeout(f"{self.name}: no reply")
        return self._take(n)

    def read_until(self, terminator: bytes, timeout: float) -> bytes:
        if self._closed_by_peer:
            raise TransportClosed(f"{self.name}: closed by peer")
        i = self._buf.find(terminator)
        if i < 0:
            self._buf.clear()
            raise TransportTimeout(f"{self.name}: no reply")
        return self._take(i + len(terminator))

    def discard_input(self) -> None:
        self._buf.clear()

    def assert_done(self) -> None:
        left = self.pairs[self.index :]
        assert not left, f"{len(left)} scripted pair(s) never used, first {left[0]!r}"


@contextmanager
def expected_protocol(
    make: Callable[[ProtocolAdapter], T],
    pairs: Sequence[tuple[bytes | None, bytes | None]],
    **kw: Any,
) -> Iterator[T]:
    """Build a driver on a :class:`ProtocolAdapter` replaying ``pairs``; check all were used."""
    adapter = ProtocolAdapter(pairs, **kw)
    adapter.open()
    yield make(adapter)
    adapter.assert_done()
