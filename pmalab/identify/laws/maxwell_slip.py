"""Maxwell-slip hysteresis: parallel elasto-slide elements with free stiffness and slip force.

    z_i ← clip(z_i − k_i·Δx, −f_i, +f_i),   h = Σ z_i,   f_i = k_i·d_i

Four elements, each with a stiffness k_i (N/mm) and a slip displacement d_i (mm: how far the
path must move after a reversal before the element slides; f_i = k_i·d_i is its slip force).
This is the PMA friction model of Minh et al. (the seed papers' reference for braid
friction): each fibre contact sticks, loads elastically and slips.  Compared with
Prandtl-Ishlinskii (fixed thresholds, linear weights) the slip displacements are fitted, so
four elements do what eight fixed operators do, at the price of a nonlinear fit (start:
d_i on a geometric grid over the stroke, k_i by non-negative least squares).  Same
integrator (:mod:`._slide`), same sign convention: tension higher while stretching.

The slip displacements are a property of the braid, the same at every pressure (the slip
*forces* grow with pressure): they are the law's ``shared_shape``.  A campaign fits them per
run, then holds them at one reference run's values on every run (so element i is the same
element at every pressure and k_i(p) is a smooth law), and the joint fit refines them as
constants.  The elements are exchangeable: :meth:`MaxwellSlip.canonical` orders them by slip
displacement.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.optimize import nnls

from pmalab.identify.laws._slide import (
    column,
    nonneg,
    play_basis,
    slide_h_rows,
)
from pmalab.identify.laws.base import LawParam
from pmalab.identify.laws.element_sum import ElementSum

ELEMENTS = 4
_K = tuple(f"k{i + 1}" for i in range(ELEMENTS))
_D = tuple(f"d{i + 1}" for i in range(ELEMENTS))


def _kf(theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    k = np.array([max(float(theta[n]), 0.0) for n in _K])
    d = np.array([max(float(theta[n]), 0.0) for n in _D])
    return k, k * d


class MaxwellSlip(ElementSum):
    name = "maxwell-slip"
    order = 3
    title = "Maxwell-slip (elasto-slide elements)"
    params = (
        *(
            LawParam(n, 10.0, 0.0, 1e4, "N/mm", f"stiffness of element {i + 1}")
            for i, n in enumerate(_K)
        ),
        *(
            LawParam(n, 0.5 * 3.0**i, 1e-3, 50.0, "mm", f"slip displacement of element {i + 1}")
            for i, n in enumerate(_D)
        ),
        LawParam("h0", 0.0, -1e4, 1e4, "N", "initial hysteretic force"),
    )
    state_size = ELEMENTS
    scale_param = None
    shared_shape = _D
    structures = ("scaled", "scaled-thresholds")

    def guess(
        self, x: np.ndarray, force: np.ndarray, v: np.ndarray, fixed=None
    ) -> dict[str, float]:
        """Slip displacements on a geometric grid over the stroke (or the ones held fixed),
        stiffnesses by non-negative least squares of F on their elements with k and c0."""
        x = np.asarray(x, dtype=np.float64)
        stroke = max(float(np.ptp(x)), 1e-3)
        d = stroke * np.geomspace(0.01, 0.3, ELEMENTS)
        for i, n in enumerate(_D):
            if fixed and n in fixed:
                d[i] = max(float(fixed[n]), 1e-3)
        B = play_basis(x, d)
        M = np.column_stack([B, x, -x, np.ones_like(x), -np.ones_like(x)])
        sc = np.maximum(np.abs(M).max(axis=0), 1e-12)
        coef, _ = nnls(M / sc, np.asarray(force, dtype=np.float64), maxiter=5000)
        coef = coef / sc
        k = coef[:ELEMENTS]
        out = {n: float(min(max(ki, 1e-3), 1e4)) for n, ki in zip(_K, k)}
        out.update({n: float(di) for n, di in zip(_D, d)})
        out.update(
            k=float(coef[ELEMENTS] - coef[ELEMENTS + 1]),
            c0=float(coef[ELEMENTS + 2] - coef[ELEMENTS + 3]),
            h0=0.0,
        )
        return out

    def canonical(self, theta: Mapping[str, float]) -> dict[str, float]:
        """Elements ordered by slip displacement (smallest first)."""
        out = dict(theta)
        order = np.argsort([float(theta[n]) for n in _D], kind="stable")
        for j, i in enumerate(order):
            out[_K[j]], out[_D[j]] = float(theta[_K[i]]), float(theta[_D[i]])
        return out

    def elements(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """Stiffnesses (N/mm) and slip displacements (mm) of the elements."""
        k = np.array([max(float(theta[n]), 0.0) for n in _K])
        d = np.array([max(float(theta[n]), 0.0) for n in _D])
        return k, d

    def element_names(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        return _K, _D

    def _kf(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        return _kf(theta)

    def h_many(self, x, thetas, extras=None):
        # every row's _kf at once: the same max(k, 0)·max(d, 0), elementwise
        K = nonneg(column(thetas, _K))
        return slide_h_rows(x, K, K * nonneg(column(thetas, _D)), thetas)
