"""The forward model is open to every law: a law written in a test file (its compiled
segment in its own module) runs in the compiled loops, with a mass and without."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from pmalab.identify.forward import (
    Coefficients,
    Load,
    _integrate_py,
    compiled_loops,
    simulate,
)
from pmalab.identify.laws import LAWS, HysteresisLaw, LawParam
from pmalab.identify.model import ForceModel


@njit(cache=False)
def _dahl_segment(h, x0, x1, prm):
    """Dahl's friction law along one segment, exact: dh/dx = σ·(F_c − σ·h)/x_c (h → ±F_c)."""
    dx = x1 - x0
    if dx == 0.0:
        return h
    sigma = 1.0 if dx > 0.0 else -1.0
    target = -sigma * prm[0]  # tension lower while contracting (x rising)
    return target + (h - target) * math.exp(-abs(dx) / prm[1])


class ThrowawayDahl(HysteresisLaw):
    """A law no file of pmalab knows: Dahl's, with its own compiled segment (registered
    only while a test runs, so other tests' collections never see it)."""

    params = (
        LawParam("Fc", 10.0, 0.0, 1e4, "N", "saturation force"),
        LawParam("xc", 1.0, 1e-4, 1e3, "mm", "memory length"),
        LawParam("h0", 0.0, -1e4, 1e4, "N", "initial hysteretic force"),
    )

    def h(self, x, theta, extras=None):
        prm = np.array([theta["Fc"], theta["xc"], theta["h0"]])
        out = np.empty(len(x))
        out[0] = hk = float(theta["h0"])
        for k in range(len(x) - 1):
            hk = _dahl_segment(hk, float(x[k]), float(x[k + 1]), prm)
            out[k + 1] = hk
        return out

    def kernel(self):
        return _dahl_segment

    def stepper(self, theta, extras=None):
        prm = np.array([theta["Fc"], theta["xc"], theta.get("h0", 0.0)])
        return lambda h, x0, x1: _dahl_segment(h, x0, x1, prm)


@pytest.fixture
def law():
    ThrowawayDahl.name = "throwaway-dahl"
    LAWS.register(ThrowawayDahl.name, ThrowawayDahl, replace=True)
    try:
        yield LAWS["throwaway-dahl"]()
    finally:
        LAWS.unregister("throwaway-dahl")


def test_a_new_law_runs_in_the_compiled_loop_as_the_python_one_does(law):
    model = ForceModel(law)
    loops = compiled_loops(law)
    assert loops is not None and loops.law_id == -1  # its own loops, not a built-in's
    th = {"k": -30.0, "c0": 0.0, "Fc": 8.0, "xc": 0.8, "h0": 0.0}
    t = np.arange(1500) / 500.0
    rng = np.random.default_rng(1)
    u = 40 * np.sin(2 * np.pi * 1.5 * t) + np.cumsum(rng.normal(0, 0.5, t.size))
    load = Load(mass_kg=2.0)
    fast = simulate(model, th, t, u, 0.0, load=load, h0=2.0)
    assert fast.status == "ok"
    coef = Coefficients(model, th)
    xo, vo, ho, fo = (np.full(t.size, np.nan) for _ in range(4))
    code, _, _ = _integrate_py(
        model, coef, t, u, np.zeros(t.size), 0.0, load, 0.0, 0.0, 2.0, fast.n_sub, xo, vo, ho, fo
    )
    assert code == 0
    np.testing.assert_allclose(xo, fast.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ho, fast.h, rtol=0, atol=1e-8)


def test_a_new_law_runs_massless_and_inverts_its_own_force(law):
    model = ForceModel(law)
    th = {"k": -30.0, "c0": 200.0, "Fc": 8.0, "xc": 0.8, "h0": 0.0}
    t = np.arange(2000) / 500.0
    x = 8.0 + 6.0 * np.sin(2 * np.pi * 0.5 * t)
    f = th["k"] * x + th["c0"] + law.h(x, th)
    s = simulate(model, th, t, f, 0.3, x0=float(x[0]))
    assert s.n_sub == 0 and s.status == "ok"
    np.testing.assert_allclose(s.position, x, rtol=0, atol=1e-7)
