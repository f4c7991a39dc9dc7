"""Bouc-Wen hysteresis (with Song & Der Kiureghian's asymmetric extension).

Rate independent, so it is integrated in the *position* domain: for each sample step the
(filtered) position moves by dx = x[k+1] − x[k] in a constant direction σ = sign(dx), and
h is advanced along that straight segment — exact in time stamps, no velocity estimate::

    dh/dx' = A − |h|^n · (β·sgn(dx·h) + γ + ψ_v·sgn(dx) + ψ_h·sgn(h) + ψ_x·sgn(x − x_c)),
    dx' = (1 + ψ_a·sgn(dx))·dx  (a direction-dependent path length: each branch its own slope)

For ψ = 0 this is ḣ = A·ẋ − β·|ẋ|·|h|^(n−1)·h − γ·ẋ·|h|^n.

n = 1 (the default; fits fix n = 1): along a segment of constant direction σ and with
s = |dx|, ``dh/ds = σ·A − λ·h`` with λ = β + sgn(h)·(γ·σ + ψ_v + ψ_x·sgn(x − x_c)·σ) + ψ_h·σ,
*linear* in h while sgn(h) is constant, integrated exactly: h(s) = h∞ + (h₀ − h∞)·e^(−λs),
h∞ = σA/λ; where h crosses zero inside the segment the crossing s* is solved in closed
form and the rest continues with the new λ.  One exp per sample, no pow.

General n: classical RK4 on each segment with m = 1 + ⌈4·|dx|·L⌉ sub-steps (≤ 64),
L = n·(|β|+|γ|+|ψ|)·|h|^(n−1) bounding ∂(dh/dx)/∂h, so each sub-step moves h by a small
fraction of its own relaxation length (stable for fast runs, one RK4 step at 500 Hz for
slow ones).

Sign: with F = k·x + c0 + h, a physical loop needs A < 0.  Fits allow either sign.
Identifiability: n trades off against β and γ (held at 1 by default); β and γ are nearly
collinear on typical data (Brunot et al. 2017: ρ ≈ 0.998), so γ may be fixed at 0.
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
def _bw_rate(h, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x):
    ah = abs(h)
    hn = ah**n if ah > 0.0 else 0.0
    sh = 1.0 if h > 0.0 else (-1.0 if h < 0.0 else 0.0)
    return A - hn * (beta * sigma * sh + gamma + psi_v * sigma + psi_h * sh + psi_x * xs)


@njit(cache=True, fastmath=False)
def bw_segment(hk, x0, x1, A, beta, gamma, n, psi_v, psi_h, psi_x, x_c, psi_a=0.0):
    """h after the segment x0 → x1 (mm), general n: RK4 with adaptive sub-steps.

    ``psi_a``: direction-dependent path length, the law sees dx' = (1 + ψ_a·σ)·dx."""
    dx = x1 - x0
    if dx == 0.0:
        return hk
    sigma = 1.0 if dx > 0.0 else -1.0
    dx = dx * (1.0 + psi_a * sigma)
    lip0 = abs(beta) + abs(gamma) + abs(psi_v) + abs(psi_h) + abs(psi_x)
    ah = abs(hk)
    lip = n * lip0 * (ah ** (n - 1.0) if ah > 0.0 else (1.0 if n == 1.0 else 0.0))
    m = 1 + int(math.ceil(4.0 * abs(dx) * lip))
    if m > 64:
        m = 64
    dxs = dx / m
    dxp = (x1 - x0) / m  # sub-step in the measured position (for the sgn(x − x_c) term)
    for j in range(m):
        xa = x0 + j * dxp
        xs = 1.0 if xa + 0.5 * dxp > x_c else -1.0
        k1 = _bw_rate(hk, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x)
        k2 = _bw_rate(hk + 0.5 * dxs * k1, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x)
        k3 = _bw_rate(hk + 0.5 * dxs * k2, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x)
        k4 = _bw_rate(hk + dxs * k3, sigma, xs, A, beta, gamma, n, psi_v, psi_h, psi_x)
        hk = hk + dxs * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
    return hk


