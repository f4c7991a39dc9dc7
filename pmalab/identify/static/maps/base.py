"""The static-map contract: :class:`StaticMap`, its parameters and the registry.

A static map is the non-hysteretic part of F = F_s(x, p) + h: the force a muscle held at
contraction x (mm) and pressure p (MPa) would pull without friction.  Each map is one
file in this folder holding one :class:`StaticMap` subclass that sets ``name``; it
registers itself in :data:`STATIC_MAPS` when its file is imported (``--static NAME``).

Units: x contraction in mm (positive = shorter), p gauge MPa (= N/mm², so mm² · MPa = N),
F tension in N.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pmalab.errors import ConfigError
from pmalab.registry import Registry


@dataclass(frozen=True)
class MapParam:
    """A static-map parameter: start value, bounds, unit and meaning."""

    name: str
    init: float
    lo: float
    hi: float
    unit: str
    doc: str


@dataclass(frozen=True)
class Geometry:
    """What the user measured on the muscle: relaxed active length and outer diameter (mm)."""

    length_mm: float | None = None
    diameter_mm: float | None = None


#: every static map by the id users type (``--static``)
STATIC_MAPS: Registry[type[StaticMap]] = Registry("static map")


class StaticMap:
    """Base class of a static map (subclass, set ``name`` and ``params``, write ``force``)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("name"):
            STATIC_MAPS.register(cls.name, cls, title=cls.title or cls.name, order=cls.order)

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    order: ClassVar[float] = 100.0
    params: ClassVar[tuple[MapParam, ...]] = ()
    #: geometry the map needs from the user (``length_mm``, ``diameter_mm``)
    needs: ClassVar[tuple[str, ...]] = ()

    def __init__(self, geometry: Geometry | None = None) -> None:
        self.geometry = geometry or Geometry()
        for g in self.needs:
            v = getattr(self.geometry, g)
            if v is None or not (math.isfinite(v) and v > 0):
                opt = {"length_mm": "--length MM", "diameter_mm": "--diameter MM"}[g]
                what = {"length_mm": "relaxed active length", "diameter_mm": "relaxed diameter"}[g]
                raise ConfigError(
                    f"--static {self.name}: give the muscle's {what} with {opt} "
                    "(measured; the force data cannot tell it)"
                )

    def force(self, x: np.ndarray, p: np.ndarray, theta: Mapping[str, float]) -> np.ndarray:
        """F_s (N) at contraction ``x`` (mm) and pressure ``p`` (MPa)."""
        raise NotImplementedError

    def guess(self, x: np.ndarray, p: np.ndarray, force: np.ndarray) -> dict[str, float]:
        """Start values from data (contraction mm, pressure MPa, force N)."""
        return {q.name: q.init for q in self.params}

    def derived(self, theta: Mapping[str, float]) -> dict[str, tuple[float, str, str]]:
        """Quantities worth reporting that follow from the parameters: name → (value, unit, doc)."""
        return {}

    def clip(self, theta: Mapping[str, float]) -> dict[str, float]:
        """``theta`` inside the parameters' bounds."""
        out = dict(theta)
        for q in self.params:
            if q.name in out:
                out[q.name] = float(min(max(out[q.name], q.lo), q.hi))
        return out


def quadratic_per_pressure(
    eps: np.ndarray, p: np.ndarray, force: np.ndarray
) -> tuple[float, float, float, float]:
    """Least squares F ≈ p·(α0 + α1·ε + α2·ε²) + F_off: (α0, α1, α2, F_off)."""
    A = np.column_stack([p, p * eps, p * eps**2, np.ones_like(p)])
    coef, *_ = np.linalg.lstsq(A, force, rcond=None)
    return float(coef[0]), float(coef[1]), float(coef[2]), float(coef[3])
