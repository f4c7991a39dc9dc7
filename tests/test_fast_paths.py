"""Fast paths of the fitting code that must give the plain computation's numbers bit for bit.

* a channel delay shifts its position, rates and slide drive with one interval look-up
  (``shift_all_in_time``): each shifted signal must be ``np.interp``'s, to the bit;
* an elasto-slide start state's bisection stops once its interval no longer changes: the
  element forces must be those of the full 80 steps;
* a one-run problem (every order 0, every basis value 1) copies its shared Jacobian columns
  instead of multiplying them by 1: the entries must be the products.
"""

from __future__ import annotations

import numpy as np
import pytest
from identify_synth import make_run

from pmalab.identify.effects import EFFECTS
from pmalab.identify.effects.delay import shift_all_in_time, shift_in_time
from pmalab.identify.estimation.problem import Problem, Record
from pmalab.identify.laws._slide import _branch, slide_start
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals


def _records_of_signals(rng: np.random.Generator, n: int) -> tuple[np.ndarray, list[np.ndarray]]:
    t = 3.0 + np.arange(n) * 0.002 + rng.normal(scale=1e-6, size=n)
    t = np.sort(t)
    x = 9.0 + 7.0 * np.sin(2.0 * np.pi * 0.7 * t) + 0.01 * rng.standard_normal(n)
    v = np.gradient(x, t)
    a = np.gradient(v, t)
    xs = x.copy()
    xs[rng.integers(0, n, 3)] = np.nan  # gaps and runaway values pass through as np.interp's
    a[rng.integers(0, n, 2)] = np.inf
    return t, [x, v, a, xs]


@pytest.mark.parametrize("tau", [0.0123, -0.05, 0.004, -0.002, 0.3, -0.3, float("nan")])
def test_shift_all_in_time_is_np_interp_bit_for_bit(tau):
    rng = np.random.default_rng(7)
    t, ys = _records_of_signals(rng, 1500)
    if tau == 0.004:
        tau = float(t[5] - t[3])  # nearly onto samples
    got = shift_all_in_time(t, ys, tau)
    assert len(got) == len(ys)
    for y, g in zip(ys, got):
        want = np.interp(t + tau, t, y)
        assert g.tobytes() == want.tobytes()
    # a strided view (a decimated fit's signals) and three signals: the same
    got3 = shift_all_in_time(t[::3], [y[::3] for y in ys[:3]], tau)
    for y, g in zip(ys[:3], got3):
        assert g.tobytes() == np.interp(t[::3] + tau, t[::3], y[::3]).tobytes()


def test_shift_all_in_time_falls_back_where_time_does_not_rise():
    rng = np.random.default_rng(3)
    t, ys = _records_of_signals(rng, 400)
    t[200] = t[199]  # a repeated stamp
    got = shift_all_in_time(t, ys[:3], 0.01)
    for y, g in zip(ys[:3], got):
        assert g.tobytes() == np.interp(t + 0.01, t, y).tobytes()
    one = np.array([1.0])
    assert shift_all_in_time(one, [np.array([2.0])], 0.1)[0].tolist() == [2.0]
    assert shift_all_in_time(t, ys[:1], 0.0)[0] is ys[0]


def test_delay_transform_shifts_every_signal_as_before():
    run, _ = make_run("bouc-wen", 0.35, n=1200, seed=2, f=0.8)
    sig = Signals.from_run(run)
    assert sig.x_slide is not None
    s = EFFECTS["sensor-delay"]().transform(sig, {"delay_tau": 0.0137})
    for name in ("x", "v", "a", "x_slide"):
        want = shift_in_time(sig.t, getattr(sig, name), 0.0137)
        assert getattr(s, name).tobytes() == want.tobytes(), name


