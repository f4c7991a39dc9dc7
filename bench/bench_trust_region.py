"""The trust-region solver: CPU per fit and per step on a tutorial-sized fit, against SciPy's least_squares.

One bounded fit of the size the tutorial's ``diagnose`` runs most (2000 residuals, 9
parameters, the Jacobian a column slice of a wider array as the models return it, one
upper bound that binds so steps are reflected), from ``PMALAB_BENCH_TRF_STARTS`` (default
40) seeded starts, solved by :func:`pmalab.identify.estimation.trust_region.least_squares_trf`
and by SciPy's ``least_squares(method='trf', x_scale='jac')``, interleaved, median of 5
rounds, BLAS on one thread (as :func:`~pmalab.identify.estimation.solver.solve` runs it).
"solver CPU" is the fit's CPU less the time spent in the residual and Jacobian.

``PMALAB_BENCH_TRF_OLD=path/to/trust_region.py`` adds that copy of the module (e.g. an
older commit's, ``git show REV:pmalab/identify/estimation/trust_region.py > /tmp/t.py``)
as a third row, and checks that its evaluated points equal ours bit for bit.
"""

from __future__ import annotations

import importlib.util
import os
import statistics
import time

import numpy as np
from scipy.optimize import least_squares

from bench.table import print_table
from pmalab.identify.estimation import trust_region
from pmalab.identify.estimation.solver import one_blas_thread

M, N, WIDE = 2000, 9, 46  # residuals, parameters, columns of the array J is sliced from


def _problem():
    """Two damped sines on a line: z = (a1, w1, p1, a2, w2, p2, c0, c1, d)."""
    t = np.linspace(0.0, 4.0, M)
    truth = np.array([3.0, 5.0, 0.3, 1.2, 13.0, -0.7, 0.5, 0.8, 0.4])
    y = _model(truth, t) + 0.02 * np.random.default_rng(0).standard_normal(M)
    lo = np.array([0.0, 1.0, -3.2, 0.0, 8.0, -3.2, -5.0, -5.0, 0.0])
    hi = np.array([10.0, 8.0, 3.2, 10.0, 20.0, 3.2, 5.0, 0.6, 2.0])  # c1 ≤ 0.6 binds (0.8)
    clock = [0.0]  # CPU spent in the residual and the Jacobian

    def fun(z):
        t0 = time.process_time()
        r = _model(z, t) - y
        clock[0] += time.process_time() - t0
        return r

    def jac(z):
        t0 = time.process_time()
        a1, w1, p1, a2, w2, p2, _, _, d = z
        e = np.exp(-d * t)
        s1, c1 = np.sin(w1 * t + p1), np.cos(w1 * t + p1)
        s2, c2 = np.sin(w2 * t + p2), np.cos(w2 * t + p2)
        wide = np.empty((M, WIDE))
        J = wide[:, 3 : 3 + N]
        J[:, 0] = e * s1
        J[:, 1] = e * a1 * t * c1
        J[:, 2] = e * a1 * c1
        J[:, 3] = e * s2
        J[:, 4] = e * a2 * t * c2
        J[:, 5] = e * a2 * c2
        J[:, 6] = 1.0
        J[:, 7] = t
        J[:, 8] = -t * e * (a1 * s1 + a2 * s2)
        clock[0] += time.process_time() - t0
        return J

    rng = np.random.default_rng(1)
    n_starts = int(os.environ.get("PMALAB_BENCH_TRF_STARTS", "40"))
    starts = [np.clip(truth * rng.uniform(0.8, 1.2, N), lo + 1e-6, hi - 1e-6) for _ in range(n_starts)]
    return fun, jac, lo, hi, starts, clock


def _model(z, t):
    a1, w1, p1, a2, w2, p2, c0, c1, d = z
    return np.exp(-d * t) * (a1 * np.sin(w1 * t + p1) + a2 * np.sin(w2 * t + p2)) + c0 + c1 * t


def _load(path: str):
    spec = importlib.util.spec_from_file_location("_trust_region_old", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    fun, jac, lo, hi, starts, clock = _problem()
    kw = dict(ftol=1e-8, xtol=1e-8, gtol=1e-8, max_nfev=400)

    def ours(mod):
        return lambda z0: mod.least_squares_trf(fun, jac, z0, lo, hi, **kw)

    def scipy(z0):
        return least_squares(fun, z0, jac=jac, bounds=(lo, hi), method="trf", x_scale="jac", **kw)

    solvers = {"least_squares_trf": ours(trust_region), "SciPy least_squares": scipy}
    old = os.environ.get("PMALAB_BENCH_TRF_OLD")
    if old:
        solvers["least_squares_trf (PMALAB_BENCH_TRF_OLD)"] = ours(_load(old))
    cpu: dict[str, list[float]] = {k: [] for k in solvers}
    own: dict[str, list[float]] = {k: [] for k in solvers}
    nfev: dict[str, int] = {}
    results = {}
    with one_blas_thread():
        for _ in range(5):
            for name, solve in solvers.items():
                clock[0] = 0.0
                t0 = time.process_time()
                res = [solve(z0) for z0 in starts]
                dt = time.process_time() - t0
                cpu[name].append(dt / len(starts))
                own[name].append((dt - clock[0]) / len(starts))
                nfev[name] = sum(r.nfev for r in res)
                results[name] = res
    rows = []
    for name in solvers:
        per_fit = statistics.median(cpu[name])
        mine = statistics.median(own[name])
        steps = nfev[name] / len(starts)
        rows.append([name, f"{1e3 * per_fit:.2f}", f"{1e3 * mine:.2f}", f"{steps:.1f}",
                     f"{1e6 * mine / steps:.0f}"])
    print_table(["solver", "ms CPU / fit", "solver ms CPU / fit", "evaluations / fit",
                 "solver µs / evaluation"], rows)
    ref = results["least_squares_trf"]
    sp = results["SciPy least_squares"]
    worst = max(float(np.max(np.abs(a.x - b.x) / (np.abs(b.x) + 1e-12))) for a, b in zip(ref, sp))
    print(f"   {len(starts)} starts, {sum(r.active_mask.any() for r in ref)} ending on a bound; "
          f"largest relative |Δx| against SciPy {worst:.1e} (its SVD's round-off)")
    if old:
        same = all(a.x.tobytes() == b.x.tobytes() and a.nfev == b.nfev
                   for a, b in zip(ref, results["least_squares_trf (PMALAB_BENCH_TRF_OLD)"]))
        print(f"   the old copy's optima and evaluation counts equal ours bit for bit: {same}")
