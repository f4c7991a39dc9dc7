"""``linear``: the seeds' k(p)·x + c0(p), k and c0 quadratics in p, as one surface over every
run (what the isobaric identification fits run by run)."""

from __future__ import annotations

import numpy as np

from pmalab.identify.static.maps.base import MapParam, StaticMap


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
