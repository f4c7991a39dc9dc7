"""The serial adapter over a real pseudo-terminal: a line whose rest arrives after a read's
deadline is continued by the next read, not lost (the weight indicator's reader reads with
a 0.1 s deadline; a line split across it was dropped and its tail counted as a bad frame)."""

from __future__ import annotations

import os
import time

import pytest

from pmalab.rig.drivers.adapters import MAX_PARTIAL_LINE, SerialAdapter, TransportTimeout
from tests.pty_support import needs_pty


@pytest.fixture
def pty_link():
    master, slave = os.openpty()
    adapter = SerialAdapter(os.ttyname(slave), 9600)
    adapter.open()
    try:
        yield master, adapter
    finally:
        adapter.close()
        os.close(master)
        os.close(slave)


@needs_pty
def test_a_line_split_across_the_deadline_is_continued_not_lost(pty_link):
    master, adapter = pty_link
    os.write(master, b"ST,GS,+00")
    with pytest.raises(TransportTimeout):
        adapter.read_until(b"\n", 0.05)
    os.write(master, b"12.34kg\r\nST,GS,+0")
    assert adapter.read_until(b"\n", 1.0) == b"ST,GS,+0012.34kg\r\n"
    with pytest.raises(TransportTimeout):
        adapter.read_until(b"\n", 0.05)
    os.write(master, b"001.00kg\r\n")
    assert adapter.read_until(b"\n", 1.0) == b"ST,GS,+0001.00kg\r\n"


@needs_pty
def test_discarding_the_input_drops_a_partial_line_too(pty_link):
    # a request/reply driver resynchronises after a timeout: the late reply's start must
    # not be glued to the next reply
    master, adapter = pty_link
    os.write(master, b"LATE")
    with pytest.raises(TransportTimeout):
        adapter.read_until(b"\r\n", 0.05)
    adapter.discard_input()
    time.sleep(0.01)
    os.write(master, b"OK\r\n")
    assert adapter.read_until(b"\r\n", 1.0) == b"OK\r\n"


@needs_pty
def test_a_device_that_never_ends_its_lines_does_not_grow_the_kept_start(pty_link):
    # a wrong line ending (``\r`` only): the kept start is dropped once it is longer than
    # any line, so the reader's memory stays bounded whatever the device sends
    master, adapter = pty_link
    for _ in range(3):
        os.write(master, b"ST,GS,+0012.34kg\r" * 40)
        with pytest.raises(TransportTimeout):
            adapter.read_until(b"\n", 0.1)
    assert len(adapter._partial) <= MAX_PARTIAL_LINE  # pyright: ignore[reportPrivateUsage]
    adapter.discard_input()
    os.write(master, b"ST,GS,+0001.00kg\r\n")
    assert adapter.read_until(b"\n", 1.0) == b"ST,GS,+0001.00kg\r\n"
