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
has them, :func:`least_squares_trf` is ``scipy.optimize.least_squares`` itself.  The
small ones are written out in the loop with the same floating-point operations in the
same order (on vectors of a few to tens of parameters their calls cost more than their
arithmetic), and the loop's evaluated points are those of SciPy's
``trf_bounds`` given the same SVD, bit for bit (tests/test_trust_region.py checks it).

Adapted from SciPy's ``scipy/optimize/_lsq/trf.py`` (``trf_bounds``), Copyright (c)
2001-2002 Enthought, Inc. and 2003-2024 SciPy Developers, BSD 3-Clause licence (the text
is in ``LICENSES/scipy.txt``).
"""

from __future__ import annotations

from collections.abc import Callable
from math import copysign, sqrt
from typing import Any

import numpy as np
from numpy.linalg import LinAlgError, norm
from scipy.linalg import lapack
from scipy.optimize import OptimizeResult, least_squares

try:  # SciPy's own step helpers (their names unchanged since SciPy 0.17)
    from scipy.optimize._lsq.common import (
        CL_scaling_vector,
        compute_grad,
        compute_jac_scale,
        find_active_constraints,
        in_bounds,
        make_strictly_feasible,
        minimize_quadratic_1d,
    )

    # written out in the loop below; a SciPy whose trf module no longer has it may have
    # changed the method, so it is asked for here too (the fallback then runs SciPy's own)
    from scipy.optimize._lsq.trf import select_step  # noqa: F401

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
    return _svd_step(A, f.reshape(-1, 1), n, np.tril_indices(n, -1), max(64, n))


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


def _norm(x: np.ndarray) -> np.float64:
    """``numpy.linalg.norm(x)`` of a 1-D float vector, bit for bit: NumPy computes it as
    ``sqrt(x.dot(x))`` (its fast path for ``ord=None``), and both square roots are IEEE's
    correctly rounded one; a NumPy scalar, as ``norm`` returns, so the arithmetic that
    follows is NumPy's (a division by a zero norm gives ``inf``, not an exception)."""
    return np.float64(sqrt(x.dot(x)))


def _step_size_to_bound(lb_x, ub_x, s, hits):
    """SciPy's ``step_size_to_bound(x, s, lb, ub)`` given ``lb - x`` and ``ub - x``, its
    operations: the smallest ``t ≥ 0`` putting ``x + t·s`` on a bound, and (``hits``) which
    bounds it reaches (−1 lower, 1 upper, 0 none), else ``None``."""
    if s.all():
        with np.errstate(over="ignore"):
            steps = np.maximum(lb_x / s, ub_x / s)
    else:
        non_zero = np.nonzero(s)
        s_non_zero = s[non_zero]
        steps = np.empty_like(s)
        steps.fill(np.inf)
        with np.errstate(over="ignore"):
            steps[non_zero] = np.maximum(lb_x[non_zero] / s_non_zero, ub_x[non_zero] / s_non_zero)
    min_step = np.min(steps)
    if not hits:
        return min_step, None
    return min_step, np.equal(steps, min_step) * np.sign(s).astype(int)


