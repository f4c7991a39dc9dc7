"""The compiled many-row kernels of the scalar-state laws: each row the law's own call, bit
for bit, and no whole-row array assignment whose shape check makes numba compile its
error-message code in every process that compiles the kernels (a fresh install, a fresh
clone, a new numba cache).

A Jacobian's columns of the law's parameters are one ``h_many`` call (:mod:`pmalab.identify.
estimation.problem`); Bouc-Wen's rows with n = 1 are integrated two at a time there.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from pmalab.identify.laws.bouc_wen import (
    BoucWen,
    bouc_wen_h,
    bouc_wen_h1,
    bouc_wen_h1_many,
    bouc_wen_h_many,
)
from pmalab.identify.laws.duhem import duhem_h, duhem_h_many


def _path(seed: int, n: int = 900) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 5.0 * np.pi, n)
    # a loop with minor reversals and a flat stretch (zero-length segments)
    x = 9.0 + 7.0 * np.sin(t) + 1.5 * np.sin(7.3 * t) + 0.02 * rng.standard_normal(n)
    x[100:120] = x[100]
    return x


def _bw_rows(rows: int, seed: int, general: bool) -> np.ndarray:
    """Rows (A, beta, gamma, n, h0, psi_v, psi_h, psi_x, x_c, psi_a); with ``general`` every
    third row has n ≠ 1; a NaN parameter on one row; a row whose h starts at 0 (the exact
    integrator's zero-crossing branch)."""
    rng = np.random.default_rng(seed)
    P = np.column_stack(
        [
            rng.uniform(-120.0, -20.0, rows),
            rng.uniform(0.05, 0.8, rows),
            rng.uniform(-0.3, 0.3, rows),
            np.ones(rows),
            rng.uniform(-8.0, 8.0, rows),
            rng.uniform(-0.1, 0.1, rows),
            rng.uniform(-0.1, 0.1, rows),
            rng.uniform(-0.05, 0.05, rows),
            rng.uniform(5.0, 12.0, rows),
            rng.uniform(-0.2, 0.2, rows),
        ]
    )
    P[0, 4] = 0.0
    if general:
        P[2::3, 3] = 1.6
    if rows > 3:
        P[3, 1] = np.nan
    return P


def _bw_own(x: np.ndarray, q: np.ndarray) -> np.ndarray:
    if q[3] == 1.0:
        return bouc_wen_h1(x, q[0], q[1], q[2], q[4], q[5], q[6], q[7], q[8], q[9])
    return bouc_wen_h(x, q[0], q[1], q[2], q[3], q[4], q[5], q[6], q[7], q[8], q[9])


@pytest.mark.parametrize("rows", [1, 2, 5, 8])
@pytest.mark.parametrize("general", [False, True])
def test_bouc_wen_h_many_rows_are_their_own_call_bit_for_bit(rows, general):
    x = _path(rows)
    P = _bw_rows(rows, rows + 10 * general, general)
    want = np.array([_bw_own(x, P[j]) for j in range(rows)])
    H = bouc_wen_h_many(x, P)
    assert H.shape == want.shape and H.tobytes() == want.tobytes()
    if not general:
        H1 = bouc_wen_h1_many(x, P)
        assert H1.tobytes() == want.tobytes()
    # the rows differ (a pair's two chains are not one row written twice)
    assert rows == 1 or not np.array_equal(H[0], H[1])
    # and the law's h_many (the Jacobian's call) takes the right kernel for each case
    thetas = [{"A": q[0], "beta": q[1], "gamma": q[2], "n": q[3], "h0": q[4]} for q in P]
    extras = {"psi_v": 0.0, "psi_h": 0.0, "psi_x": 0.0, "x_c": 0.0, "psi_a": 0.0}
    Q = P.copy()
    Q[:, 5:] = 0.0
    want0 = np.array([_bw_own(x, Q[j]) for j in range(rows)])
    assert BoucWen().h_many(x, thetas, extras).tobytes() == want0.tobytes()


def test_bouc_wen_h_many_on_an_empty_path_is_empty():
    P = _bw_rows(3, 0, True)
    for fn in (bouc_wen_h_many, bouc_wen_h1_many):
        assert fn(np.empty(0), P).shape == (3, 0)


@pytest.mark.parametrize("rows", [1, 4])
def test_duhem_h_many_rows_are_duhem_h_bit_for_bit(rows):
    rng = np.random.default_rng(rows)
    x = _path(rows + 20)
    P = np.column_stack(
        [
            rng.uniform(0.05, 2.0, rows),
            rng.uniform(-1.0, 1.0, rows),
            rng.uniform(-80.0, -10.0, rows),
            rng.uniform(-5.0, 5.0, rows),
            rng.uniform(-0.2, 0.2, rows),
            rng.uniform(-0.2, 0.2, rows),
        ]
    )
    want = np.array([duhem_h(x, *P[j]) for j in range(rows)])
    H = duhem_h_many(x, P)
    assert H.shape == want.shape and H.tobytes() == want.tobytes()
    assert duhem_h_many(np.empty(0), P).shape == (rows, 0)


_COLD = r"""
import json, sys
import numpy as np
from numba.core import event

compiled = []


class Seen(event.Listener):
    def on_start(self, e):
        fn = e.data["dispatcher"].py_func
        compiled.append(f"{fn.__module__}.{fn.__qualname__}")

    def on_end(self, e):
        pass


event.register("numba:compile", Seen())
from pmalab.identify.laws._slide import slide_h_many
from pmalab.identify.laws.bouc_wen import bouc_wen_h1_many, bouc_wen_h_many
from pmalab.identify.laws.duhem import duhem_h_many

x = np.linspace(0.0, 10.0, 50)
P = np.tile([-50.0, 0.3, 0.05, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], (3, 1))
bouc_wen_h1_many(x, P)
P[1, 3] = 1.5
bouc_wen_h_many(x, P)
duhem_h_many(x, np.tile([1.0, 0.0, -50.0, 0.0, 0.0, 0.0], (3, 1)))
slide_h_many(x, np.ones((3, 2)), np.ones((3, 2)), np.zeros(3), np.zeros(3))
json.dump(compiled, sys.stdout)
"""


def test_many_row_kernels_compile_no_error_message_code(tmp_path):
    # a new numba cache: every kernel compiled here, as on a fresh install.  A whole-row
    # assignment (out[j, :] = row) compiles numba's shape-mismatch message (str/repr/
    # concat of tuples: ~1.4 CPU-s); sample-by-sample writes compile none of it
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    got = subprocess.run(
        [sys.executable, "-c", _COLD], capture_output=True, text=True, env=env, timeout=300
    )
    assert got.returncode == 0, got.stderr
    compiled = json.loads(got.stdout)
    assert "pmalab.identify.laws.bouc_wen.bouc_wen_h_many" in compiled  # really cold
    assert "pmalab.identify.laws._slide.slide_h_many" in compiled
    shape_message = [c for c in compiled if "raise_with_shape_context" in c]
    assert not shape_message, shape_message
    # one signature of each pmalab kernel (no literal index, no omitted argument)
    ours = [c for c in compiled if c.startswith("pmalab.")]
    assert len(ours) == len(set(ours)), sorted(ours)


_LOADS = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
from identify_synth import make_run
from pmalab.identify.estimation.single import fit_run
from pmalab.identify.laws import _slide, bouc_wen, duhem, get_law

kernels = {
    "bouc-wen": [bouc_wen.bouc_wen_h1, bouc_wen.bouc_wen_h1_many],
    "duhem": [duhem.duhem_h, duhem.duhem_h_many],
    "maxwell-slip": [_slide.slide_h, _slide.slide_h_many],
    "prandtl-ishlinskii": [_slide.slide_h, _slide.slide_h_many],
}
run, _ = make_run("bouc-wen", 0.3, n=1200, seed=3, f=0.8)
out = {}
for law, ds in kernels.items():
    get_law(law).load_compiled()
    loaded = [len(d.signatures) for d in ds]
    fit_run(run, law)
    out[law] = (loaded, [len(d.signatures) for d in ds])
json.dump(out, sys.stdout)
"""


def test_load_compiled_loads_the_kernels_a_fit_calls():
    # in a fresh process: what load_compiled loads is what a fit then runs (fitting
    # afterwards adds no signature: a worker forked after it would otherwise compile or
    # load its own)
    here = os.path.dirname(os.path.abspath(__file__))
    got = subprocess.run(
        [sys.executable, "-c", _LOADS, here], capture_output=True, text=True, timeout=300
    )
    assert got.returncode == 0, got.stderr
    for law, (loaded, after_fit) in json.loads(got.stdout).items():
        assert min(loaded) >= 1, law
        assert after_fit == loaded, law


@pytest.mark.parametrize(
    ("jobs", "scheduler", "loads"),
    [(2, None, True), (1, None, False), (2, "tcp://nowhere:1", False)],
)
def test_the_ladder_loads_every_scored_law_before_its_workers_start(
    monkeypatch, jobs, scheduler, loads
):
    from pmalab.identify.diagnosis import ladder
    from pmalab.identify.laws.base import HysteresisLaw

    seen: list[str] = []
    monkeypatch.setattr(HysteresisLaw, "load_compiled", lambda self: seen.append(self.name))

    class Started(Exception):
        pass

    def scorer(*a, **k):
        raise Started(list(seen))

    monkeypatch.setattr(ladder, "Scorer", scorer)
    with pytest.raises(Started) as got:
        ladder.run_ladder(
            [], [], "bouc-wen", [], jobs=jobs, laws=["duhem", "maxwell-slip"], scheduler=scheduler
        )
    assert got.value.args[0] == (["bouc-wen", "duhem", "maxwell-slip"] if loads else [])