def _start_80(k: np.ndarray, f: np.ndarray, h0: float, s: float) -> np.ndarray:
    """slide_start's bisection with all its 80 steps (the numbers to keep)."""
    m = f.shape[0]
    z = np.zeros(m)
    tot, umax = 0.0, 0.0
    for i in range(m):
        fi = abs(f[i])
        tot += fi
        if k[i] > 0.0:
            umax = max(umax, 2.0 * fi / k[i])
    if tot <= 0.0:
        return z
    lo, hi = 0.0, umax
    target = min(max(h0, -tot), tot)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        hm = _branch(k, f, s, mid, z)
        if (hm - target) * s > 0.0:
            lo = mid
        else:
            hi = mid
    _branch(k, f, s, 0.5 * (lo + hi), z)
    return z


def test_slide_start_is_the_full_bisection_bit_for_bit():
    rng = np.random.default_rng(11)
    early = 0
    for case in range(400):
        m = int(rng.integers(1, 13))
        k = rng.uniform(0.0, 60.0, m)
        f = k * rng.uniform(0.001, 3.0, m) * np.where(rng.uniform(size=m) < 0.2, -1.0, 1.0)
        if case % 17 == 0:
            k[0] = 0.0
        tot = float(np.sum(np.abs(f)))
        h0 = float(rng.choice([rng.uniform(-1.3, 1.3) * tot, tot, -tot, 0.0, 0.999999 * tot]))
        s = float(rng.choice([1.0, -1.0]))
        got = slide_start(k, f, h0, s)
        want = _start_80(k, f, h0, s)
        assert got.tobytes() == want.tobytes(), (case, got, want)
        early += 1
    assert early == 400


def _one_run_problem(model: ForceModel) -> Problem:
    run, _ = make_run("bouc-wen", 0.35, n=1500, seed=4, f=0.8)
    sig = Signals.from_run(run).every(2)
    rec = Record(run.label, 0.35, sig, np.asarray(run.force[::2], float))
    ps = model.params(sig, rec.force)
    run_params = [n for n in model.state_params if n in ps]
    free = [p.name for p in ps if p.vary and p.name not in run_params]
    return Problem(
        model,
        [rec],
        free=free,
        degree=dict.fromkeys(free, 0),
        constants={p.name: p.value for p in ps if not p.vary},
        bounds={p.name: (p.lo, p.hi) for p in ps},
        run_params=run_params,
    )


@pytest.mark.parametrize(
    ("law", "effects"),
    [("maxwell-slip", ("viscous-friction", "sensor-delay")), ("bouc-wen", ("inertia",))],
)
def test_one_run_jacobian_entries_are_the_products_bit_for_bit(law, effects):
    model = ForceModel(law, [EFFECTS[e]() for e in effects])
    prob = _one_run_problem(model)
    assert all(np.array_equal(prob.B[n], [[1.0]]) for n in prob.free)
    rng = np.random.default_rng(1)
    ps = model.params(prob.records[0].sig, prob.records[0].force)
    start = {p.name: p.value for p in ps}
    for p in ps:
        if p.vary and np.isfinite(p.hi - p.lo):
            start[p.name] = p.value + 0.1 * (p.hi - p.value) * rng.uniform(0.05, 0.5)
    if "delay_tau" in start:
        start["delay_tau"] = 0.011
    z = prob.z_from({n: [start[n]] for n in prob.free}, {n: [start[n]] for n in prob.run_params})
    J = prob.jac(z)
    r0 = prob.residual(z)
    (th,) = prob.thetas(z)
    ref = np.zeros_like(J)
    rows = prob.rows[0]
    for n in prob.free:
        d = prob.dresid(0, th, n, r0)
        ref[rows, prob.slices[n]] = d[:, None] * prob.B[n][0][None, :]
    for j, rn in enumerate(prob.run_params):
        ref[rows, prob.block(j).start] = prob.dresid(0, th, rn, r0)
    assert J.tobytes() == ref.tobytes(), np.argwhere(J != ref)[:5]
    assert np.all(np.any(J != 0.0, axis=0))  # every column written


