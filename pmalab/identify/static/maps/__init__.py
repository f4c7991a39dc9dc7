"""Static maps F_s(x, p), one file each; :data:`STATIC_MAPS` is the registry.

Adding a map is ONE new file in this folder with a
:class:`~pmalab.identify.static.maps.base.StaticMap` subclass that sets ``name``: every
module here is imported and every such subclass registered (``--static NAME`` then works in
``identify`` and ``diagnose``, and the report draws it).  Built in: ``linear``,
``chou-hannaford``, ``tondu-lopez``.
"""

from __future__ import annotations

import importlib
import pkgutil

from pmalab.identify.static.maps.base import STATIC_MAPS, Geometry, MapParam, StaticMap

__all__ = ["STATIC_MAPS", "Geometry", "MapParam", "StaticMap", "get_static_map"]

for _m in pkgutil.iter_modules(__path__):
    if not _m.name.startswith("_") and _m.name != "base":
        importlib.import_module(f"{__name__}.{_m.name}")


def get_static_map(name: str, geometry: Geometry | None = None) -> StaticMap:
    """A static map by id (one clear line listing the valid ids if unknown)."""
    return STATIC_MAPS.lookup(name)(geometry)
