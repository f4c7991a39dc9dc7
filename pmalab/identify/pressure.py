"""Pressure dependence: every parameter as θ(p) = q0 + q1·p + q2·p² (p in MPa).

The seeds fit each identified parameter as a quadratic in the muscle pressure over the
identification pressure levels.  We weight each run's value by 1/stderr (the
autocorrelation-corrected standard error of :mod:`pmalab.identify.fit`), so a badly
determined value does not drag the curve; a parameter that was held fixed has no stderr
and gets equal weights.  With fewer than three distinct pressure levels the degree drops
(two levels: a line; one level: a constant) and the unused coefficients are 0 — the fit
records the degree used.  R² is the weighted coefficient of determination.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass
class PressureFit:
    """θ(p) = q0 + q1·p + q2·p² for one parameter, with its fit statistics."""

    name: str
    coef: tuple[float, float, float]
    degree: int
    r2: float
    pressures: list[float]
    values: list[float]
    stderr: list[float | None]
    residuals: list[float]

    def __call__(self, p: float | np.ndarray) -> float | np.ndarray:
        q0, q1, q2 = self.coef
        return q0 + q1 * p + q2 * p * p

    def stats(self) -> dict:
        """The JSON block (``pressure_fit_stats[name]``)."""
        return {"r2": self.r2, "degree": self.degree, "residuals": self.residuals,
                "pressures": self.pressures, "values": self.values, "stderr": self.stderr}


def fit_quadratic(
    name: str,
    pressures: Sequence[float],
    values: Sequence[float],
    stderr: Sequence[float | None] | None = None,
    max_degree: int = 2,
) -> PressureFit:
    """Weighted least-squares quadratic of ``values`` against ``pressures`` (MPa)."""
    p = np.asarray(pressures, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    se_in = list(stderr) if stderr is not None else [None] * len(p)
    se = np.array([np.nan if s is None else float(s) for s in se_in])
    good = np.isfinite(se) & (se > 0)
    if good.any():
        # runs without a usable stderr get the median of the others (not infinite weight)
        se = np.where(good, se, float(np.median(se[good])))
        w = 1.0 / se
    else:
        w = np.ones_like(y)
    levels = np.unique(np.round(p, 4))
    deg = int(min(max_degree, max(len(levels) - 1, 0)))
    V = np.vander(p, deg + 1, increasing=True)
    coef, *_ = np.linalg.lstsq(V * w[:, None], y * w, rcond=None)
    fitted = V @ coef
    res = y - fitted
    yw = float(np.sum(w * w * y) / np.sum(w * w))
    ss_tot = float(np.sum((w * (y - yw)) ** 2))
    ss_res = float(np.sum((w * res) ** 2))
    if ss_tot > 1e-24 * max(1.0, float(np.sum((w * y) ** 2))):
        r2 = 1.0 - ss_res / ss_tot
    else:
        r2 = 1.0 if ss_res <= 1e-24 * max(1.0, float(np.sum((w * y) ** 2))) else 0.0
    q = [0.0, 0.0, 0.0]
    q[: deg + 1] = [float(c) for c in coef]
    return PressureFit(name=name, coef=(q[0], q[1], q[2]), degree=deg, r2=float(r2),
                       pressures=[float(v) for v in p], values=[float(v) for v in y],
                       stderr=[None if s is None else float(s) for s in se_in],
                       residuals=[float(v) for v in res])
