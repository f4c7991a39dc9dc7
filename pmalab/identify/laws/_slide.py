"""Elasto-slide elements: the one integrator of the Prandtl-Ishlinskii and Maxwell-slip laws.

Element i is a spring of stiffness k_i (N/mm) in series with a slider that slips at
±f_i (N).  Its force z_i follows the contraction x while it sticks and stays at the slip
force while it slides:

    z_i ← clip(z_i − k_i·Δx, −f_i, +f_i),     h = Σ z_i

exactly, for a piecewise-linear x (one clip per segment: an element can only saturate once
along a monotone segment).  The minus sign makes a physical loop: while the muscle is
stretched (Δx < 0) the elements load toward +f_i, so the tension is higher than while it
contracts.  A Prandtl-Ishlinskii play operator of threshold r_i and weight w_i is the same
element with k_i = w_i, f_i = w_i·r_i (its output w_i·(y_i − x)); a Maxwell-slip element is
it with (k_i, f_i) free.  The state is the vector z (N), its output h = Σ z_i; the record's
start state is one number h0, spread over the elements on a branch of the major loop
(:func:`slide_start`), so h[0] = h0 whenever |h0| ≤ Σ f_i.  By default the branch is the one
the record's first motion follows (a long move against it, then some way along it: a record
that starts in motion).  A record that starts at a turning point may instead have arrived
there moving the other way — its small elements slid against its first motion, its large
ones still holding what came before — which is the other branch (``reversed``): the
prediction of a record tries both and keeps the one its early part says
(:func:`pmalab.identify.estimation.records.estimate_record`).
"""

from __future__ import annotations

from operator import itemgetter

import numpy as np
from numba import njit

#: the theta key of an element law's start branch: 0 (default) the branch of the record's
#: first motion, 1 the branch of a move against it (see the module doc)
START_BRANCH = "h0_reversed"


@njit(cache=True, fastmath=False)
def _branch(k, f, s, u, z):
    """Element forces after a long move against ``s`` then ``u`` mm along ``s``; returns h."""
    h = 0.0
    for i in range(f.shape[0]):
        fi = abs(f[i])
        zi = s * fi - s * k[i] * u
        if zi > fi:
            zi = fi
        elif zi < -fi:
            zi = -fi
        z[i] = zi
        h += zi
    return h


@njit(cache=True, fastmath=False)
def slide_start(k, f, h0, s=1.0):
    """Element forces (N) on the major loop's branch with h = h0 (clipped to ±Σ f_i).

    The state is that after a long move against ``s`` (every element slid), then ``u`` mm
    along ``s`` (+1: contracting) — a record starts on the branch of sense ``s``.
    h(u) is monotone along a branch, so u is found by bisection; h[0] = h0 exactly when
    |h0| ≤ Σ f_i.  One number thus sets every element, as a scalar-state law's h0 does."""
    m = f.shape[0]
    z = np.zeros(m)
    tot = 0.0
    umax = 0.0
    for i in range(m):
        fi = abs(f[i])
        tot += fi
        if k[i] > 0.0:
            umax = max(umax, 2.0 * fi / k[i])
    if tot <= 0.0:
        return z
    if s == 0.0:
        s = 1.0
    # h(0) = s·tot, h(umax) = −s·tot; find h(u) = h0
    lo, hi = 0.0, umax
    target = min(max(h0, -tot), tot)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        hm = _branch(k, f, s, mid, z)
        if (hm - target) * s > 0.0:
            if mid == lo:
                break  # (lo, hi) unchanged: every step left would be this one again
            lo = mid
        else:
            if mid == hi:
                break
            hi = mid
    _branch(k, f, s, 0.5 * (lo + hi), z)
    return z


@njit(cache=True, fastmath=False)
def first_direction(x):
    """+1 when the path first moves toward contraction, −1 toward stretch (0: no motion)."""
    n = x.shape[0]
    lo = x[0]
    hi = x[0]
    for j in range(n):
        lo = min(lo, x[j])
        hi = max(hi, x[j])
    tol = 1e-3 * max(hi - lo, 1e-9)
    for j in range(1, n):
        d = x[j] - x[0]
        if d > tol:
            return 1.0
        if d < -tol:
            return -1.0
    return 1.0


@njit(cache=True, fastmath=False)
def slide_segment(z, dx, k, f):
    """Advance the element forces ``z`` (in place) along Δx (mm); returns h = Σ z_i (N)."""
    h = 0.0
    for i in range(z.shape[0]):
        fi = abs(f[i])
        zi = z[i] - k[i] * dx
        if zi > fi:
            zi = fi
        elif zi < -fi:
            zi = -fi
        z[i] = zi
        h += zi
    return h


@njit(cache=True, fastmath=False)
def slide_h(x, k, f, h0, reversed=0.0):
    """h[n] (N) of the elements driven by the contraction path ``x`` (mm), starting on the
    branch of the first motion (``reversed`` 0) or of a move against it (1)."""
    n = x.shape[0]
    h = np.empty(n)
    s = first_direction(x)
    if reversed > 0.5:
        s = -s
    z = slide_start(k, f, h0, s)
    s = 0.0
    for i in range(z.shape[0]):
        s += z[i]
    h[0] = s
    for j in range(n - 1):
        h[j + 1] = slide_segment(z, x[j + 1] - x[j], k, f)
    return h


