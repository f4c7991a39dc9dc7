"""User-facing errors.

Anything a user can cause (a bad file, a bad option, a tripped limit) raises a subclass of
:class:`PmalabError`.  The CLI prints ``str(error)`` as one line on stderr and exits with
``error.exit_code``; no traceback.  Programming errors are not caught and do show one.
"""

from __future__ import annotations

from typing import Any


def printable(text: str) -> str:
    """``text`` with control characters shown as escapes (``\\n``, ``\\x00``).

    Names read from a user's file (channel, group, column) can hold any character; an
    error that quotes them must stay one line on a terminal.
    """
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class PmalabError(Exception):
    """An error the user can fix; its message is one line naming the file/run/channel/field."""

    exit_code = 2
    #: the process cannot shut down normally (an HDF5 file could not be closed, e.g. on a
    #: full disk, and the library would crash at exit): the CLI ends it with ``os._exit``
    hard_exit: bool = False


class RunFileError(PmalabError):
    """A run file (HDF5 or CSV import) is malformed."""


class ConfigError(PmalabError):
    """A TOML file (rig, protocol, truth) has a mistake."""


class RigError(PmalabError):
    """A device is unreachable, misconfigured or faulted."""

    exit_code = 3


class SafetyAbort(PmalabError):
    """A run was aborted by a limit trip, Ctrl-C or a device fault, or a regulator's vent
    was not confirmed; the message states each regulator's vent outcome."""

    exit_code = 4
    #: the vent report the message states (``pmalab.rig.base.VentReport``), if any
    vent: Any = None
    #: the message with a placeholder for the vent report (re-rendered on a later vent)
    template: str | None = None


class OutputError(PmalabError):
    """An output cannot be written there (a directory or file in the way, no permission,
    disk full)."""


class OutputExistsError(OutputError):
    """An output exists and ``--force`` was not given."""


class RunFileWarning(UserWarning):
    """Something the user should know about an input that is used anyway or left out (an
    aborted run skipped); the CLI prints it as one ``pmalab VERB: warning: ...`` line."""
