"""Hysteresis laws, one file each; ``LAWS`` is the registry, :func:`get_law` the lookup.

Adding a law (e.g. Prandtl-Ishlinskii or Maxwell-slip) is one new file with a
:class:`~pmalab.identify.laws.base.HysteresisLaw` subclass, registered here.
"""

from __future__ import annotations

from pmalab.errors import PmalabError
from pmalab.identify.laws.base import HysteresisLaw, LawParam
from pmalab.identify.laws.bouc_wen import BoucWen
from pmalab.identify.laws.duhem import Duhem

__all__ = ["LAWS", "BoucWen", "Duhem", "HysteresisLaw", "LawParam", "get_law"]

#: every law by the id users type (``--model``)
LAWS: dict[str, type[HysteresisLaw]] = {cls.name: cls for cls in (BoucWen, Duhem)}


def get_law(name: str) -> HysteresisLaw:
    """A law instance by id (one clear line listing the valid ids if unknown)."""
    try:
        return LAWS[name]()
    except KeyError:
        raise PmalabError(f"unknown model '{name}' (choose from {', '.join(LAWS)})") from None
