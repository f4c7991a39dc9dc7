"""The one solver and the one uncertainty estimate of every fit pmalab makes.

:func:`solve` is SciPy's trust-region reflective least squares (bounds, ``x_scale='jac'``;
:mod:`~pmalab.identify.estimation.trust_region`: the same method with each step's SVD taken
on the Jacobian's triangular factor) started strictly inside the bounds, with BLAS
single-threaded (tall-skinny Jacobian products are slower threaded; batches parallelise
across runs instead).

:func:`uncertainty`: covariance s²·(JᵀJ)⁻¹ at the optimum, computed on the column-scaled
Jacobian (pseudo-inverse, so a degenerate direction gives large errors instead of a crash),
inflated by N/N_eff.  Residuals of a hysteresis fit are strongly autocorrelated (a model
error persists over a loop), so naive standard errors are optimistic; N_eff is the AR(1)
effective sample size N·(1 − ρ₁)/(1 + ρ₁) from each run's lag-1 residual autocorrelation ρ₁,
summed over the runs of the problem.  The same N_eff enters every information criterion.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import OptimizeResult
from threadpoolctl import ThreadpoolController

from pmalab.identify.estimation.trust_region import least_squares_trf
from pmalab.identify.metrics import information_criteria

STDERR_METHOD = (
    "Jacobian covariance s^2 (J^T J)^-1 inflated by N/N_eff, N_eff = N(1-r1)/(1+r1) "
    "from the lag-1 residual autocorrelation r1 of each run (AR(1) effective sample size)"
)

#: what :func:`solve` is, for the method block of an identification file (files written
#: before the solver was re-hosted say "scipy least_squares (trf, bounds)", true for them)
SOLVER_METHOD = (
    "SciPy's trust-region reflective method (trf, bounds, x_scale='jac') in "
    "pmalab.identify.estimation.trust_region: SciPy's steps, each step's SVD taken on the "
    "Jacobian's QR factor (SciPy's least_squares itself where its step helpers are missing)"
)


_BLAS: ThreadpoolController | None = None
_BLAS_DEPTH = 0


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS limited to one thread inside the block (small dense problems run slower on
    several threads; batches parallelise across runs instead).

    The libraries are looked up once per process (``threadpoolctl`` scans the loaded
    shared objects each time it is asked, 4 ms a call), and nested blocks cost nothing.
    """
    global _BLAS, _BLAS_DEPTH
    if _BLAS_DEPTH:
        yield
        return
    if _BLAS is None:
        _BLAS = ThreadpoolController()
    _BLAS_DEPTH += 1
    try:
        with _BLAS.limit(limits=1, user_api="blas"):
            yield
    finally:
        _BLAS_DEPTH -= 1


def inside(z0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``z0`` moved strictly inside the bounds (the trust-region method's requirement)."""
    span = np.where(np.isfinite(hi - lo), hi - lo, np.abs(z0) + 1.0)
    return np.clip(z0, lo + 1e-9 * span, hi - 1e-9 * span)


def solve(
    residual: Callable[[np.ndarray], np.ndarray],
    jac: Callable[[np.ndarray], np.ndarray],
    z0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    max_nfev: int,
    tol: float = 1e-8,
) -> OptimizeResult:
    """Bounded nonlinear least squares from ``z0`` (see the module docstring)."""
    with one_blas_thread():
        return least_squares_trf(
            residual,
            jac,
            inside(np.asarray(z0, float), lo, hi),
            lo,
            hi,
            ftol=tol,
            xtol=tol,
            gtol=tol,
            max_nfev=max_nfev,
        )


def autocorr1(r: np.ndarray) -> float:
    """Lag-1 autocorrelation of a residual (0 for a constant one)."""
    r = r - float(np.mean(r))
    d = float(r @ r)
    return float(r[1:] @ r[:-1]) / d if d > 0 else 0.0


def n_eff(residual: np.ndarray, rows: Sequence[slice] | None = None) -> float:
    """AR(1) effective sample size of ``residual``, summed over its runs (``rows``)."""
    rows = rows or [slice(0, residual.shape[0])]
    tot = 0.0
    for s in rows:
        r = residual[s]
        rho = min(max(autocorr1(r), 0.0), 0.999)
        tot += r.shape[0] * (1.0 - rho) / (1.0 + rho)
    return max(tot, 1.0)


@dataclass
class Uncertainty:
    """Standard errors, correlation, conditioning and N_eff at an optimum."""

    stderr: np.ndarray  # same order as the solution vector (NaN where undetermined)
    correlation: np.ndarray
    condition: float  # of the column-scaled JᵀJ
    n_eff: float

    def ic(self, rss: float, n: int, k: int) -> tuple[float, float]:
        """(AIC, BIC) with this fit's N_eff (:func:`information_criteria`)."""
        return information_criteria(rss, n, k, self.n_eff)


def uncertainty(J: np.ndarray, r: np.ndarray, rows: Sequence[slice] | None = None) -> Uncertainty:
    """Covariance of the least-squares solution (see the module docstring).

    Runs with one BLAS thread, like :func:`solve`: a joint campaign's Jacobian is tall and
    skinny (thousands of rows, tens of columns), where a second thread only adds hand-offs,
    and on a busy machine a threaded SVD waiting for its other thread took a second
    instead of tens of milliseconds.
    """
    with one_blas_thread():
        return _uncertainty(J, r, rows)


def _uncertainty(J: np.ndarray, r: np.ndarray, rows: Sequence[slice] | None) -> Uncertainty:
    J = np.asarray(J, dtype=float)
    r = np.asarray(r, dtype=float)
    N, p = J.shape
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms
    sv = np.linalg.svd(Js, compute_uv=False)
    cond = float((sv[0] / sv[-1]) ** 2) if sv.size and sv[-1] > 0 else float("inf")
    cov_s = np.linalg.pinv(Js.T @ Js, rcond=1e-15)
    ne = max(n_eff(r, rows), p + 1.0)
    s2 = float(r @ r) / max(N - p, 1)
    cov = s2 * (N / ne) * cov_s / np.outer(norms, norms)
    var = np.diag(cov).copy()
    se = np.sqrt(np.where(var > 0, var, np.nan))
    d = np.sqrt(np.abs(np.diag(cov_s)))
    d[d == 0] = 1.0
    corr = np.clip(cov_s / np.outer(d, d), -1.0, 1.0)
    return Uncertainty(stderr=se, correlation=corr, condition=cond, n_eff=ne)
