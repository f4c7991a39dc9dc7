"""Package attributes imported on first use (PEP 562), so that ``pmalab`` starts fast.

Every verb registers its options at start-up through its area's ``cli`` module, which
imports the area's package; a package that re-exported its API eagerly would make every
``pmalab`` command pay for numpy, h5py, scipy or matplotlib before the chosen verb runs.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
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
