"""A plain-numpy re-statement of the effects-off muscle law, to cross-check the kernel.

Tests and benchmarks use it as an independent reference: drive it with a (true or
measured) position history and the muscle pressure, and compare with what the compiled
rig's load cell reports.  It implements only the baseline: static characteristic
``F0(p)·(1 − x/x_max(p))`` (+ stretch term for x < 0, slack beyond x_max) and the Maxwell-slip braid friction;
none of the hidden effects.  Units: mm, MPa, N.
"""

from __future__ import annotations

import math

import numpy as np

from pmalab.rig.sim.truth import Truth, default_truth


def _q(truth: Truth, p: np.ndarray) -> np.ndarray:
    m = truth.section("muscle")
    pth = m["threshold_pressure_MPa"]
    return np.clip((np.asarray(p, float) - pth) / (m["reference_pressure_MPa"] - pth), 0.0, None)


def static_force(x: np.ndarray, p: np.ndarray, truth: Truth | None = None) -> np.ndarray:
    """Baseline static tension F_s(x, p) in N (linear in x at fixed p)."""
    truth = truth or default_truth()
    m = truth.section("muscle")
    q = _q(truth, p)
    beta = m["force_pressure_curvature"]
    f0 = m["max_force_N"] * ((1 - beta) * q + beta * q * q)
    sc = m["contraction_pressure_scale"]
    xm = np.maximum(m["max_contraction_mm"] * (1 - np.exp(-q / sc)) / (1 - math.exp(-1 / sc)), 0.5)
    x = np.asarray(x, float)
    f = np.maximum(f0 * (1.0 - x / xm), 0.0)  # slack beyond free contraction
    return f + np.where(x < 0, -m["stretch_stiffness_N_per_mm"] * x, 0.0)


def friction_force(
    x: np.ndarray, p: np.ndarray, truth: Truth | None = None, u0: list[float] | None = None
) -> np.ndarray:
    """Baseline Maxwell-slip braid friction (N) along the position path ``x``.

    ``u0``: initial element displacements (mm); default: all zero.
    """
    truth = truth or default_truth()
    fr = truth.section("friction")
    d = np.asarray(fr["presliding_mm"], float)
    w = np.asarray(fr["weights"], float)
    w = w / w.sum()
    g = fr["pressure_curvature"]
    q = _q(truth, p) * np.ones_like(np.asarray(x, float))
    ftot = fr["slip_force_N"] * ((1 - g) * q + g * q * q)
    x = np.asarray(x, float)
    u = np.zeros(len(d)) if u0 is None else np.asarray(u0, float).copy()
    out = np.empty_like(x)
    prev = x[0]
    for i, xi in enumerate(x):
        u = np.clip(u + (xi - prev), -d, d)
        prev = xi
        out[i] = -ftot[i] * np.sum(w * u / d)
    return out


def baseline_tension(
    x: np.ndarray, p: np.ndarray, truth: Truth | None = None, u0: list[float] | None = None
) -> np.ndarray:
    """Static + friction tension (N) of the baseline law along ``x`` at pressures ``p``
    (never negative: a muscle only pulls)."""
    return np.maximum(static_force(x, p, truth) + friction_force(x, p, truth, u0), 0.0)


def maxwell_slip_theta(
    p: float, truth: Truth | None = None, elements: int = 4
) -> dict[str, float] | None:
    """The baseline law at nominal pressure ``p`` (MPa) as parameters of pmalab's
    Maxwell-slip law: what a perfect identification would find.

    The static line F0(p)·(1 − x/x_max(p)) is ``c0 + k·x`` (c0 = F0 in N, k = −F0/x_max in
    N/mm); element i of the braid friction slides at ``d_i`` = its slip displacement × q^a
    (mm; a = ``presliding_pressure_exponent``) and holds it with the stiffness
    ``k_i`` = its slip force ÷ d_i (N/mm), its slip force being its weight's share of the
    pressure's total slip force.  Elements the truth does not have are given no stiffness
    (``k_i`` = 0; ``d_i`` = 1 mm, which then acts on nothing).  With ``elements`` = the
    truth's count it restates any truth's friction as elements, a Prandtl-Ishlinskii-shaped
    one included: a play operator of threshold r and weight w is the element with d = r and
    k = w (slip force w·r).

    Parameters
    ----------
    p : float
        Nominal muscle pressure (MPa).
    truth : Truth, optional
        The simulated muscle (default: the simulator's default truth).
    elements : int
        The law's number of elasto-slide elements (names ``k1, d1, …``).

    Returns
    -------
    dict or None
        ``k``, ``c0``, ``k1…``, ``d1…``; None when the law cannot express the truth: more
        elements than ``elements``, or any hidden effect enabled (an asymmetric loop, a
        curved static line and the rate-dependent effects are not in the law).
    """
    truth = truth or default_truth()
    fr = truth.section("friction")
    d = np.asarray(fr["presliding_mm"], float)
    if d.size > elements or truth.enabled_effects():
        return None
    m = truth.section("muscle")
    q = float(_q(truth, np.asarray(p)))
    beta = m["force_pressure_curvature"]
    f0 = m["max_force_N"] * ((1 - beta) * q + beta * q * q)
    sc = m["contraction_pressure_scale"]
    xm = max(m["max_contraction_mm"] * (1 - math.exp(-q / sc)) / (1 - math.exp(-1 / sc)), 0.5)
    w = np.asarray(fr["weights"], float)
    w = w / w.sum()
    g = fr["pressure_curvature"]
    ftot = fr["slip_force_N"] * ((1 - g) * q + g * q * q)
    a = fr["presliding_pressure_exponent"]
    ds = d * (max(q, 0.05) ** a if a != 0.0 else 1.0)  # the kernel's slip scale
    th = {"k": -f0 / xm, "c0": f0}
    for i in range(elements):
        on = i < d.size
        th[f"d{i + 1}"] = float(ds[i]) if on else 1.0
        th[f"k{i + 1}"] = float(ftot * w[i] / ds[i]) if on else 0.0
    return th
