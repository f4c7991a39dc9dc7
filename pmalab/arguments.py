"""Argument types shared by the command line's verbs: a number a user types is checked
where it is parsed, so a bad one is one line naming the option (exit 2), never a traceback
deep in a library (an HDF5 attribute cannot hold a 90-digit integer)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterable

from pmalab.errors import PmalabError

#: the largest seed: it is stored with the recording as a 64-bit integer attribute
MAX_SEED = 2**63 - 1
#: the environment variable that sets the default of every command's ``--jobs``
JOBS_ENV = "PMALAB_JOBS"
#: worker processes of an identification or a diagnosis when neither ``--jobs`` nor
#: ``$PMALAB_JOBS`` says (the library's default too; here, where the command line reads it
#: without loading the fitting code)
DEFAULT_JOBS = 2


def default_jobs(fallback: int) -> int:
    """The worker processes a command starts when ``--jobs`` is not given.

    ``$PMALAB_JOBS`` when set (1 where other work already fills the cores: a parallel test
    suite, commands run side by side; every result is the same under any number of
    workers), else ``fallback``.

    Parameters
    ----------
    fallback
        The command's own default (worker processes).

    Returns
    -------
    int
        The number of worker processes, ≥ 1.

    Raises
    ------
    PmalabError
        ``$PMALAB_JOBS`` is set but not a whole number ≥ 1 (one line naming it).
    """
    import os

    text = os.environ.get(JOBS_ENV, "").strip()
    if not text:
        return fallback
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise PmalabError(f"{JOBS_ENV}={text}: give a whole number >= 1 (worker processes)")
    return n


def seed(text: str) -> int:
    """A random seed: an integer 0 … 2**63 − 1.

    Parameters
    ----------
    text
        The option's text.

    Returns
    -------
    int
        The seed.
    """
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
    if not 0 <= v <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be an integer ≥ 0 and ≤ 2**63-1, got {text}")
    return v


def fixes(items: Iterable[str]) -> dict[str, float]:
    """``--fix NAME=VALUE`` options as ``{name: value}``: each value a finite number.

    Raises
    ------
    PmalabError
        One line naming the option, for a missing ``=``, name or number, or a value that is
        not finite.  Whether the value lies inside the parameter's bounds is the fit's
        check (it knows the law).
    """
    out: dict[str, float] = {}
    for it in items:
        name, sep, val = it.partition("=")
        try:
            if not sep or not name:
                raise ValueError
            v = float(val)
        except ValueError:
            raise PmalabError(f"--fix {it!r}: expected NAME=VALUE with a number") from None
        if not math.isfinite(v):
            raise PmalabError(f"--fix {it!r}: the value must be a finite number")
        out[name.strip()] = v
    return out


def law_names(text: str | None) -> list[str] | None:
    """``diagnose --laws``: the comma-separated law ids (``none`` and empty items dropped:
    ``--laws none`` scores no other law); None when the option is not given (every law)."""
    return None if text is None else [x for x in text.split(",") if x and x != "none"]


def check_max_steps(n: int) -> int:
    """``diagnose --max-steps``: ``n`` when ≥ 0, else one line naming the option."""
    if n < 0:
        raise PmalabError(f"--max-steps {n}: must be ≥ 0")
    return n
