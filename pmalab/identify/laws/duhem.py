"""Duhem hysteresis in the Coleman–Hodgdon form.

    dh = α·|dx|·(a·x − h) + b·dx,   asymmetric:  α → α·(1 + ψ_α·σ),  b → b·(1 + ψ_b·σ)

Linear in h along a segment of constant direction σ, so it is integrated *exactly* for
piecewise-linear x: h(s) = h₀·e^(−αs) + (1 − e^(−αs))·a·x₀ + (b − a)·σ·(1 − e^(−αs))/α
+ a·σ·s, s = |dx| (the α → 0 limit with expm1).

Sign: a physical loop (tension higher while stretching) needs b − a < 0.
Identifiability: with F = k·x + c0 + h the force depends on k + a only (write h = a·x + u:
u obeys du = −α|dx|·u + (b − a)·dx), so a is held at 0 by default.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import ClassVar

import numpy as np
from numba import njit

from pmalab.identify.laws._loop import loop_half_width
from pmalab.identify.laws.base import HysteresisLaw, LawParam


@njit(cache=True, fastmath=False)
def duhem_segment(hk, x0, x1, alpha, a, b, psi_alpha, psi_b):
    """h after the segment x0 → x1 (mm), exact."""
    dx = x1 - x0
    if dx == 0.0:
        return hk
    sigma = 1.0 if dx > 0.0 else -1.0
    s = abs(dx)
    al = alpha * (1.0 + psi_alpha * sigma)
    bb = b * (1.0 + psi_b * sigma)
    z = al * s
    E = math.exp(-z)
    G = -math.expm1(-z)
    S = G / al if abs(al) > 1e-12 else s
    return hk * E + G * a * x0 + (bb - a) * sigma * S + a * sigma * s


@njit(cache=True, fastmath=False)
def duhem_kernel(hk, x0, x1, prm):
    """One segment with prm = (alpha, a, b, h0, psi_alpha, psi_b)."""
    return duhem_segment(hk, x0, x1, prm[0], prm[1], prm[2], prm[4], prm[5])


@njit(cache=True, fastmath=False)
def duhem_h(x, alpha, a, b, h0, psi_alpha=0.0, psi_b=0.0):
    """h[k] for the Coleman–Hodgdon Duhem law driven by ``x`` (mm); exact per segment."""
    N = x.shape[0]
    h = np.empty(N)
    h[0] = h0
    hk = h0
    for k in range(N - 1):
        hk = duhem_segment(hk, x[k], x[k + 1], alpha, a, b, psi_alpha, psi_b)
        h[k + 1] = hk
    return h


@njit(cache=True, fastmath=False)
def duhem_h_many(x, P):
    """:func:`duhem_h` along ``x`` for each row of P = (alpha, a, b, h0, psi_alpha, psi_b)
    (one compiled call for a Jacobian's columns; each row the same numbers as its own)."""
    out = np.empty((P.shape[0], x.shape[0]))
    if x.shape[0] == 0:
        return out
    # written sample by sample (a whole-row assignment's shape check would make numba
    # compile its error-message code: about a second of a cold process's start)
    for j in range(P.shape[0]):
        q = P[j]
        hk = q[3]
        out[j, 0] = hk
        for k in range(x.shape[0] - 1):
            hk = duhem_segment(hk, x[k], x[k + 1], q[0], q[1], q[2], q[4], q[5])
            out[j, k + 1] = hk
    return out


def _args(theta: Mapping[str, float], extras: Mapping[str, float] | None) -> tuple[float, ...]:
    e = extras or {}
    return (
        float(theta["alpha"]),
        float(theta["a"]),
        float(theta["b"]),
        float(e.get("psi_alpha", 0.0)),
        float(e.get("psi_b", 0.0)),
    )


class Duhem(HysteresisLaw):
    name = "duhem"
    order = 2
    params = (
        LawParam(
            "alpha",
            1.0,
            1e-4,
            100.0,
            "1/mm",
            "rate at which h approaches a·x (inverse memory length)",
        ),
        LawParam("a", 0.0, -1e4, 1e4, "N/mm", "slope of the anhysteretic curve"),
        LawParam("b", -50.0, -1e4, 1e4, "N/mm", "initial slope of h after a reversal"),
        LawParam("h0", 0.0, -1e4, 1e4, "N", "initial hysteretic force"),
    )
    extras = ("psi_alpha", "psi_b")
    default_fixed: ClassVar[dict[str, float]] = {"a": 0.0}
    default_fixed_why: ClassVar[dict[str, str]] = {
        "a": "a fixed at 0 (default): F depends on k + a only, so k and a are not separately identifiable",
    }
    scale_param = "b"

    def shape_grid(self, stroke_mm: float) -> list[dict[str, float]]:
        R = max(stroke_mm, 1e-3)
        return [{"alpha": float(a)} for a in np.geomspace(0.25, 128.0, 10) / R]

    def guess(
        self, x: np.ndarray, force: np.ndarray, v: np.ndarray, fixed=None
    ) -> dict[str, float]:
        w = abs(loop_half_width(x, force, v)) + 1e-3
        alpha = 5.0 / max(float(np.ptp(x)), 1e-3)
        return {"alpha": alpha, "a": 0.0, "b": -w * alpha, "h0": 0.0}

    def h(self, x, theta, extras=None):
        alpha, a, b, pa, pb = _args(theta, extras)
        return duhem_h(
            np.ascontiguousarray(x, dtype=np.float64), alpha, a, b, float(theta["h0"]), pa, pb
        )

    def h_many(self, x, thetas, extras=None):
        rows = []
        for th in thetas:
            alpha, a, b, pa, pb = _args(th, extras)
            rows.append((alpha, a, b, float(th["h0"]), pa, pb))
        P = np.array(rows, dtype=np.float64).reshape(len(rows), 6)
        return duhem_h_many(np.ascontiguousarray(x, dtype=np.float64), P)

    def kernel(self):
        return duhem_kernel

    def stepper(self, theta, extras=None) -> Callable[[float, float, float], float]:
        alpha, a, b, pa, pb = _args(theta, extras)

        def step(h: float, x_prev: float, x: float) -> float:
            return duhem_segment(h, x_prev, x, alpha, a, b, pa, pb)

        return step