@njit(cache=True, fastmath=False)
def bw1_segment(hk, x0, x1, A, beta, gamma, psi_v, psi_h, psi_x, x_c, psi_a=0.0):
    """h after the segment x0 → x1 (mm) for n = 1, integrated exactly (``psi_a``: see
    :func:`bw_segment`)."""
    dx = x1 - x0
    if dx == 0.0:
        return hk
    sigma = 1.0 if dx > 0.0 else -1.0
    s = abs(dx) * (1.0 + psi_a * sigma)
    xs = 1.0 if x0 + 0.5 * dx > x_c else -1.0
    drive = sigma * A  # dh/ds at h = 0
    # at most two pieces: before and after a zero crossing of h
    for _piece in range(2):
        if hk > 0.0:
            sh = 1.0
        elif hk < 0.0:
            sh = -1.0
        else:
            sh = 1.0 if drive > 0.0 else (-1.0 if drive < 0.0 else 0.0)
            if sh == 0.0:
                break
        lam = beta + sh * (gamma * sigma + psi_v + psi_x * xs * sigma) + psi_h * sigma
        if abs(lam) * s < 1e-12:
            hn = hk + drive * s
            if hn * sh < 0.0 and hk * sh > 0.0:  # crosses zero (linear)
                sz = -hk / drive
                hk = 0.0
                s = s - sz
                continue
            hk = hn
            break
        hinf = drive / lam
        hn = hinf + (hk - hinf) * math.exp(-lam * s)
        if hk * sh > 0.0 and hn * sh < 0.0:
            # exact crossing: e^(−λ s*) = h∞ / (h∞ − h₀)
            sz = -math.log(hinf / (hinf - hk)) / lam
            hk = 0.0
            s = s - sz
            if s <= 0.0:
                break
            continue
        hk = hn
        break
    return hk


@njit(cache=True, fastmath=False)
def bouc_wen_h(x, A, beta, gamma, n, h0, psi_v=0.0, psi_h=0.0, psi_x=0.0, x_c=0.0, psi_a=0.0):
    """h[k] for the Bouc-Wen law driven by position samples ``x`` (mm); h in N."""
    N = x.shape[0]
    h = np.empty(N)
    h[0] = h0
    hk = h0
    for k in range(N - 1):
        hk = bw_segment(hk, x[k], x[k + 1], A, beta, gamma, n, psi_v, psi_h, psi_x, x_c, psi_a)
        h[k + 1] = hk
    return h


@njit(cache=True, fastmath=False)
def bouc_wen_h1(x, A, beta, gamma, h0, psi_v=0.0, psi_h=0.0, psi_x=0.0, x_c=0.0, psi_a=0.0):
    """h[k] for Bouc-Wen with n = 1, integrated exactly on each linear segment of ``x``."""
    N = x.shape[0]
    h = np.empty(N)
    h[0] = h0
    hk = h0
    for k in range(N - 1):
        hk = bw1_segment(hk, x[k], x[k + 1], A, beta, gamma, psi_v, psi_h, psi_x, x_c, psi_a)
        h[k + 1] = hk
    return h


@njit(cache=True, fastmath=False)
def _bw1_row(out, j, x, q):
    """Row ``j`` of ``out``: :func:`bouc_wen_h1` along ``x`` with q = (A, beta, gamma, n,
    h0, psi_v, psi_h, psi_x, x_c, psi_a), written in place (the same numbers)."""
    hk = q[4]
    out[j, 0] = hk
    for k in range(x.shape[0] - 1):
        hk = bw1_segment(hk, x[k], x[k + 1], q[0], q[1], q[2], q[5], q[6], q[7], q[8], q[9])
        out[j, k + 1] = hk


@njit(cache=True, fastmath=False)
def _bw_row(out, j, x, q):
    """Row ``j`` of ``out``: :func:`bouc_wen_h` along ``x`` (general n), in place."""
    hk = q[4]
    out[j, 0] = hk
    for k in range(x.shape[0] - 1):
        hk = bw_segment(hk, x[k], x[k + 1], q[0], q[1], q[2], q[3], q[5], q[6], q[7], q[8], q[9])
        out[j, k + 1] = hk


