"""Bounded nonlinear least squares: SciPy's trust-region reflective method, with each step's
decomposition done on the Jacobian's triangular factor.

This is ``scipy.optimize.least_squares(method='trf', tr_solver='exact', x_scale='jac',
loss='linear')`` — the same algorithm (Branch, Coleman & Li 1999: Coleman-Li scaling, the
exact trust-region subproblem solved on the SVD of the scaled, augmented Jacobian,
reflected and gradient steps at a bound, the same radius updates and termination tests),
step for step, with one change.  SciPy takes the thin SVD ``U S Vᵀ`` of the augmented
Jacobian (m + n rows, n columns) at every iteration and uses ``U`` only as ``Uᵀ f``.  Here
the tall matrix is first reduced by a QR factorisation, ``J = Q R``, with ``Qᵀ f`` applied
from the Householder reflectors (never formed), and the SVD is taken of the n × n factor:
``R = U_R S Vᵀ``, so ``S`` and ``V`` are the augmented Jacobian's and
``Uᵀ f = U_Rᵀ (Qᵀ f)``.  For the tall Jacobians of a per-run fit (thousands of samples, tens
of parameters) this costs about a third of the full SVD (LAPACK's SVD of a tall matrix does
the same QR, then forms Q and U explicitly); the results agree with SciPy's to round-off,
not bit for bit.

The helpers of the step (subproblem, reflection, radius update, termination) are SciPy's
own (``scipy.optimize._lsq``), so the method is theirs; where a SciPy release no longer
has them, :func:`least_squares_trf` is ``scipy.optimize.least_squares`` itself.

Adapted from SciPy's ``scipy/optimize/_lsq/trf.py`` (``trf_bounds``), Copyright (c)
2001-2002 Enthought, Inc. and 2003-2024 SciPy Developers, BSD 3-Clause licence (the text
is in ``LICENSES/scipy.txt``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.linalg import LinAlgError, norm
from scipy.linalg import lapack
from scipy.optimize import OptimizeResult, least_squares

try:  # SciPy's own step helpers (their names unchanged since SciPy 0.17)
    from scipy.optimize._lsq.common import (
        CL_scaling_vector,
        check_termination,
        compute_grad,
        compute_jac_scale,
        find_active_constraints,
        in_bounds,
        make_strictly_feasible,
        solve_lsq_trust_region,
        update_tr_radius,
    )
    from scipy.optimize._lsq.trf import select_step

    _HAVE_STEP_HELPERS = True
except ImportError:  # pragma: no cover - a SciPy that moved them: its own least_squares
    _HAVE_STEP_HELPERS = False

EPS = np.finfo(float).eps  # SciPy's ``_lsq.common.EPS``

#: SciPy's messages for the same termination statuses
MESSAGES = {
    0: "The maximum number of function evaluations is exceeded.",
    1: "`gtol` termination condition is satisfied.",
    2: "`ftol` termination condition is satisfied.",
    3: "`xtol` termination condition is satisfied.",
    4: "Both `ftol` and `xtol` termination conditions are satisfied.",
}

#: LAPACK's QR, Qᵀ·c and divide-and-conquer SVD (SciPy's default driver), called directly:
#: SciPy's wrappers check and look up the same routines at every call, ~50 µs a step
_GEQRF, _ORMQR, _GESDD = lapack.get_lapack_funcs(("geqrf", "ormqr", "gesdd"), (np.zeros((2, 2)),))


def reduced_svd_uf(A: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s, V, Uᵀ f)`` of the thin SVD ``A = U diag(s) Vᵀ`` of a tall matrix (rows ≥
    columns), by QR first: ``A = Q R``, ``R = U_R diag(s) Vᵀ``, ``Uᵀ f = U_Rᵀ Qᵀ f``.

    Raises ``ValueError`` when ``A`` holds a NaN or an infinity (as SciPy's SVD does), or is
    wide (the trust-region step's augmented Jacobian, m + n rows, never is: m < n is fine)."""
    if not np.isfinite(A).all():
        raise ValueError("array must not contain infs or NaNs")
    n = A.shape[1]
    if A.shape[0] < n:
        raise ValueError(f"reduced_svd_uf needs rows >= columns, got {A.shape}")
    qr, tau, _, info = _GEQRF(A)
    if info != 0:  # pragma: no cover - LAPACK argument error: a bug, not data
        raise ValueError(f"QR factorisation failed (LAPACK info {info})")
    r = np.triu(qr[:n])
    qtf, _, info = _ORMQR("L", "T", qr, tau, f.reshape(-1, 1), max(64, n))
    if info != 0:  # pragma: no cover
        raise ValueError(f"applying Qᵀ failed (LAPACK info {info})")
    ur, s, vt, info = _GESDD(r, compute_uv=1, full_matrices=0, overwrite_a=1)
    if info > 0:
        raise LinAlgError("SVD did not converge")
    if info < 0:  # pragma: no cover
        raise ValueError(f"SVD failed (LAPACK info {info})")
    return s, vt.T, ur.T.dot(qtf[:n, 0])


