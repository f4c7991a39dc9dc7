"""Package attributes imported on first use (PEP 562), so that ``pmalab`` starts fast.

Every verb registers its options at start-up through its area's ``cli`` module, which
imports the area's package; a package that re-exported its API eagerly would make every
``pmalab`` command pay for numpy, h5py, scipy or matplotlib before the chosen verb runs.
"""

from __future__ import annotations

import gc
import importlib
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any


def lazy_exports(
    package: str, exports: Mapping[str, str]
) -> tuple[Callable[[str], Any], list[str]]:
    """``(__getattr__, __all__)`` for ``package``: ``exports`` maps a name to its module."""
    table = dict(exports)

    def __getattr__(name: str) -> Any:
        mod = table.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(mod), name)

    return __getattr__, sorted(table)


@contextmanager
def gc_paused(freeze: bool) -> Iterator[None]:
    """Cyclic garbage collection paused while a command imports its heavy modules.

    Importing SciPy and numba, and numba's first load of its compiled code, create hundreds
    of thousands of long-lived objects that the collector would walk again and again: about
    a tenth of the import time and a third of that first load.

    Parameters
    ----------
    freeze
        Move every object alive at the end into the collector's permanent generation
        (:func:`gc.freeze`), so no later collection walks them again; else resuming would
        walk them all at the next collection.  For a process's first import of those
        modules (a command run from the shell: they live as long as the process); not for a
        process that already holds other work (a test session), whose garbage of the moment
        would be kept too.
    """
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            if freeze:
                gc.freeze()
            gc.enable()
