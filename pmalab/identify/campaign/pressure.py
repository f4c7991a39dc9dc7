"""Pressure dependence: every parameter as θ(p) = q0 + q1·p + q2·p² (p in MPa).

The seeds fit each identified parameter as a quadratic in the muscle pressure over the
identification pressure levels.  We weight each run's value by 1/stderr (the
autocorrelation-corrected standard error of :mod:`pmalab.identify.estimation.single`), so a badly
determined value does not drag the curve; a parameter that was held fixed has no stderr
and gets equal weights.  With fewer than three distinct pressure levels the degree drops
(two levels: a line; one level: a constant) and the unused coefficients are 0 — the fit
records the degree used.  R² is the weighted coefficient of determination.

These per-run quadratics are the *start* of the campaign's pressure laws: the campaign then
refines the coefficients jointly on the free-run error of all runs, with each parameter's
order chosen (0, 1 or 2) — :mod:`pmalab.identify.estimation.joint`.  A refined fit keeps the per-run
quadratic in ``per_run_coef`` and reports R²/residuals of the per-run values about the
refined law (``method = "joint"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pmalab.identify.estimation.basis import fit_polynomial, weights
from pmalab.identify.estimation.basis import weighted_r2 as _r2


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
    #: "per-run" (the weighted quadratic through the per-run values) or "joint" (refined)
    method: str = "per-run"
    #: the per-run weighted quadratic and its R² (kept when ``method == "joint"``)
    per_run_coef: tuple[float, float, float] | None = None
    per_run_r2: float | None = None
    per_run_degree: int | None = None

    def __call__(self, p: float | np.ndarray) -> float | np.ndarray:
        q0, q1, q2 = self.coef
        return q0 + q1 * p + q2 * p * p

    def stats(self) -> dict:
        """The JSON block (``pressure_fit_stats[name]``)."""
        out = {
            "r2": self.r2,
            "degree": self.degree,
            "residuals": self.residuals,
            "pressures": self.pressures,
            "values": self.values,
            "stderr": self.stderr,
            "method": self.method,
        }
        if self.per_run_coef is not None:
            out["per_run_quadratic"] = list(self.per_run_coef)
            out["per_run_r2"] = self.per_run_r2
            out["per_run_degree"] = self.per_run_degree
        return out


def fit_quadratic(
    name: str,
    pressures: Sequence[float],
    values: Sequence[float],
    stderr: Sequence[float | None] | None = None,
    max_degree: int = 2,
) -> PressureFit:
    """Weighted least-squares quadratic of ``values`` against ``pressures`` (MPa): the
    per-run law, through the one polynomial fit
    (:func:`~pmalab.identify.estimation.basis.fit_polynomial`)."""
    se_in = list(stderr) if stderr is not None else [None] * len(values)
    pf = fit_polynomial(pressures, values, weights(se_in, len(se_in)), max_degree=max_degree)
    return PressureFit(
        name=name,
        coef=pf.coef,
        degree=pf.degree,
        r2=float(pf.r2),
        pressures=[float(v) for v in pressures],
        values=[float(v) for v in values],
        stderr=[None if s is None else float(s) for s in se_in],
        residuals=list(pf.residuals),
    )


def weighted_r2(
    values: Sequence[float], fitted: Sequence[float], stderr: Sequence[float | None] | None = None
) -> tuple[float, list[float]]:
    """(weighted R², residuals) of per-run ``values`` about a given law's ``fitted`` values."""
    y = np.asarray(values, dtype=np.float64)
    f = np.asarray(fitted, dtype=np.float64)
    w = weights(list(stderr) if stderr is not None else None, y.shape[0])
    return float(_r2(y, f, w)), [float(v) for v in y - f]