def least_squares_trf(
    fun: Callable[[np.ndarray], np.ndarray],
    jac: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    *,
    ftol: float,
    xtol: float,
    gtol: float,
    max_nfev: int | None,
) -> OptimizeResult:
    """Minimise ½‖fun(x)‖² over ``lb ≤ x ≤ ub`` (see the module docstring).

    ``x0`` must lie inside the bounds; ``jac(x)`` returns the dense m × n Jacobian;
    ``max_nfev`` ``None`` is SciPy's default, 100 evaluations per variable.  The result has
    SciPy's fields: ``x``, ``cost``, ``fun``, ``jac``, ``grad``, ``optimality``,
    ``active_mask``, ``nfev``, ``njev``, ``status``, ``message``, ``success``."""
    # SciPy's refusals of the arguments (a budget of 0 evaluations would never stop)
    if max_nfev is not None and max_nfev <= 0:
        raise ValueError("`max_nfev` must be None or positive integer.")
    if ftol < EPS and xtol < EPS and gtol < EPS:
        raise ValueError(
            f"At least one of the tolerances must be higher than machine epsilon ({EPS:.2e})."
        )
    lb = np.asarray(lb, dtype=float)
    ub = np.asarray(ub, dtype=float)
    if not _HAVE_STEP_HELPERS:  # SciPy moved its helpers: its own least_squares
        return least_squares(
            fun,
            x0,
            jac=jac,  # pyright: ignore[reportArgumentType]
            bounds=(lb, ub),
            method="trf",
            x_scale="jac",
            ftol=ftol,
            xtol=xtol,
            gtol=gtol,
            max_nfev=max_nfev,
        )
    x0 = np.atleast_1d(np.asarray(x0, dtype=float))
    if lb.shape != x0.shape or ub.shape != x0.shape:
        raise ValueError("Inconsistent shapes between bounds and `x0`.")
    if np.any(lb >= ub):
        raise ValueError("Each lower bound must be strictly less than each upper bound.")
    if not in_bounds(x0, lb, ub):
        raise ValueError("Initial guess is outside of provided bounds")
    x0 = make_strictly_feasible(x0, lb, ub)
    f0 = np.atleast_1d(np.asarray(fun(x0.copy()), dtype=float))
    if f0.ndim != 1:
        raise ValueError(f"`fun` must return at most 1-d array_like. f0.shape: {f0.shape}")
    if not np.all(np.isfinite(f0)):
        raise ValueError("Residuals are not finite in the initial point.")
    J0 = np.atleast_2d(np.asarray(jac(x0.copy()), dtype=float))
    if J0.shape != (f0.size, x0.size):
        raise ValueError(
            f"The return value of `jac` has wrong shape: expected {(f0.size, x0.size)}, "
            f"actual {J0.shape}."
        )
    if max_nfev is None:
        max_nfev = x0.size * 100
    res = _trf_bounds(fun, jac, x0, f0, J0, lb, ub, ftol, xtol, gtol, max_nfev)
    res.message = MESSAGES[res.status]
    res.success = res.status > 0
    return res