def _trf_bounds(fun, jac, x0, f0, J0, lb, ub, ftol, xtol, gtol, max_nfev) -> OptimizeResult:
    """SciPy's ``trf_bounds`` for a linear loss, ``x_scale='jac'`` and the exact
    subproblem, the SVD taken on the QR factor (:func:`reduced_svd_uf`).

    SciPy's per-step helpers (``CL_scaling_vector``, ``solve_lsq_trust_region``,
    ``select_step`` with ``build_quadratic_1d``, ``evaluate_quadratic``,
    ``step_size_to_bound`` and ``intersect_trust_region``,
    ``make_strictly_feasible``, ``update_tr_radius``, ``check_termination``,
    ``compute_grad``, ``compute_jac_scale``) are written out with the same floating-point
    operations in the same order, and what does not change between the tries of one
    iteration is computed once (the Gauss-Newton step, the norms of ``s·Uᵀf`` and of ``x``,
    ``s²``, the gradient direction at a bound): the evaluated points are SciPy's bit for
    bit (tests/test_trust_region.py runs SciPy's ``trf_bounds`` to compare).
    ``minimize_quadratic_1d`` is still called.  The loop is split into small functions
    (:func:`_svd_step`, :func:`_lm_constants`, :func:`_lm_step`, :func:`_leaving_box`,
    :func:`_radius_and_status`): one function with all their locals takes a type checker
    minutes to analyse, and a call costs well under a microsecond."""
    # the loop's variables declared: inferring them through the loop's numpy arithmetic
    # takes a type checker tens of seconds
    x: np.ndarray
    f: np.ndarray
    f_true: np.ndarray
    J: np.ndarray
    g: np.ndarray
    v: np.ndarray
    dv: np.ndarray
    d: np.ndarray
    diag_h: np.ndarray
    g_h: np.ndarray
    scale: np.ndarray
    scale_inv: np.ndarray
    p: np.ndarray
    p_h: np.ndarray
    x_p: np.ndarray
    x_new: np.ndarray
    f_new: np.ndarray
    step: np.ndarray
    step_h: np.ndarray
    Js: np.ndarray
    cost: Any
    cost_new: Any
    g_norm: Any
    x_norm: Any
    Delta: Any
    Delta_new: Any
    alpha: Any
    q: Any
    predicted_reduction: Any
    actual_reduction: Any
    step_h_norm: Any
    theta: Any
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
    J_augmented = np.zeros((m + n, n))  # the lower n × n block: diagonal, zeros elsewhere
    J_h = J_augmented[:m]  # a view
    diag_aug = J_augmented.reshape(-1)[m * n :: n + 1]  # the lower block's diagonal, a view
    f_aug_col = f_augmented.reshape(-1, 1)
    lower = np.tril_indices(n, -1)
    lwork = max(64, n)
    lb_finite = np.isfinite(lb)
    ub_finite = np.isfinite(ub)
    rank_threshold = EPS * m  # times s[0]: SciPy's full-rank test
    x_norm = norm(x)
    alpha = 0.0  # the Levenberg-Marquardt parameter
    termination_status = None

    while True:
        # CL_scaling_vector(x, g, lb, ub)
        lower_mask = (g > 0) & lb_finite
        upper_mask = (g < 0) & ub_finite
        v = np.where(lower_mask, x - lb, np.where(upper_mask, ub - x, 1.0))
        dv = np.subtract(lower_mask, upper_mask, dtype=float)  # 1, -1 or 0
        g_norm = np.abs(g * v).max()  # norm(g * v, ord=np.inf)
        if g_norm < gtol:
            termination_status = 1
        if termination_status is not None or nfev == max_nfev:
            break

        # the "hat" variables: x_scale first, then the Coleman-Li scaling
        v = np.where(dv != 0, v * scale_inv, v)
        d = v**0.5 * scale
        diag_h = g * dv * scale
        g_h = d * g

        f_augmented[:m] = f
        np.multiply(J, d, out=J_h)  # J·d written in place (no temporary)
        diag_aug[:] = diag_h**0.5
        s, V, uf = _svd_step(J_augmented, f_aug_col, n, lower, lwork)

        # solve_lsq_trust_region's parts that do not depend on Delta or alpha
        suf = s * uf
        s2 = s**2
        full_rank = bool(m >= n and s[-1] > rank_threshold * s[0])
        p_gn = p_gn_norm = None
        if full_rank:
            p_gn = -V.dot(uf / s)  # the Gauss-Newton step
            p_gn_norm = _norm(p_gn)
        lm = None  # the subproblem's constant parts, when the Gauss-Newton step is too long
        box: dict[str, Any] = {}  # select_step's parts at a bound, computed once

        # theta: how far a step stays back from the bounds
        theta = max(0.995, 1 - g_norm)

        actual_reduction = -1
        while actual_reduction <= 0 and nfev < max_nfev:
            # solve_lsq_trust_region(n, m, uf, s, V, Delta, initial_alpha=alpha)
            if p_gn is not None and p_gn_norm is not None and p_gn_norm <= Delta:
                p_h = p_gn.copy()
                alpha = 0.0
            else:
                if lm is None:
                    lm = _lm_constants(suf, s2, full_rank)
                p_h, alpha = _lm_step(suf, s2, V, Delta, alpha, full_rank, lm)

            p = d * p_h  # the trust-region step in the original variables
            # select_step(x, J_h, diag_h, g_h, p, p_h, d, Delta, lb, ub, theta)
            x_p = x + p
            if ((x_p >= lb) & (x_p <= ub)).all():
                # evaluate_quadratic(J_h, g_h, p_h, diag=diag_h)
                Js = J_h.dot(p_h)
                q = np.dot(Js, Js)
                q += np.dot(p_h * diag_h, p_h)
                step, step_h, predicted_reduction = p, p_h, -(0.5 * q + np.dot(p_h, g_h))
                x_new = x_p
            else:
                step, step_h, predicted_reduction = _leaving_box(
                    x, p, p_h, d, J_h, g_h, diag_h, Delta, lb, ub, theta, box
                )
                x_new = x + step
            # make_strictly_feasible(x_new, lb, ub, rstep=0): a point strictly inside is kept
            if not ((x_new > lb) & (x_new < ub)).all():
                x_new = make_strictly_feasible(x_new, lb, ub, rstep=0)
            f_new = np.atleast_1d(np.asarray(fun(x_new.copy()), dtype=float))
            nfev += 1
            step_h_norm = _norm(step_h)
            cost_new = 0.5 * np.dot(f_new, f_new)  # finite when every residual is
            if not np.isfinite(cost_new) and not np.isfinite(f_new).all():
                Delta = 0.25 * step_h_norm
                continue
            actual_reduction = cost - cost_new
            Delta_new, termination_status = _radius_and_status(
                Delta,
                actual_reduction,
                predicted_reduction,
                step_h_norm,
                cost,
                _norm(step),
                x_norm,
                ftol,
                xtol,
            )
            if termination_status is not None:
                break
            alpha *= Delta / Delta_new
            Delta = Delta_new

        if actual_reduction > 0:
            x = x_new
            x_norm = _norm(x)
            f = f_new
            f_true = f.copy()
            cost = cost_new
            J = np.atleast_2d(np.asarray(jac(x.copy()), dtype=float))
            njev += 1
            g = J.T.dot(f)  # compute_grad(J, f)
            # compute_jac_scale(J, scale_inv)
            scale_inv = np.maximum((J**2).sum(axis=0) ** 0.5, scale_inv)
            scale = 1 / scale_inv

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