@njit(cache=True, fastmath=False)
def slide_h_many(x, K, F, h0, reversed):
    """:func:`slide_h` for several element sets at once: row j has stiffnesses ``K[j]``,
    slip forces ``F[j]``, start ``h0[j]`` and branch ``reversed[j]`` (one compiled call for
    a Jacobian's columns; each row the same numbers as its own :func:`slide_h`).

    Two rows are advanced side by side along the path: each row's element forces and sum
    are the same operations in the same order as :func:`slide_segment`'s (|f_i| taken
    once), but the two rows' sums are independent chains the processor overlaps."""
    n = x.shape[0]
    rows = K.shape[0]
    m = K.shape[1]
    out = np.empty((rows, n))
    s0 = first_direction(x)
    Z = np.empty((rows, m))
    for j in range(rows):
        s = -s0 if reversed[j] > 0.5 else s0
        z = slide_start(K[j], F[j], h0[j], s)
        t = 0.0
        for i in range(m):
            t += z[i]
            Z[j, i] = z[i]
        if n > 0:
            out[j, 0] = t
    FA = np.abs(F)
    j = 0
    while j + 1 < rows:
        for q in range(n - 1):
            dx = x[q + 1] - x[q]
            ha = 0.0
            hb = 0.0
            for i in range(m):
                fa = FA[j, i]
                za = Z[j, i] - K[j, i] * dx
                if za > fa:
                    za = fa
                elif za < -fa:
                    za = -fa
                Z[j, i] = za
                ha += za
                fb = FA[j + 1, i]
                zb = Z[j + 1, i] - K[j + 1, i] * dx
                if zb > fb:
                    zb = fb
                elif zb < -fb:
                    zb = -fb
                Z[j + 1, i] = zb
                hb += zb
            out[j, q + 1] = ha
            out[j + 1, q + 1] = hb
        j += 2
    if j < rows and n > 0:
        # an odd count's last row alone: :func:`slide_h`'s steps from the start state set
        # above, written sample by sample (a whole-row assignment's shape check would make
        # numba compile its error-message code: about a second of a cold process's start)
        z = Z[j]
        k = K[j]
        f = F[j]
        for q in range(n - 1):
            out[j, q + 1] = slide_segment(z, x[q + 1] - x[q], k, f)
    return out


def slide_h_rows(x, K, F, thetas) -> np.ndarray:
    """Rows of :func:`slide_h` along ``x``: row j with the stiffnesses ``K[j]`` and slip
    forces ``F[j]`` (N/mm, N) and the start state and branch of ``thetas[j]``."""
    h0 = np.array([float(th["h0"]) for th in thetas], dtype=np.float64)
    rev = np.array([branch(th) for th in thetas], dtype=np.float64)
    K = np.ascontiguousarray(K, dtype=np.float64).reshape(len(thetas), -1)
    F = np.ascontiguousarray(F, dtype=np.float64).reshape(len(thetas), -1)
    return slide_h_many(np.ascontiguousarray(x, dtype=np.float64), K, F, h0, rev)


def nonneg(a: np.ndarray) -> np.ndarray:
    """``max(v, 0.0)`` of every element, as Python's ``max`` gives it (NaN and −0.0 kept:
    0.0 is taken only where 0.0 > v)."""
    return np.where(0.0 > a, 0.0, a)


def column(thetas, names) -> np.ndarray:
    """The values of ``names`` in every parameter set, shape (len(thetas), len(names)),
    each converted to float64 as ``float`` converts it."""
    if len(names) < 2:  # itemgetter of one name gives the value, not a tuple
        return np.array([[float(th[n]) for n in names] for th in thetas], dtype=np.float64).reshape(
            len(thetas), len(names)
        )
    get = itemgetter(*names)
    return np.array([get(th) for th in thetas], dtype=np.float64).reshape(len(thetas), len(names))


def slide_stepper(k: np.ndarray, f: np.ndarray):
    """``step(z, x_prev, x) -> z'`` (a new array; ``z`` is left as it was)."""
    k = np.ascontiguousarray(k, dtype=np.float64)
    f = np.ascontiguousarray(f, dtype=np.float64)

    def step(z, x_prev: float, x: float):
        z2 = np.array(z, dtype=np.float64, copy=True)
        slide_segment(z2, float(x) - float(x_prev), k, f)
        return z2

    return step


def play_basis(x: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Columns (N per unit weight) of unit-weight play operators along ``x`` from a zero
    state: column i is the element with k = 1, f = r_i (linear least-squares basis)."""
    cols = np.empty((x.shape[0], thresholds.shape[0]))
    one = np.ones(1)
    for i, r in enumerate(thresholds):
        cols[:, i] = slide_h(
            np.ascontiguousarray(x, dtype=np.float64), one, np.array([float(r)]), 0.0, 0.0
        )
    return cols


def branch(theta) -> float:
    """The start branch of ``theta`` (``START_BRANCH``: 0 the first motion's, 1 against it)."""
    return float(theta.get(START_BRANCH, 0.0))