@njit(cache=True, fastmath=False)
def _bw1_pair(out, i, j, x, a, b):
    """Rows ``i`` and ``j`` of ``out`` (n = 1 both, parameters ``a`` and ``b``) advanced side
    by side: each row the same operations in the same order as :func:`_bw1_row`, but the
    two rows are independent chains the processor overlaps (each segment waits on an exp)."""
    ha = a[4]
    hb = b[4]
    out[i, 0] = ha
    out[j, 0] = hb
    for k in range(x.shape[0] - 1):
        x0 = x[k]
        x1 = x[k + 1]
        ha = bw1_segment(ha, x0, x1, a[0], a[1], a[2], a[5], a[6], a[7], a[8], a[9])
        hb = bw1_segment(hb, x0, x1, b[0], b[1], b[2], b[5], b[6], b[7], b[8], b[9])
        out[i, k + 1] = ha
        out[j, k + 1] = hb


@njit(cache=True, fastmath=False)
def _bw1_rows(out, x, P, rows):
    """The rows ``rows`` of ``out`` (each with n = 1): :func:`bouc_wen_h1` with the
    parameters of that row of P, two at a time (:func:`_bw1_pair`)."""
    m = rows.shape[0]
    i = 0
    while i + 1 < m:
        _bw1_pair(out, rows[i], rows[i + 1], x, P[rows[i]], P[rows[i + 1]])
        i += 2
    if i < m:
        _bw1_row(out, rows[i], x, P[rows[i]])


@njit(cache=True, fastmath=False)
def bouc_wen_h1_many(x, P):
    """:func:`bouc_wen_h_many` when every row of P has n = 1 (the default law): the general
    n's integrator is then neither called nor compiled."""
    out = np.empty((P.shape[0], x.shape[0]))
    if x.shape[0] > 0:
        _bw1_rows(out, x, P, np.arange(P.shape[0]))
    return out


@njit(cache=True, fastmath=False)
def bouc_wen_h_many(x, P):
    """h along ``x`` for each row of P = (A, beta, gamma, n, h0, psi_v, psi_h, psi_x, x_c,
    psi_a): :func:`bouc_wen_h1` where n = 1, else :func:`bouc_wen_h` (one compiled call for
    a Jacobian's columns; each row the same numbers as its own call).

    The rows with n = 1 are integrated two at a time (:func:`_bw1_pair`).  Every row is
    written sample by sample: no whole-row assignment, whose shape check would make numba
    compile its error-message code (about a second of a cold process's start)."""
    rows = P.shape[0]
    out = np.empty((rows, x.shape[0]))
    if x.shape[0] == 0:
        return out
    ones = np.empty(rows, dtype=np.int64)
    m = 0
    for j in range(rows):
        if P[j, 3] == 1.0:
            ones[m] = j
            m += 1
        else:
            _bw_row(out, j, x, P[j])
    _bw1_rows(out, x, P, ones[:m])
    return out


@njit(cache=True, fastmath=False)
def bw_kernel(hk, x0, x1, prm):
    """One segment with prm = (A, beta, gamma, n, h0, psi_v, psi_h, psi_x, x_c, psi_a)."""
    if prm[3] == 1.0:
        return bw1_segment(
            hk, x0, x1, prm[0], prm[1], prm[2], prm[5], prm[6], prm[7], prm[8], prm[9]
        )
    return bw_segment(
        hk, x0, x1, prm[0], prm[1], prm[2], prm[3], prm[5], prm[6], prm[7], prm[8], prm[9]
    )


def _extra_args(extras: Mapping[str, float] | None) -> tuple[float, ...]:
    """(psi_v, psi_h, psi_x, x_c, psi_a) from the effects' extras (0 where none is given)."""
    e = extras or {}
    return (
        float(e.get("psi_v", 0.0)),
        float(e.get("psi_h", 0.0)),
        float(e.get("psi_x", 0.0)),
        float(e.get("x_c", 0.0)),
        float(e.get("psi_a", 0.0)),
    )


def _args(theta: Mapping[str, float], extras: Mapping[str, float] | None) -> tuple[float, ...]:
    return (
        float(theta["A"]),
        float(theta["beta"]),
        float(theta["gamma"]),
        *_extra_args(extras),
    )


