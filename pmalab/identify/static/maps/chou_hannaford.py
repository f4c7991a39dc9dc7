"""``chou-hannaford``: the geometric model of an inextensible braid from virtual work.

Chou & Hannaford (1996, "Measurement and modeling of McKibben pneumatic artificial
muscles", IEEE Trans. Robotics and Automation 12(1):90–102): F = (π·D0²·p/4)·(3cos²θ − 1)
with D0 the diameter at θ = 90°.  With the relaxed braid angle θ0, relaxed diameter
Di = D0·sin θ0 and length L0 (cos θ = cos θ0·(1 − k·ε), ε = x/L0) and the end-effect factor
k of Tondu & Lopez (2000, "Modeling and control of McKibben artificial muscle robot
actuators", IEEE Control Systems Magazine 20(2):15–38 — the capped ends stay narrow, so the
cylindrical part contracts k·ε)::

    F_s = (π·Di²·p/4)·[3·(1 − k·ε)²/tan²θ0 − 1/sin²θ0] + F_off

Fitted: θ0 (degrees), Di (mm), k (−), F_off (N); L0 is the user's measured length
(``--length``; only k/L0 is identifiable from force data).
"""

from __future__ import annotations

import math

from pmalab.identify.static.maps.base import MapParam, StaticMap, quadratic_per_pressure


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
        a0, a1, a2, off = quadratic_per_pressure(eps, p, force)
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
