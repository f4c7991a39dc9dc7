"""``tondu-lopez``: F_s = π·r0²·p·[a·(1 − k·ε)² − b] + F_off with a and b free.

Tondu & Lopez (2000, "Modeling and control of McKibben artificial muscle robot actuators",
IEEE Control Systems Magazine 20(2):15–38); for an ideal braid a = 3/tan²θ0 and
b = 1/sin²θ0 — fitted apart they absorb the bladder's elasticity and wall thickness.
r0 = Di/2 and L0 are the user's measurements (``--diameter``, ``--length``).
"""

from __future__ import annotations

import math

from pmalab.identify.static.maps.base import MapParam, StaticMap, quadratic_per_pressure


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
        a0, a1, a2, off = quadratic_per_pressure(eps, p, force)
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