class BoucWen(HysteresisLaw):
    name = "bouc-wen"
    order = 1
    params = (
        LawParam("A", -50.0, -1e4, 1e4, "N/mm", "initial slope of h against x"),
        LawParam("beta", 0.1, -50.0, 50.0, "1/mm·N^(1-n)", "shape (with gamma): loop fullness"),
        LawParam("gamma", 0.0, -50.0, 50.0, "1/mm·N^(1-n)", "shape: hardening/softening"),
        LawParam("n", 1.0, 0.5, 4.0, "-", "sharpness of the elastic-plastic transition"),
        LawParam("h0", 0.0, -1e4, 1e4, "N", "initial hysteretic force"),
    )
    extras = ("psi_v", "psi_h", "psi_x", "x_c", "psi_a")
    default_fixed: ClassVar[dict[str, float]] = {"n": 1.0}
    default_fixed_why: ClassVar[dict[str, str]] = {
        "n": "n fixed at 1 (default): n trades off against beta/gamma; free it with --free n",
    }
    collinear_fixes = (("gamma", 0.0),)
    scale_param = "A"

    def shape_grid(self, stroke_mm: float) -> list[dict[str, float]]:
        R = max(stroke_mm, 1e-3)
        out = []
        for lam_a in np.geomspace(0.5, 64.0, 8) / R:  # approach rate to saturation, 1/mm
            for ratio in (0.25, 1.0, 3.0):  # decay rate after a reversal / lam_a
                lam_o = ratio * lam_a
                out.append(
                    {"beta": 0.5 * (lam_o + lam_a), "gamma": 0.5 * (lam_o - lam_a), "n": 1.0}
                )
        return out

    def scale_valid(self, theta: Mapping[str, float]) -> bool:
        # h(c·A) = c·h(A) (c ≥ 0, h0 = 0) holds for n = 1 only
        return float(theta.get("n", 1.0)) == 1.0

    def guess(
        self, x: np.ndarray, force: np.ndarray, v: np.ndarray, fixed=None
    ) -> dict[str, float]:
        # saturation after ~1/5 of the stroke; A·(1/β) = the loop half-width
        w = abs(loop_half_width(x, force, v)) + 1e-3
        beta = 5.0 / max(float(np.ptp(x)), 1e-3)
        return {"A": -w * beta, "beta": beta, "gamma": 0.0, "n": 1.0, "h0": 0.0}

    def h(self, x, theta, extras=None):
        x = np.ascontiguousarray(x, dtype=np.float64)
        A, beta, gamma, pv, ph, px, xc, pa = _args(theta, extras)
        if float(theta["n"]) == 1.0:
            return bouc_wen_h1(x, A, beta, gamma, float(theta["h0"]), pv, ph, px, xc, pa)
        return bouc_wen_h(
            x, A, beta, gamma, float(theta["n"]), float(theta["h0"]), pv, ph, px, xc, pa
        )

    def h_many(self, x, thetas, extras=None):
        # _args of each row: the extras' part is every row's (read once)
        pv, ph, px, xc, pa = _extra_args(extras)
        rows = [
            (
                float(th["A"]),
                float(th["beta"]),
                float(th["gamma"]),
                float(th["n"]),
                float(th["h0"]),
                pv,
                ph,
                px,
                xc,
                pa,
            )
            for th in thetas
        ]
        P = np.array(rows, dtype=np.float64).reshape(len(rows), 10)
        x = np.ascontiguousarray(x, dtype=np.float64)
        # each row's n as P holds it (a float's float64 is itself): n = 1 on every row
        if all(r[3] == 1.0 for r in rows):
            return bouc_wen_h1_many(x, P)
        return bouc_wen_h_many(x, P)

    def kernel(self):
        return bw_kernel

    def stepper(self, theta, extras=None) -> Callable[[float, float, float], float]:
        A, beta, gamma, pv, ph, px, xc, pa = _args(theta, extras)
        n = float(theta["n"])
        if n == 1.0:

            def step1(h: float, x_prev: float, x: float) -> float:
                return bw1_segment(h, x_prev, x, A, beta, gamma, pv, ph, px, xc, pa)

            return step1

        def step(h: float, x_prev: float, x: float) -> float:
            return bw_segment(h, x_prev, x, A, beta, gamma, n, pv, ph, px, xc, pa)

        return step
