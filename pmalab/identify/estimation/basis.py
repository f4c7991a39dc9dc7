"""Pressure dependence of a parameter: the basis and the one polynomial fit.

Every muscle parameter is a polynomial of order 0–2 in the nominal muscle pressure p (MPa),
θ(p) = q0 + q1·p + q2·p² (the seeds' quadratics).  Inside the estimator it is written in
Legendre polynomials of u = (2p − p_lo − p_hi)/(p_hi − p_lo) ∈ [−1, 1] over the identified
range: the coefficients are nearly orthogonal (well conditioned) and the top one measures
the curvature (or slope) directly, which the order test needs.  Results are reported as
monomials q.

:func:`fit_polynomial` is the single weighted polynomial fit used for every pressure law
(per-run values → start laws and the reported per-run quadratics).  Its order selection is
robust to round-off: residual sums below :func:`rss_floor` (the machine-precision level of
the data) count as zero, so an exactly linear parameter never gets order 2 on one machine
and order 1 on another.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pmalab.identify.metrics import information_criteria


@dataclass(frozen=True)
class PressureBasis:
    """Legendre basis in u = (2p − p_lo − p_hi)/(p_hi − p_lo) over the identified range."""

    p_lo: float
    p_hi: float

    @classmethod
    def over(cls, pressures: Sequence[float]) -> PressureBasis:
        return cls(float(min(pressures)), float(max(pressures)))

    def u(self, p: float | Sequence[float] | np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        span = self.p_hi - self.p_lo
        if span <= 0:
            return np.zeros_like(p)
        return (2.0 * p - self.p_lo - self.p_hi) / span

    def matrix(self, p: float | Sequence[float] | np.ndarray, degree: int) -> np.ndarray:
        """Rows: pressures; columns P_0..P_degree."""
        u = np.atleast_1d(self.u(p))
        cols = [np.ones_like(u), u, 1.5 * u * u - 0.5][: degree + 1]
        return np.column_stack(cols)

    def to_monomial(self, c: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
        """(q0, q1, q2) of θ(p) = q0 + q1·p + q2·p² equal to Σ c_d·P_d(u(p))."""
        c = list(c) + [0.0] * (3 - len(c))
        nodes = self._nodes()
        vals = self.matrix(nodes, 2) @ np.asarray(c, dtype=np.float64)
        q = np.linalg.solve(np.vander(nodes, 3, increasing=True), vals)
        return float(q[0]), float(q[1]), float(q[2])

    def from_monomial(self, q: Sequence[float], degree: int) -> np.ndarray:
        """Legendre coefficients (degree + 1) of the least-squares fit to q on the range."""
        nodes = self._nodes(7)
        vals = np.vander(nodes, 3, increasing=True) @ np.asarray(list(q) + [0.0] * (3 - len(q)))
        c, *_ = np.linalg.lstsq(self.matrix(nodes, degree), vals, rcond=None)
        return c

    def _nodes(self, m: int = 3) -> np.ndarray:
        if self.p_hi > self.p_lo:
            return np.linspace(self.p_lo, self.p_hi, m)
        # one level: any distinct points (the basis is constant there)
        return self.p_lo + np.linspace(-0.1, 0.1, m)


def rss_floor(y: np.ndarray, w: np.ndarray) -> float:
    """Weighted residual sum of squares that is round-off, not misfit (≈ n·(1e-9·|wy|)²)."""
    scale = float(np.max(np.abs(w * y))) if y.size else 0.0
    return y.size * (1e-9 * max(scale, 1e-300)) ** 2


def weights(
    stderr: Sequence[float | None] | None, n: int, *, floor_at_median: bool = False
) -> np.ndarray:
    """1/stderr weights; missing or zero stderrs get the median of the others (not ∞).

    ``floor_at_median``: stderrs are also floored at their median, so no single
    over-confident run dominates (used for start laws of collinear parameters)."""
    se = np.array([np.nan if s is None else float(s) for s in (stderr or [None] * n)])
    good = np.isfinite(se) & (se > 0)
    if not good.any():
        return np.ones(n)
    med = float(np.median(se[good]))
    se = np.where(good, se, med)
    return 1.0 / (np.maximum(se, med) if floor_at_median else se)


@dataclass(frozen=True)
class PolyFit:
    """A weighted polynomial θ(p) fitted to per-run values (monomial coefficients)."""

    coef: tuple[float, float, float]
    degree: int
    r2: float
    residuals: tuple[float, ...]

    def __call__(self, p: float | np.ndarray) -> float | np.ndarray:
        q0, q1, q2 = self.coef
        return q0 + q1 * p + q2 * p * p


def fit_polynomial(
    p: Sequence[float] | np.ndarray,
    y: Sequence[float] | np.ndarray,
    w: np.ndarray | None = None,
    *,
    max_degree: int = 2,
    select: bool = False,
) -> PolyFit:
    """Weighted least squares of ``y`` on p, order ≤ ``max_degree`` (≤ levels − 1).

    ``select``: choose the order by BIC with an unknown noise scale, where a residual sum
    below :func:`rss_floor` counts as exactly zero (ties go to the lower order).
    R² is the weighted coefficient of determination (1 when y is constant and fitted).
    """
    p_a = np.asarray(p, dtype=np.float64)
    y_a = np.asarray(y, dtype=np.float64)
    w_a = np.ones_like(y_a) if w is None else np.asarray(w, dtype=np.float64)
    n = y_a.shape[0]
    levels = np.unique(np.round(p_a, 4)).shape[0]
    top = int(min(max_degree, max(levels - 1, 0)))
    floor = rss_floor(y_a, w_a)

    def solve(d: int) -> tuple[np.ndarray, float]:
        V = np.vander(p_a, d + 1, increasing=True)
        c, *_ = np.linalg.lstsq(V * w_a[:, None], y_a * w_a, rcond=None)
        return c, float(np.sum((w_a * (y_a - V @ c)) ** 2))

    deg = top
    if select and top > 0:
        best = float("inf")
        for d in range(0, top + 1):
            if d + 1 >= n:
                break
            _, rss = solve(d)
            b = information_criteria(max(rss, floor), n, d + 1)[1]
            if b < best - 1e-9:
                best, deg = b, d
    c, rss = solve(deg)
    q = [0.0, 0.0, 0.0]
    q[: deg + 1] = [float(v) for v in c]
    res = y_a - np.vander(p_a, 3, increasing=True) @ np.asarray(q)
    return PolyFit(
        coef=(q[0], q[1], q[2]),
        degree=deg,
        r2=weighted_r2(y_a, y_a - res, w_a),
        residuals=tuple(float(v) for v in res),
    )


def weighted_r2(y: np.ndarray, fitted: np.ndarray, w: np.ndarray) -> float:
    """Weighted R² of ``fitted`` against ``y`` (1/0 for a constant y fitted exactly/not)."""
    res = y - fitted
    yw = float(np.sum(w * w * y) / np.sum(w * w))
    ss_tot = float(np.sum((w * (y - yw)) ** 2))
    ss_res = float(np.sum((w * res) ** 2))
    tiny = 1e-24 * max(1.0, float(np.sum((w * y) ** 2)))
    if ss_tot > tiny:
        return 1.0 - ss_res / ss_tot
    return 1.0 if ss_res <= tiny else 0.0
