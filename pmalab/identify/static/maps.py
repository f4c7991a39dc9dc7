"""Static maps F_s(x, p): the muscle's elastic force–length–pressure surface, one class each.

A static map is the non-hysteretic part of F = F_s(x, p) + h: the force a muscle held at
contraction x (mm) and pressure p (MPa) would pull without friction.  Three are built in:

* ``linear`` — the seeds' ``k(p)·x + c0(p)`` with k and c0 quadratics in p (what the
  isobaric identification fits run by run, here one surface over every run);
* ``chou-hannaford`` — the geometric model of an inextensible braid from virtual work
  (Chou & Hannaford 1996, "Measurement and modeling of McKibben pneumatic artificial
  muscles", IEEE Trans. Robotics and Automation 12(1):90–102): F = (π·D0²·p/4)·(3cos²θ − 1)
  with D0 the diameter at θ = 90°.  With the relaxed braid angle θ0, relaxed diameter
  Di = D0·sin θ0 and length L0 (cos θ = cos θ0·(1 − k·ε), ε = x/L0) and the end-effect
  factor k of Tondu & Lopez (2000, "Modeling and control of McKibben artificial muscle robot
  actuators", IEEE Control Systems Magazine 20(2):15–38 — the capped ends stay narrow, so
  the cylindrical part contracts k·ε)::

      F_s = (π·Di²·p/4)·[3·(1 − k·ε)²/tan²θ0 − 1/sin²θ0] + F_off

  Fitted: θ0 (degrees), Di (mm), k (−), F_off (N); L0 is the user's measured length
  (``--length``; only k/L0 is identifiable from force data);
* ``tondu-lopez`` — Tondu & Lopez's form F_s = π·r0²·p·[a·(1 − k·ε)² − b] + F_off with a
  and b free (for an ideal braid a = 3/tan²θ0, b = 1/sin²θ0; fitted apart they absorb the
  bladder's elasticity and wall thickness), r0 = Di/2 and L0 the user's measurements
  (``--diameter``, ``--length``).

Units: x contraction in mm (positive = shorter), p gauge MPa (= N/mm², so mm² · MPa = N),
F tension in N.  Each map can give start values from data in closed form (a least-squares
quadratic in ε per unit pressure, solved back for its parameters).
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


def _quadratic_per_pressure(
    eps: np.ndarray, p: np.ndarray, force: np.ndarray
) -> tuple[float, float, float, float]:
    """Least squares F ≈ p·(α0 + α1·ε + α2·ε²) + F_off: (α0, α1, α2, F_off)."""
    A = np.column_stack([p, p * eps, p * eps**2, np.ones_like(p)])
    coef, *_ = np.linalg.lstsq(A, force, rcond=None)
    return float(coef[0]), float(coef[1]), float(coef[2]), float(coef[3])


class LinearMap(StaticMap):
    """k(p)·x + c0(p), each a quadratic in p (the seeds' linear component as a surface)."""

    name = "linear"
    title = "k(p)·x + c0(p)"
    order = 1
    params = (
        MapParam("k0", -20.0, -1e4, 1e4, "N/mm", "stiffness at p = 0"),
        MapParam("k1", 0.0, -1e5, 1e5, "N/mm/MPa", "stiffness: linear pressure term"),
        MapParam("k2", 0.0, -1e5, 1e5, "N/mm/MPa²", "stiffness: quadratic pressure term"),
        MapParam("c0", 0.0, -1e5, 1e5, "N", "tension at x = 0, p = 0"),
        MapParam("c1", 1000.0, -1e6, 1e6, "N/MPa", "tension at x = 0: linear pressure term"),
        MapParam("c2", 0.0, -1e6, 1e6, "N/MPa²", "tension at x = 0: quadratic pressure term"),
    )

    def force(self, x, p, theta):
        k = theta["k0"] + theta["k1"] * p + theta["k2"] * p**2
        return k * x + theta["c0"] + theta["c1"] * p + theta["c2"] * p**2

    def guess(self, x, p, force):
        A = np.column_stack([x, x * p, x * p**2, np.ones_like(p), p, p**2])
        coef, *_ = np.linalg.lstsq(A, force, rcond=None)
        return dict(zip(("k0", "k1", "k2", "c0", "c1", "c2"), map(float, coef), strict=True))


class ChouHannaford(StaticMap):
    """Chou & Hannaford's geometric model with Tondu & Lopez's end-effect factor."""

    name = "chou-hannaford"
    title = "Chou–Hannaford geometric (end-effect k)"
    order = 2
    needs = ("length_mm",)
    params = (
        MapParam(
            "theta0_deg", 25.0, 5.0, 54.0, "deg", "relaxed braid angle from the muscle's axis"
        ),
        MapParam("diameter_mm", 10.0, 0.5, 200.0, "mm", "relaxed outer diameter Di"),
        MapParam("end_effect", 1.2, 0.5, 4.0, "-", "k: the cylindrical part contracts k·ε"),
        MapParam("offset_N", 0.0, -1e4, 1e4, "N", "force offset (load cell pretension)"),
    )

    def force(self, x, p, theta):
        th = math.radians(theta["theta0_deg"])
        eps = x / float(self.geometry.length_mm or 1.0)
        area = math.pi * theta["diameter_mm"] ** 2 / 4.0
        shape = 3.0 * (1.0 - theta["end_effect"] * eps) ** 2 / math.tan(th) ** 2
        return area * p * (shape - 1.0 / math.sin(th) ** 2) + theta["offset_N"]

    def guess(self, x, p, force):
        eps = x / float(self.geometry.length_mm or 1.0)
        a0, a1, a2, off = _quadratic_per_pressure(eps, p, force)
        # α2 = 3·A·k²·u, α1 = −6·A·k·u, α0 = A·(2u − 1), u = 1/tan²θ0, A = π·Di²/4
        out = {q.name: q.init for q in self.params}
        out["offset_N"] = off
        if a1 < 0 and a2 > 0:
            k = -2.0 * a2 / a1
            au = -a1 / (6.0 * k)
            area = 2.0 * au - a0
            if area > 0 and au > 0:
                u = au / area
                out.update(
                    theta0_deg=math.degrees(math.atan(1.0 / math.sqrt(u))),
                    diameter_mm=math.sqrt(4.0 * area / math.pi),
                    end_effect=k,
                )
                return self.clip(out)
        if a0 > 0:  # no curvature to read: the braid angle's default, the area from α0
            u = 1.0 / math.tan(math.radians(out["theta0_deg"])) ** 2
            out["diameter_mm"] = math.sqrt(4.0 * a0 / (2.0 * u - 1.0) / math.pi)
        return self.clip(out)

    def derived(self, theta):
        th = math.radians(theta["theta0_deg"])
        k = theta["end_effect"]
        L0 = float(self.geometry.length_mm or 0.0)
        eps_max = (1.0 - math.cos(th) / math.sqrt(3.0)) / k
        return {
            "initial_radius_mm": (theta["diameter_mm"] / 2.0, "mm", "relaxed outer radius r0"),
            "max_contraction_mm": (
                eps_max * L0,
                "mm",
                "free contraction (F_s = 0 without offset): 1 − k·ε = cos θ0/√3",
            ),
            "max_contraction_percent": (100.0 * eps_max, "%", "of the relaxed length"),
            "braid_length_mm": (
                L0 / math.cos(th),
                "mm",
                "one fibre's length b = L0/cos θ0 (the cylindrical model's)",
            ),
        }


class TonduLopez(StaticMap):
    """Tondu & Lopez's static model with a and b free (r0 and L0 measured)."""

    name = "tondu-lopez"
    title = "Tondu–Lopez π·r0²·p·[a(1−kε)² − b]"
    order = 3
    needs = ("length_mm", "diameter_mm")
    params = (
        MapParam("a", 15.0, 0.0, 1e3, "-", "braid coefficient a (ideal braid: 3/tan²θ0)"),
        MapParam("b", 6.0, 0.0, 1e3, "-", "braid coefficient b (ideal braid: 1/sin²θ0)"),
        MapParam("end_effect", 1.2, 0.5, 4.0, "-", "k: the cylindrical part contracts k·ε"),
        MapParam("offset_N", 0.0, -1e4, 1e4, "N", "force offset (load cell pretension)"),
    )

    @property
    def _area(self) -> float:
        return math.pi * float(self.geometry.diameter_mm or 0.0) ** 2 / 4.0

    def force(self, x, p, theta):
        eps = x / float(self.geometry.length_mm or 1.0)
        shape = theta["a"] * (1.0 - theta["end_effect"] * eps) ** 2 - theta["b"]
        return self._area * p * shape + theta["offset_N"]

    def guess(self, x, p, force):
        eps = x / float(self.geometry.length_mm or 1.0)
        a0, a1, a2, off = _quadratic_per_pressure(eps, p, force)
        # α2 = A·a·k², α1 = −2·A·a·k, α0 = A·(a − b)
        out = {q.name: q.init for q in self.params}
        out["offset_N"] = off
        A = self._area
        if a1 < 0 and a2 > 0:
            k = -2.0 * a2 / a1
            a = -a1 / (2.0 * A * k)
            out.update(a=a, b=a - a0 / A, end_effect=k)
        elif a0 > 0:
            out["b"] = out["a"] - a0 / A
        return self.clip(out)

    def derived(self, theta):
        out = {}
        if theta["a"] > 0:
            out["braid_angle_from_a_deg"] = (
                math.degrees(math.atan(math.sqrt(3.0 / theta["a"]))),
                "deg",
                "θ0 with a = 3/tan²θ0 (equal to the one from b for an ideal braid)",
            )
        if theta["b"] >= 1.0:
            out["braid_angle_from_b_deg"] = (
                math.degrees(math.asin(math.sqrt(1.0 / theta["b"]))),
                "deg",
                "θ0 with b = 1/sin²θ0",
            )
        return out


def get_static_map(name: str, geometry: Geometry | None = None) -> StaticMap:
    """A static map by id (one clear line listing the valid ids if unknown)."""
    return STATIC_MAPS.lookup(name)(geometry)