def _svd_step(
    J_augmented: np.ndarray, f_aug_col: np.ndarray, n: int, lower: Any, lwork: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`reduced_svd_uf`'s LAPACK calls on ``J_augmented`` (n columns) and the column
    ``f_aug_col``, with the loop's kept strictly-lower indices ``lower`` and workspace
    ``lwork``: the singular values ``s``, ``V`` and ``Uᵀf``."""
    if not np.isfinite(J_augmented).all():
        raise ValueError("array must not contain infs or NaNs")
    qr, tau, _, info = _GEQRF(J_augmented)
    if info != 0:  # pragma: no cover - LAPACK argument error: a bug, not data
        raise ValueError(f"QR factorisation failed (LAPACK info {info})")
    r = qr[:n].copy(order="F")
    r[lower] = 0.0
    qtf, _, info = _ORMQR("L", "T", qr, tau, f_aug_col, lwork)
    if info != 0:  # pragma: no cover
        raise ValueError(f"applying Qᵀ failed (LAPACK info {info})")
    ur, s, vt, info = _GESDD(r, compute_uv=1, full_matrices=0, overwrite_a=1)
    if info > 0:
        raise LinAlgError("SVD did not converge")
    if info < 0:  # pragma: no cover
        raise ValueError(f"SVD failed (LAPACK info {info})")
    return s, vt.T, ur.T.dot(qtf[:n, 0])


def _lm_constants(suf: np.ndarray, s2: np.ndarray, full_rank: bool) -> tuple[Any, Any, Any, Any]:
    """The parts of ``solve_lsq_trust_region``'s Newton iteration that depend on neither the
    radius nor α: (``suf²``, ``‖suf‖``, and at full rank ``phi_and_derivative(0.0, …)``'s
    norm and derivative — ``s**2 + 0.0`` is ``s**2`` —, else unused zeros)."""
    suf2 = suf**2
    suf_norm = _norm(suf)
    if not full_rank:
        return suf2, suf_norm, 0.0, 0.0
    p_norm0 = _norm(suf / s2)
    dphi0 = -(suf2 / s2**3).sum() / p_norm0
    return suf2, suf_norm, p_norm0, dphi0


def _lm_step(
    suf: np.ndarray,
    s2: np.ndarray,
    V: np.ndarray,
    Delta: Any,
    alpha: Any,
    full_rank: bool,
    lm: tuple[Any, Any, Any, Any],
) -> tuple[np.ndarray, Any]:
    """``solve_lsq_trust_region``'s Levenberg-Marquardt branch (the Gauss-Newton step is
    longer than ``Delta``): its Newton iteration on α from ``alpha``, then the step scaled
    to the radius; (the step in the hat variables, the final α)."""
    suf2, suf_norm, p_norm0, dphi0 = lm
    alpha_upper = suf_norm / Delta
    if full_rank:
        phi = p_norm0 - Delta
        alpha_lower = -phi / dphi0
    else:
        alpha_lower = 0.0
    if not full_rank and alpha == 0:
        alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
    for _ in range(10):
        if alpha < alpha_lower or alpha > alpha_upper:
            alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
        # phi_and_derivative(alpha, suf, s, Delta)
        denom = s2 + alpha
        t = suf / denom
        p_norm = _norm(t)
        phi = p_norm - Delta
        phi_prime = -(suf2 / denom**3).sum() / p_norm
        if phi < 0:
            alpha_upper = alpha
        ratio = phi / phi_prime
        alpha_lower = max(alpha_lower, alpha - ratio)
        alpha -= (phi + Delta) * ratio / Delta
        if abs(phi) < 0.01 * Delta:
            break
    p_h = -V.dot(suf / (s2 + alpha))
    p_h *= Delta / _norm(p_h)
    return p_h, alpha


def _leaving_box(
    x: np.ndarray,
    p: np.ndarray,
    p_h: np.ndarray,
    d: np.ndarray,
    J_h: np.ndarray,
    g_h: np.ndarray,
    diag_h: np.ndarray,
    Delta: Any,
    lb: np.ndarray,
    ub: np.ndarray,
    theta: Any,
    box: dict[str, Any],
) -> tuple[np.ndarray, np.ndarray, Any]:
    """``select_step``'s branch for a trust-region step ``p`` (``p_h`` in the hat variables)
    that leaves the box: the best of the step cut at the bound, its reflection and the
    gradient step, each kept strictly inside; (the step, in the hat variables, the predicted
    reduction).  ``p`` and ``p_h`` are cut in place, as SciPy's are.  ``box`` keeps what
    all the tries of one iteration share (``lb − x``, ``ub − x`` and the gradient
    direction's parts): the caller gives a new one for each iteration."""
    if not box:
        box["lb_x"] = lb - x
        box["ub_x"] = ub - x
    lb_x, ub_x = box["lb_x"], box["ub_x"]
    p_stride, hits = _step_size_to_bound(lb_x, ub_x, p, True)
    assert hits is not None
    # the reflected direction
    r_h = np.copy(p_h)
    r_h[hits.astype(bool)] *= -1
    r = d * r_h
    # the trust-region step cut where it hits the bound
    p *= p_stride
    p_h *= p_stride
    x_on_bound = x + p
    # intersect_trust_region(p_h, r_h, Delta): its positive root
    a = np.dot(r_h, r_h)
    if a == 0:
        raise ValueError("`s` is zero.")
    b = np.dot(p_h, r_h)
    c = np.dot(p_h, p_h) - Delta**2
    if c > 0:
        raise ValueError("`x` is not within the trust region.")
    q = -(b + copysign(np.sqrt(b * b - a * c), b))
    t1 = q / a
    t2 = c / q
    to_tr = t2 if t1 < t2 else t1
    to_bound, _ = _step_size_to_bound(lb - x_on_bound, ub - x_on_bound, r, False)
    r_stride = min(to_bound, to_tr)
    if r_stride > 0:
        r_stride_l = (1 - theta) * p_stride / r_stride
        if r_stride == to_bound:
            r_stride_u = theta * to_bound
        else:
            r_stride_u = to_tr
    else:
        r_stride_l = 0
        r_stride_u = -1
    if r_stride_l <= r_stride_u:
        # build_quadratic_1d(J_h, g_h, r_h, s0=p_h, diag=diag_h)
        Jr = J_h.dot(r_h)
        a = np.dot(Jr, Jr)
        a += np.dot(r_h * diag_h, r_h)
        a *= 0.5
        b = np.dot(g_h, r_h)
        Jp = J_h.dot(p_h)
        b += np.dot(Jp, Jr)
        c = 0.5 * np.dot(Jp, Jp) + np.dot(g_h, p_h)
        b += np.dot(p_h * diag_h, r_h)
        c += 0.5 * np.dot(p_h * diag_h, p_h)
        r_stride, r_value = minimize_quadratic_1d(a, b, r_stride_l, r_stride_u, c=c)
        r_h *= r_stride
        r_h += p_h
        r = r_h * d
    else:
        r_value = np.inf
    # the cut step made strictly interior
    p *= theta
    p_h *= theta
    Js = J_h.dot(p_h)  # evaluate_quadratic(J_h, g_h, p_h, diag=diag_h)
    q = np.dot(Js, Js)
    q += np.dot(p_h * diag_h, p_h)
    p_value = 0.5 * q + np.dot(p_h, g_h)
    # the gradient direction: all but its length is the iteration's
    if "ag" not in box:
        ag_h0 = -g_h
        ag = d * ag_h0
        box["ag_h0"], box["ag"] = ag_h0, ag
        box["ag_h_norm"] = _norm(ag_h0)
        box["ag_to_bound"] = _step_size_to_bound(lb_x, ub_x, ag, False)[0]
        # build_quadratic_1d(J_h, g_h, ag_h0, diag=diag_h)
        Jag = J_h.dot(ag_h0)
        ag_a = np.dot(Jag, Jag)
        ag_a += np.dot(ag_h0 * diag_h, ag_h0)
        ag_a *= 0.5
        box["ag_a"], box["ag_b"] = ag_a, np.dot(g_h, ag_h0)
    to_tr = Delta / box["ag_h_norm"]
    if box["ag_to_bound"] < to_tr:
        ag_stride = theta * box["ag_to_bound"]
    else:
        ag_stride = to_tr
    ag_stride, ag_value = minimize_quadratic_1d(box["ag_a"], box["ag_b"], 0, ag_stride)
    if p_value < r_value and p_value < ag_value:
        return p, p_h, -p_value
    if r_value < p_value and r_value < ag_value:
        return r, r_h, -r_value
    return box["ag"] * ag_stride, box["ag_h0"] * ag_stride, -ag_value


def _radius_and_status(
    Delta: Any,
    actual_reduction: Any,
    predicted_reduction: Any,
    step_h_norm: Any,
    cost: Any,
    step_norm: Any,
    x_norm: Any,
    ftol: float,
    xtol: float,
) -> tuple[Any, int | None]:
    """``update_tr_radius(Delta, actual_reduction, predicted_reduction, step_h_norm,
    step_h_norm > 0.95 * Delta)`` and ``check_termination(actual_reduction, cost,
    norm(step), norm(x), ratio, ftol, xtol)``: (the new radius, the status or ``None``)."""
    if predicted_reduction > 0:
        ratio = actual_reduction / predicted_reduction
    elif predicted_reduction == actual_reduction == 0:
        ratio = 1
    else:
        ratio = 0
    if ratio < 0.25:
        Delta_new = 0.25 * step_h_norm
    elif ratio > 0.75 and step_h_norm > 0.95 * Delta:
        Delta_new = Delta * 2.0
    else:
        Delta_new = Delta
    ftol_satisfied = actual_reduction < ftol * cost and ratio > 0.25
    xtol_satisfied = step_norm < xtol * (xtol + x_norm)
    if ftol_satisfied and xtol_satisfied:
        return Delta_new, 4
    if ftol_satisfied:
        return Delta_new, 2
    if xtol_satisfied:
        return Delta_new, 3
    return Delta_new, None
