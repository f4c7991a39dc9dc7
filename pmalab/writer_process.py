"""Which process records a run file, and whether it still runs.

A recording's file is written by one process (SWMR: single writer, many readers).  A reader
that finds a run still marked ``running`` must know whether its writer was killed — its
last chunk may then be torn, and what the checksum does not verify is lost — or is alive
and still appending, rewriting that chunk at every flush: nothing is lost, the run is not
finished.  The recorder stores :func:`identity` in the file before the first sample;
:func:`alive` tells later whether that very process still runs.

A process is named by its host, pid, pid namespace, the kernel's boot id and its start time
(clock ticks since boot, ``/proc/PID/stat`` field 22): a pid reused by another process after
the writer died, the same pid after a reboot, or the same pid in another container is not
the writer.  Where this cannot be told (the file was written on another host or in another
pid namespace, no ``/proc``), :func:`alive` says so by returning None,
and the reader treats the writer as killed, as it did before files named their writer.
"""

from __future__ import annotations

import json
import os
import socket
from typing import Any

#: the root attr of a run file holding its writer's :func:`identity`
WRITER_ATTR = "writer"


def _boot_id() -> str:
    try:
        with open("/proc/sys/kernel/random/boot_id") as fh:
            return fh.read().strip()
    except OSError:
        return ""


def _pid_namespace() -> str:
    """This process's pid namespace (``"pid:[4026531836]"``), or "" where it cannot be
    read: a pid means a process only within its namespace (a container has its own)."""
    try:
        return os.readlink("/proc/self/ns/pid")
    except OSError:
        return ""


def _stat(pid: int) -> tuple[str, int] | None:
    """(state letter, start time in clock ticks since boot) of process ``pid``, or None
    when it does not exist (or ``/proc`` cannot be read)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            text = fh.read().decode("ascii", "replace")
    except OSError:
        return None
    # the command name (field 2) is in parentheses and may hold spaces: split after it
    rest = text[text.rfind(")") + 2 :].split()
    try:
        return rest[0], int(rest[19])  # fields 3 (state) and 22 (start time)
    except (IndexError, ValueError):
        return None


def identity() -> str:
    """This process as a file's writer: JSON of ``host``, ``pid``, ``boot_id``,
    ``start_ticks`` (its start, clock ticks since boot; 0 where unknown) and ``pid_ns`` (the
    pid namespace its pid belongs to; "" where unknown)."""
    pid = os.getpid()
    st = _stat(pid)
    return json.dumps(
        {
            "host": socket.gethostname(),
            "pid": pid,
            "boot_id": _boot_id(),
            "start_ticks": st[1] if st else 0,
            "pid_ns": _pid_namespace(),
        }
    )


def alive(recorded: Any) -> str | None:
    """Words naming the writer (``"process 1234 on lab-pc"``) when the process that
    ``recorded`` (:func:`identity`'s JSON) names still runs; None when it has ended
    (gone, a zombie, its pid now another process's, another boot) or when this cannot be
    told (another host, another pid namespace — a container's pids are not the host's nor
    another container's —, no ``/proc``, no or unreadable record).

    Parameters
    ----------
    recorded
        The file's :data:`WRITER_ATTR` attr (str or bytes), or None.

    Returns
    -------
    str or None
        The writer in words while it runs, else None.
    """
    if recorded is None:
        return None
    try:
        doc = json.loads(recorded.decode() if isinstance(recorded, bytes) else str(recorded))
        host, pid = str(doc["host"]), int(doc["pid"])
        boot, ticks = str(doc.get("boot_id", "")), int(doc.get("start_ticks", 0))
        space = str(doc.get("pid_ns", ""))
    except (ValueError, TypeError, KeyError, AttributeError, UnicodeDecodeError):
        return None
    if host != socket.gethostname() or not boot or not ticks or boot != _boot_id():
        return None
    if not space or space != _pid_namespace():  # its pid names another process here
        return None
    st = _stat(pid)
    if st is None or st[0] in ("Z", "X") or st[1] != ticks:
        return None
    return f"process {pid} on {host}"
