"""``needs_pty``: skip a test where the machine cannot open a pseudo-terminal (the serial
emulators and Modbus RTU run over pty pairs)."""

from __future__ import annotations

import os

import pytest


def have_pty() -> bool:
    """True when ``os.openpty()`` works here."""
    try:
        a, b = os.openpty()
    except OSError:
        return False
    os.close(a)
    os.close(b)
    return True


needs_pty = pytest.mark.skipif(not have_pty(), reason="this machine cannot open a pseudo-terminal")
