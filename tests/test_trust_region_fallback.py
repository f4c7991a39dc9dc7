"""The trust-region solver on a SciPy without its private step helpers
(``scipy.optimize._lsq``): the import does not fail, and the solver is SciPy's own
``least_squares``, bit for bit.  A fresh copy of the module is loaded with the helpers
hidden, so the import guard itself runs (not only the flag it sets)."""

from __future__ import annotations

import importlib.util
import sys
import types

import numpy as np
import pytest
from scipy.optimize import least_squares

import pmalab.identify.estimation.trust_region as tr


def _fresh_copy():
    spec = importlib.util.spec_from_file_location("_trust_region_copy", tr.__file__)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("how", ["module gone", "name gone"])
def test_a_scipy_without_the_step_helpers_falls_back_to_its_least_squares(monkeypatch, how):
    # "module gone": importing scipy.optimize._lsq.trf fails (ModuleNotFoundError);
    # "name gone": the module is there without select_step ("cannot import name")
    stub = None if how == "module gone" else types.ModuleType("scipy.optimize._lsq.trf")
    monkeypatch.setitem(sys.modules, "scipy.optimize._lsq.trf", stub)
    mod = _fresh_copy()
    assert mod._HAVE_STEP_HELPERS is False

    t = np.linspace(0.0, 5.0, 300)
    y = 3.0 * np.exp(-t / 0.7) + 0.4 + 0.01 * np.random.default_rng(5).standard_normal(t.size)

    def fun(z):
        return z[0] * np.exp(-t / z[1]) + z[2] - y

    def jac(z):
        e = np.exp(-t / z[1])
        return np.column_stack([e, z[0] * e * t / z[1] ** 2, np.ones_like(t)])

    lo, hi = np.array([0.0, 0.05, -5.0]), np.array([2.5, 10.0, 5.0])
    kw = dict(ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=200)
    ours = mod.least_squares_trf(fun, jac, [1.0, 2.0, 0.0], lo, hi, **kw)
    monkeypatch.undo()  # SciPy's own solver with its own trf module back
    ref = least_squares(fun, [1.0, 2.0, 0.0], jac=jac, bounds=(lo, hi), method="trf",
                        x_scale="jac", **kw)
    assert ours.x.tobytes() == ref.x.tobytes()
    assert (ours.nfev, ours.njev, ours.status) == (ref.nfev, ref.njev, ref.status)
    # the real module is untouched: it still runs its own loop on SciPy's helpers
    assert tr._HAVE_STEP_HELPERS is True