def _trf_bounds(fun, jac, x0, f0, J0, lb, ub, ftol, xtol, gtol, max_nfev) -> OptimizeResult:
    """SciPy's ``trf_bounds`` for a linear loss, ``x_scale='jac'`` and the exact
    subproblem, the SVD taken by :func:`reduced_svd_uf` (the only change)."""
    x = x0.copy()
    f = f0
    f_true = f.copy()
    nfev = 1
    J = J0
    njev = 1
    m, n = J.shape

    cost = 0.5 * np.dot(f, f)
    g = compute_grad(J, f)
    scale, scale_inv = compute_jac_scale(J)

    v, dv = CL_scaling_vector(x, g, lb, ub)
    v[dv != 0] *= scale_inv[dv != 0]
    Delta = norm(x0 * scale_inv / v**0.5)
    if Delta == 0:
        Delta = 1.0

    g_norm = norm(g * v, ord=np.inf)
    f_augmented = np.zeros(m + n)
    J_augmented = np.empty((m + n, n))
    alpha = 0.0  # the Levenberg-Marquardt parameter
    termination_status = None

    while True:
        v, dv = CL_scaling_vector(x, g, lb, ub)
        g_norm = norm(g * v, ord=np.inf)
        if g_norm < gtol:
            termination_status = 1
        if termination_status is not None or nfev == max_nfev:
            break

        # the "hat" variables: x_scale first, then the Coleman-Li scaling
        v[dv != 0] *= scale_inv[dv != 0]
        d = v**0.5 * scale
        diag_h = g * dv * scale
        g_h = d * g

        f_augmented[:m] = f
        J_h = J_augmented[:m]  # a view
        np.multiply(J, d, out=J_h)  # J·d written in place (no temporary)
        J_augmented[m:] = np.diag(diag_h**0.5)
        s, V, uf = reduced_svd_uf(J_augmented, f_augmented)

        # theta: how far a step stays back from the bounds
        theta = max(0.995, 1 - g_norm)

        actual_reduction = -1
        while actual_reduction <= 0 and nfev < max_nfev:
            p_h, alpha, _ = solve_lsq_trust_region(n, m, uf, s, V, Delta, initial_alpha=alpha)
            p = d * p_h  # the trust-region step in the original variables
            step, step_h, predicted_reduction = select_step(
                x, J_h, diag_h, g_h, p, p_h, d, Delta, lb, ub, theta
            )
            x_new = make_strictly_feasible(x + step, lb, ub, rstep=0)
            f_new = np.atleast_1d(np.asarray(fun(x_new.copy()), dtype=float))
            nfev += 1
            step_h_norm = norm(step_h)
            if not np.all(np.isfinite(f_new)):
                Delta = 0.25 * step_h_norm
                continue
            cost_new = 0.5 * np.dot(f_new, f_new)
            actual_reduction = cost - cost_new
            Delta_new, ratio = update_tr_radius(
                Delta,
                actual_reduction,
                predicted_reduction,
                step_h_norm,
                step_h_norm > 0.95 * Delta,
            )
            step_norm = norm(step)
            termination_status = check_termination(
                actual_reduction, cost, step_norm, norm(x), ratio, ftol, xtol
            )
            if termination_status is not None:
                break
            alpha *= Delta / Delta_new
            Delta = Delta_new

        if actual_reduction > 0:
            x = x_new
            f = f_new
            f_true = f.copy()
            cost = cost_new
            J = np.atleast_2d(np.asarray(jac(x.copy()), dtype=float))
            njev += 1
            g = compute_grad(J, f)
            scale, scale_inv = compute_jac_scale(J, scale_inv)

    if termination_status is None:
        termination_status = 0
    active_mask = find_active_constraints(x, lb, ub, rtol=xtol)
    return OptimizeResult(
        x=x,
        cost=cost,
        fun=f_true,
        jac=J,
        grad=g,
        optimality=g_norm,
        active_mask=active_mask,
        nfev=nfev,
        njev=njev,
        status=termination_status,
    )