@pytest.mark.parametrize("runs", [1, 3])
def test_order0_laws_are_the_basis_products_bit_for_bit(runs):
    # every law of order 0: θ at each run is taken from z without the products; it must be
    # B·z's numbers, a −0.0 coefficient becoming +0.0 as the product makes it, NaN kept
    model = ForceModel("bouc-wen", [EFFECTS["viscous-friction"]()])
    base = _one_run_problem(model)
    rec = base.records[0]
    recs = [Record(f"r{i}", 0.2 + 0.15 * i, rec.sig, rec.force) for i in range(runs)]
    prob = Problem(model, recs, free=base.free, degree=dict.fromkeys(base.free, 0),
                   constants=base.constants, bounds=base.bounds, run_params=base.run_params)
    assert prob._order0
    z = np.linspace(-3.0, 4.0, prob.n_var)
    z[0], z[1], z[2] = -0.0, np.nan, 1e308
    RAW, ths = prob._at(z)
    want = np.empty((len(prob.free), runs))
    for j, n in enumerate(prob.free):
        np.matmul(prob.B[n], z[prob.slices[n]], out=want[j])
    assert RAW.shape == want.shape and RAW.tobytes() == want.tobytes()
    assert not np.signbit(RAW[0]).any()
    for i, th in enumerate(ths):
        for j, n in enumerate(prob.free):
            lo, hi = prob.bounds.get(n, (-np.inf, np.inf))
            assert np.array(th[n]).tobytes() == np.clip(want[j, i], lo, hi).tobytes()
    deg1 = Problem(model, recs, free=base.free, degree=dict.fromkeys(base.free, 1),
                   constants=base.constants, bounds=base.bounds, run_params=base.run_params)
    assert not deg1._order0


def test_column_is_float_of_each_value_bit_for_bit():
    from pmalab.identify.laws._slide import column

    thetas = [{"a": 1, "b": np.float32(0.1), "c": -0.0, "d": float("nan"), "e": 2**60 + 1},
              {"a": True, "b": np.float64(3.5), "c": 7.25, "d": -np.inf, "e": 1e-320}]
    for names in (("a", "b", "c", "d", "e"), ("c",), ("d", "a"), ()):
        want = np.array([[float(th[n]) for n in names] for th in thetas], dtype=np.float64)
        got = column(thetas, names)
        assert got.shape == (2, len(names)) and got.tobytes() == want.reshape(2, -1).tobytes()


def test_with_position_is_dataclasses_replace_field_for_field():
    # a delayed drive is a copy made without the frozen __init__: every field must be
    # replace()'s, the slide drive kept for the old position must not come along, and the
    # copy must stay frozen
    import dataclasses

    run, _ = make_run("bouc-wen", 0.35, n=400, seed=4, f=0.8)
    sig = Signals.from_run(run)
    old_drive = sig.slide_drive()
    assert old_drive is not sig  # kept beside sig now
    x, v, a = sig.x + 0.5, sig.v * 1.5, sig.a - 2.0
    got = sig.with_position(x, v, a, sig.x_slide + 0.25)
    want = dataclasses.replace(sig, x=x, v=v, a=a, x_slide=sig.x_slide + 0.25)
    assert type(got) is type(want)
    for f in dataclasses.fields(Signals):
        g, w = getattr(got, f.name), getattr(want, f.name)
        assert np.asarray(g).tobytes() == np.asarray(w).tobytes(), f.name
    assert "_slide_drive" not in vars(got)
    assert got.slide_drive().x.tobytes() == (sig.x_slide + 0.25).tobytes()
    with pytest.raises(dataclasses.FrozenInstanceError):
        got.x = x  # type: ignore[misc]


def test_assemble_adds_each_term_in_order_and_leaves_its_inputs():
    # the terms are added into the new sum in place: the numbers of (lin + h) + t1 + t2,
    # each addition once, and neither lin nor h touched; the many-row assembly likewise
    model = ForceModel("bouc-wen", [EFFECTS["viscous-friction"](), EFFECTS["nonlinear-stiffness"]()])
    run, _ = make_run("bouc-wen", 0.35, n=500, seed=5, f=0.8)
    sig = Signals.from_run(run)
    th = {"k": -31.0, "c0": 80.0, "A": -40.0, "beta": 0.3, "gamma": 0.05, "n": 1.0, "h0": 0.7,
          "visc_c": 0.37, "stiff_k2": 0.013, "stiff_k3": -0.0007}
    s, _, lin, h = model.parts(sig, th)
    lin0, h0 = lin.copy(), h.copy()
    t1 = model.effects[0].force(s, h, th)
    t2 = model.effects[1].force(s, h, th)
    want = ((lin + h) + t1) + t2
    assert model.assemble(s, lin, h, th).tobytes() == want.tobytes()
    assert lin.tobytes() == lin0.tobytes() and h.tobytes() == h0.tobytes()
    H = np.stack([h, h * 0.5, -h])
    got = model.assemble_many(s, lin, H, th)
    for j in range(3):
        assert got[j].tobytes() == model.assemble(s, lin, H[j], th).tobytes()
    assert lin.tobytes() == lin0.tobytes()


