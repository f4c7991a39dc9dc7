"""One information criterion for every fit: per-run fits, the joint pressure fit's pruning
and the pressure-order choice all call :func:`pmalab.identify.metrics.information_criteria`."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pmalab.identify.estimation.basis import fit_polynomial
from pmalab.identify.metrics import information_criteria


def test_values_and_the_effective_count():
    aic, bic = information_criteria(rss=50.0, n=100, k=3)
    ll = 100 * math.log(0.5)
    assert aic == pytest.approx(ll + 6) and bic == pytest.approx(ll + 3 * math.log(100))
    # an autocorrelated residual counts fewer independent rows: both shrink toward k
    aic2, bic2 = information_criteria(rss=50.0, n=100, k=3, n_eff=10)
    assert aic2 == pytest.approx(10 * math.log(0.5) + 6)
    assert bic2 == pytest.approx(10 * math.log(0.5) + 3 * math.log(10))
    assert np.isfinite(information_criteria(0.0, 10, 1)[0])  # a perfect fit is finite


def test_pressure_order_choice_is_the_bic_it_always_was():
    """The order choice through the shared function equals the formula it replaced,
    ``n·ln(max(RSS, floor)/n) + (d+1)·ln n``, on 200 random campaigns of 6 levels."""
    from pmalab.identify.estimation.basis import rss_floor

    rng = np.random.default_rng(0)
    p = np.linspace(0.1, 0.6, 6)
    for _ in range(200):
        y = rng.normal(0, 1, 3) @ np.vander(p, 3, increasing=True).T + rng.normal(0, 0.05, 6)
        fit = fit_polynomial(p, y, select=True)
        floor, n, best, deg = rss_floor(y, np.ones(6)), 6, float("inf"), 0
        for d in range(3):
            c = np.polyfit(p, y, d)
            rss = float(np.sum((y - np.polyval(c, p)) ** 2))
            b = n * math.log(max(rss, floor) / n) + (d + 1) * math.log(n)
            if b < best - 1e-9:
                best, deg = b, d
        assert fit.degree == deg
