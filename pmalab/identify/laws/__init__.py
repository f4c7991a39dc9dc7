"""Hysteresis laws, one file each; ``LAWS`` is the registry, :func:`get_law` the lookup.

Adding a law (e.g. Prandtl-Ishlinskii or Maxwell-slip) is ONE new file in this folder with a
:class:`~pmalab.identify.laws.base.HysteresisLaw` subclass that sets ``name``: every module
here is imported and every such subclass registered (``--model NAME`` then works in
``identify``, ``diagnose`` and the controllers).
"""

from __future__ import annotations

import importlib
import pkgutil

from pmalab.identify.laws.base import LAWS, HysteresisLaw, LawParam
from pmalab.identify.laws.bouc_wen import BoucWen
from pmalab.identify.laws.duhem import Duhem

__all__ = ["LAWS", "BoucWen", "Duhem", "HysteresisLaw", "LawParam", "get_law"]

for _m in pkgutil.iter_modules(__path__):
    if not _m.name.startswith("_") and _m.name != "base":
        importlib.import_module(f"{__name__}.{_m.name}")


def get_law(name: str) -> HysteresisLaw:
    """A law instance by id (one clear line listing the valid ids if unknown)."""
    return LAWS.lookup(name)()
