"""Static characterization: a static map F_s(x, p) (:mod:`.maps`) plus a hysteresis law driven
by the pressure, the contraction or both (:mod:`.fit`), fitted over runs of any test type."""

from __future__ import annotations

from pmalab.identify.static.fit import (
    DRIVES,
    StaticFit,
    StaticModel,
    default_drive,
    fit_static,
    predict_run,
    summary_doc,
)
from pmalab.identify.static.maps import STATIC_MAPS, Geometry, StaticMap, get_static_map

__all__ = [
    "DRIVES",
    "STATIC_MAPS",
    "Geometry",
    "StaticFit",
    "StaticMap",
    "StaticModel",
    "default_drive",
    "fit_static",
    "get_static_map",
    "predict_run",
    "summary_doc",
]
