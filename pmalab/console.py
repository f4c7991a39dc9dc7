"""How the ``pmalab`` verbs talk to a terminal: verbosity switches, notes and warnings.

Results go to stdout; progress bars, ``note:`` lines (information) and ``warning:`` lines
(something the user should look at) go to stderr, so a piped stdout stays clean.  Every
verb that does long work takes ``-q/--quiet`` (no tables, notes or progress: the one line
that names the outputs, and warnings and errors) and ``-v/--verbose`` (also the per-run
details); a progress bar is drawn only when stderr is a terminal.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

QUIET, NORMAL, VERBOSE = 0, 1, 2


def add_verbosity(p: argparse.ArgumentParser, *, quiet_help: str = "") -> None:
    """Add ``-q/--quiet`` and ``-v/--verbose`` (mutually exclusive) to a verb's parser."""
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help=quiet_help
        or "print only the line naming the outputs, warnings and errors (no tables, no notes, "
        "no progress)",
    )
    g.add_argument(
        "-v", "--verbose", action="store_true", help="also print per-run notes and details"
    )


def verbosity(args: argparse.Namespace) -> int:
    """QUIET, NORMAL or VERBOSE from the parsed ``-q``/``-v`` flags (NORMAL when absent)."""
    if getattr(args, "quiet", False):
        return QUIET
    if getattr(args, "verbose", False):
        return VERBOSE
    return NORMAL


def table_printer(args: argparse.Namespace) -> Callable[..., None]:
    """``print`` for a verb's tables and per-run lines: silent under ``-q`` (the line that
    names the outputs, warnings and errors are printed with ``print`` as always)."""
    if verbosity(args) <= QUIET:
        return _silent
    return print


def _silent(*_args: object, **_kwargs: object) -> None:
    """``print``'s signature, printing nothing."""


def show_progress(args: argparse.Namespace) -> bool:
    """A progress bar only on a terminal and never with ``-q`` (piped output stays quiet)."""
    return verbosity(args) > QUIET and sys.stderr.isatty()


def note(text: str) -> None:
    """One line of information on stderr (flushed at once)."""
    print(f"note: {text}", file=sys.stderr, flush=True)


def warning(text: str) -> None:
    """One line the user should act on or check, on stderr, in full (flushed at once)."""
    print(f"warning: {text}", file=sys.stderr, flush=True)