@pytest.mark.parametrize("weight", [1.0, 0.37])
@pytest.mark.parametrize("cap", [None, 40.0])
def test_differences_are_weigh_then_the_quotient_bit_for_bit(weight, cap):
    # a law's columns go from predictions to forward differences in one compiled pass per
    # row; every row must be (_weigh(prediction) − r0) / step as written out plainly, the
    # rows beyond the cap (an entry just above it, NaN, ±inf) clipped as _weigh clips them
    from pmalab.identify.estimation.problem import RUNAWAY_N

    model = ForceModel("bouc-wen", [EFFECTS["viscous-friction"]()])
    prob = _one_run_problem(model)
    prob.cap = cap
    rec = prob.records[0]
    rec.weight = weight
    n = rec.n
    lim = RUNAWAY_N if cap is None else cap
    rng = np.random.default_rng(7)
    E = rec.force + rng.normal(scale=3.0, size=(7, n))
    E[1, 5] = rec.force[5] + lim / weight * (1.0 + 1e-12)  # just beyond the cap
    E[2, 9] = np.nan
    E[3, 11] = np.inf
    E[4, 13] = -np.inf
    E[5, 17] = rec.force[17] + lim / weight  # at the cap (kept)
    E[6, :] = rec.force  # every error −0.0 or +0.0
    E[6, 3] = -0.0 if rec.force[3] == 0.0 else E[6, 3]
    r0 = rng.normal(size=n)
    steps = np.array([1e-8, -2e-8, 3e-7, 1.0, -1e-8, 5e-9, 1e-8])
    want = np.empty_like(E)
    for k in range(E.shape[0]):
        e = prob._weigh(0, E[k].copy())
        want[k] = (e - r0) / steps[k]
    got = prob._differences(0, E.copy(), r0, steps)
    assert got.tobytes() == want.tobytes()
    # and the NumPy path it replaces (taken for an array the kernel does not take)
    plain = prob._differences(0, np.asfortranarray(E), r0, steps)
    assert plain.tobytes() == want.tobytes()
    # a residual's run weighed in place in the same pass: _weigh's numbers
    for k in range(E.shape[0]):
        assert prob._weigh_own(0, E[k].copy()).tobytes() == prob._weigh(0, E[k].copy()).tobytes()


def test_only_a_prediction_made_here_is_weighed_in_place():
    # a model with its own predict may hand back an array it keeps: weighing in place would
    # change it (and the next residual); this class's sum of parts is a new array each time
    class Kept(ForceModel):
        def predict(self, sig, theta):
            got = self.__dict__.get("kept")
            if got is None:
                got = self.kept = super().predict(sig, theta)
            return got

    base = _one_run_problem(ForceModel("bouc-wen"))
    assert base._fresh_output()
    th = base.thetas(base.z_from({n: [base.constants.get(n, 1.0)] for n in base.free}))[0]
    th.update(A=-40.0, beta=0.3, gamma=0.05, k=-30.0, c0=50.0)
    prob = Problem(Kept("bouc-wen"), base.records, free=base.free, degree=base.degree,
                   constants=base.constants, bounds=base.bounds, run_params=base.run_params)
    assert not prob._fresh_output()
    first = prob.run_residual(0, th).copy()
    kept = prob.model.kept.copy()
    assert prob.run_residual(0, th).tobytes() == first.tobytes()
    assert prob.model.kept.tobytes() == kept.tobytes()
    assert first.tobytes() == base.run_residual(0, th).tobytes()
