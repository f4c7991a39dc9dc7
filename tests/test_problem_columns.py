"""The estimation problem's finite-difference columns that reuse the model's parts at z.

A column of a law parameter recomputes only h and the effect terms, a column of a force-only
effect parameter only the terms: the Jacobian must equal, bit for bit, the one built from
whole predictions (the generic path a user law or effect takes), on multi-run problems with
pressure laws, per-run start states and per-run record nuisances.
"""

from __future__ import annotations

import numpy as np
import pytest
from identify_synth import make_run

from pmalab.identify.effects import EFFECTS
from pmalab.identify.estimation.basis import PressureBasis
from pmalab.identify.estimation.problem import Problem, Record
from pmalab.identify.laws import get_law
from pmalab.identify.laws.structures import structured_law
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals


def _records(n_runs: int = 3) -> list[Record]:
    out = []
    for j, p in enumerate((0.2, 0.35, 0.5)[:n_runs]):
        run, _ = make_run("bouc-wen", p, n=1500, seed=j, f=0.8)
        sig = Signals.from_run(run).every(2)
        out.append(Record(run.label, p, sig, np.asarray(run.force[::2], float), 1.0 / (j + 1)))
    return out


def _problem(model: ForceModel, records: list[Record]) -> Problem:
    ps = model.params(records[0].sig, records[0].force)
    run_params = [n for n in model.record_params if n in ps]
    free = [p.name for p in ps if p.vary and p.name not in run_params]
    return Problem(
        model,
        records,
        free=free,
        degree={n: (2 if i % 3 == 0 else i % 2) for i, n in enumerate(free)},
        constants={p.name: p.value for p in ps if not p.vary},
        bounds={p.name: (p.lo, p.hi) for p in ps},
        run_params=run_params,
        cap=1e6,
        basis=PressureBasis.over([r.p_nom for r in records]),
    )


def _z(prob: Problem, model: ForceModel, rng: np.random.Generator) -> np.ndarray:
    ps = model.params(prob.records[0].sig, prob.records[0].force)
    start = {p.name: p.value for p in ps}
    for p in ps:  # away from the defaults, inside the bounds
        if p.vary and np.isfinite(p.hi - p.lo):
            start[p.name] = p.value + 0.1 * (p.hi - p.value) * rng.uniform(0.05, 0.5)
    z = prob.z_from(
        {n: [start[n], 0.05 * rng.standard_normal()] for n in prob.free},
        {n: [start[n] + 0.5 * i for i in range(len(prob.records))] for n in prob.run_params},
    )
    lo, hi = prob.z_bounds()
    return np.clip(z, lo, hi)


LAWS = ("bouc-wen", "duhem", "prandtl-ishlinskii", "maxwell-slip")
MODELS = [
    *((law, (e,)) for law in LAWS for e in sorted(EFFECTS)),
    ("bouc-wen", ("viscous-friction",)),
    ("bouc-wen", ("sensor-delay", "inertia")),
    ("bouc-wen", ("asymmetric-hysteresis", "sensor-drift")),
    ("prandtl-ishlinskii", ("viscous-friction", "nonlinear-stiffness")),
    ("maxwell-slip", ("sensor-drift",)),
    ("duhem", ("asymmetric-hysteresis",)),
    ("maxwell-slip-scaled", ("viscous-friction", "asymmetric-hysteresis")),
    ("maxwell-slip-scaled", ()),
]


def _law(name: str):
    if name == "maxwell-slip-scaled":  # a pressure structure (built per campaign)
        return structured_law(
            get_law("maxwell-slip"), "scaled-thresholds", [0.2, 0.5, 0.3], [0.1, 0.5, 2.0]
        )
    return name


@pytest.mark.parametrize(("law", "effects"), MODELS)
def test_reused_parts_give_the_whole_prediction_jacobian_bit_for_bit(law, effects):
    model = ForceModel(_law(law), [EFFECTS[e]() for e in effects])
    records = _records()
    fast = _problem(model, records)
    assert fast._reuse, "built-in law and effects: the columns reuse the model's parts"
    kinds = set(fast._reuse.values())
    assert "law" in kinds
    slow = _problem(model, records)
    slow._reuse = {}  # the generic path: every column a whole prediction
    rng = np.random.default_rng(7)
    for _ in range(2):
        z = _z(fast, model, rng)
        Jf, Js = fast.jac(z), slow.jac(z)
        assert np.array_equal(fast.residual(z), slow.residual(z))
        assert Jf.shape == (fast.n_rows, fast.n_var)
        # most of the law's columns are filled (a parameter without effect here, e.g. the
        # slip displacement of an element that never slides, gives a zero column)
        law_cols = [fast.slices[n].start for n in fast.free if fast._reuse.get(n) == "law"]
        assert law_cols and np.mean(np.any(Jf[:, law_cols] != 0.0, axis=0)) > 0.5
        assert np.array_equal(Jf, Js), np.argwhere(Jf != Js)[:5]
        Rf, Rs = fast.jac(z, run_only=True), slow.jac(z, run_only=True)
        assert np.array_equal(Rf, Rs)


def test_force_only_effects_keep_h_and_transforming_ones_do_not():
    sig = _records(1)[0].sig
    m = ForceModel("bouc-wen", [EFFECTS[e]() for e in ("viscous-friction", "sensor-delay")])
    kinds = m.unchanged_parts(sig)
    assert kinds["visc_c"] == "terms"
    assert kinds["A"] == "law" and kinds["h0"] == "law"
    assert "delay_tau" not in kinds  # shifts the drive: a whole prediction
    assert "k" not in kinds and "c0" not in kinds


@pytest.mark.parametrize("effect", sorted(EFFECTS))
def test_builtin_effects_read_only_their_own_parameters(effect):
    """What the reuse relies on: a built-in effect's transform and law extras read nothing
    but its own parameters (a theta holding only those must do)."""
    sig = _records(1)[0].sig
    e = EFFECTS[effect]()
    own = {p.name: p.value for p in e.params(sig, 10.0)}
    for law in ("bouc-wen", "duhem", "prandtl-ishlinskii", "maxwell-slip"):
        e.law_extras(law, sig, own)
    e.transform(sig, own)


@pytest.mark.parametrize("law", [*LAWS, "maxwell-slip-scaled"])
def test_h_many_rows_are_the_single_calls(law):
    """One compiled call for a Jacobian's columns gives each row's own h bit for bit, with
    the asymmetric extras, on both start branches, at n = 1 and n ≠ 1."""
    model = ForceModel(_law(law), [EFFECTS["asymmetric-hysteresis"]()])
    sig = _records(1)[0].sig
    rng = np.random.default_rng(3)
    ps = model.params(sig, np.full(sig.t.shape, 10.0))
    thetas = []
    for j in range(5):
        th = {p.name: p.value for p in ps}
        for p in model.law.params:
            if np.isfinite(p.hi - p.lo):
                th[p.name] = p.init + 0.05 * (p.hi - p.init) * rng.uniform(0.0, 1.0)
        th["h0"] = 20.0 * rng.standard_normal()
        th["n"] = 1.0 if j % 2 else 1.5
        th["h0_reversed"] = float(j % 2)
        th.update(asym_psi_v=0.3 * rng.standard_normal(), asym_psi_h=0.2, asym_psi_a=-0.1)
        thetas.append(th)
    s, extras, _, _ = model.parts(sig, thetas[0])
    H = model.law.h_many(s.x, thetas, extras)
    assert H.shape == (5, sig.t.shape[0])
    for j, th in enumerate(thetas):
        assert np.array_equal(H[j], model.law.h(s.x, th, extras))
    assert not np.array_equal(H[0], H[1])


def test_nonneg_is_pythons_max_with_zero_bit_for_bit():
    from pmalab.identify.laws._slide import nonneg

    v = np.array([-3.0, -0.0, 0.0, np.nan, 2.5, -np.inf, np.inf, 1e-320])
    want = np.array([max(float(a), 0.0) for a in v])
    assert want.tobytes() == nonneg(v).tobytes()  # -0.0 and NaN kept as max keeps them


@pytest.mark.parametrize(("law", "effects"), [("maxwell-slip", ("viscous-friction",)),
                                              ("bouc-wen", ("sensor-drift",))])
def test_jacobian_is_each_parameters_column_times_its_basis_bit_for_bit(law, effects):
    # the shared parameters' columns of a run are written in one product; each entry must
    # still be the one multiplication ∂r_i/∂θ_n · B_n(p_i), and a θ clipped at a run
    # (its law out of bounds there) must leave that run's entries exactly 0
    model = ForceModel(law, [EFFECTS[e]() for e in effects])
    prob = _problem(model, _records())
    z = _z(prob, model, np.random.default_rng(11))
    # push one pressure law with a slope out of its bounds at the highest pressure only
    n_clip = next(n for n in prob.free
                  if prob.degree[n] >= 1 and np.isfinite(prob.bounds[n][1]) and n != "k")
    sl = prob.slices[n_clip]
    b = prob.B[n_clip]
    assert np.allclose(b[:, 0], 1.0) and b[0, 1] < 0 < b[-1, 1]  # P0 = 1; P1 ≈ ∓1 at the ends
    # θ += δ·(P0 − P1/P1(p_min)): unchanged at the lowest pressure, ≈ +2δ at the highest
    delta = 0.5 * (prob.bounds[n_clip][1] - prob.raw(z)[n_clip][-1]) + 1e-3
    z[sl.start] += delta
    z[sl.start + 1] -= delta / b[0, 1]
    inside = [bool(prob.bounds[n_clip][0] <= v <= prob.bounds[n_clip][1])
              for v in prob.raw(z)[n_clip]]
    assert inside[0] and not inside[-1], inside
    J = prob.jac(z)
    r0 = prob.residual(z)
    ths = prob.thetas(z)
    ref = np.zeros_like(J)
    for i, th in enumerate(ths):
        rows = prob.rows[i]
        for n in prob.free:
            ok = prob.bounds[n][0] <= prob.raw(z)[n][i] <= prob.bounds[n][1]
            if ok:
                d = prob.dresid(i, th, n, r0)
                ref[rows, prob.slices[n]] = d[:, None] * prob.B[n][i][None, :]
        for j, rn in enumerate(prob.run_params):
            ref[rows, prob.block(j).start + i] = prob.dresid(i, th, rn, r0)
    assert np.array_equal(J, ref), np.argwhere(J != ref)[:5]
    assert not np.any(J[prob.rows[-1], sl]) and np.any(J[prob.rows[0], sl])
    assert np.signbit(J[prob.rows[-1], sl]).sum() == 0  # +0.0, as a column never written
    # J is not zeroed first: every entry is written, the ones without a derivative as +0.0
    # (filled with NaN before, the columns come out the same, to the bit)
    for run_only in (False, True):
        want = prob.jac(z, run_only)
        got = np.full_like(want, np.nan)
        with np.errstate(all="ignore"):
            prob._fill_jac(got, np.asarray(z, dtype=float), prob.residual(z), run_only)
        assert got.tobytes() == want.tobytes()
    assert not np.any(want[:, : prob.n_coef])  # run_only: every shared column 0


@pytest.mark.parametrize("rows", [1, 2, 5, 8])
def test_slide_h_many_rows_are_slide_h_bit_for_bit(rows):
    # the kernel advances two rows side by side; each row must stay its own slide_h, to the
    # bit (-0.0 and NaN too), for odd and even row counts, both start branches, an element
    # of zero share, negative slip forces (|f| is the slip force) and a NaN stiffness
    from pmalab.identify.laws._slide import slide_h, slide_h_many

    rng = np.random.default_rng(rows)
    t = np.linspace(0.0, 3.0 * np.pi, 700)
    x = 9.0 + 7.0 * np.sin(t) + 0.02 * rng.standard_normal(t.size)
    K = rng.uniform(0.2, 6.0, (rows, 5))
    F = K * rng.uniform(0.1, 4.0, (rows, 5)) * np.where(rng.uniform(size=(rows, 5)) < 0.3, -1, 1)
    K[:, 2] = F[:, 2] = 0.0
    if rows > 2:
        K[2, 0] = np.nan
    h0 = rng.uniform(-5.0, 5.0, rows)
    rev = (np.arange(rows) % 2).astype(np.float64)
    H = slide_h_many(x, K, F, h0, rev)
    want = np.array([slide_h(x, K[j], F[j], h0[j], rev[j]) for j in range(rows)])
    assert H.shape == want.shape and H.tobytes() == want.tobytes()
    assert rows == 1 or not np.array_equal(H[0], H[1])


def _reference_residual(prob: Problem, z: np.ndarray) -> np.ndarray:
    """The residual written out plainly: (prediction − force)·w per run, a runaway clipped
    to the cap (or to RUNAWAY_N without one), stacked."""
    from pmalab.identify.estimation.problem import RUNAWAY_N

    out = []
    with np.errstate(all="ignore"):
        for r, th in zip(prob.records, prob.thetas(z)):
            e = (prob.model.predict(r.sig, th) - r.force) * r.weight
            cap = RUNAWAY_N if prob.cap is None else prob.cap
            if not float(np.abs(e).max()) <= cap:
                e = np.clip(np.nan_to_num(e, nan=cap, posinf=cap, neginf=-cap), -cap, cap)
            out.append(e)
    return np.concatenate(out)


@pytest.mark.parametrize("weight", [1.0, 0.37])
@pytest.mark.parametrize(
    ("law", "effects"),
    [("maxwell-slip", ("viscous-friction",)), ("bouc-wen", ("asymmetric-hysteresis",))],
)
def test_one_run_problem_with_and_without_a_biting_cap_bit_for_bit(law, effects, weight):
    # a single-run fit (unit weight: nothing multiplied) and a weighted one; with a cap that
    # some of the law's perturbed columns exceed and some do not (the rows clipped one by
    # one), and without a cap: residual and Jacobian equal the plain formula and the
    # generic path, bit for bit
    model = ForceModel(law, [EFFECTS[e]() for e in effects])
    rec = _records(1)[0]
    rec = Record(rec.label, rec.p_nom, rec.sig, rec.force, weight)
    rng = np.random.default_rng(5)
    base = _problem(model, [rec])
    z = _z(base, model, rng)
    e0 = np.abs(_reference_residual(base, z))
    clipped_rows = 0
    for cap in (None, float(np.quantile(e0, 0.999)), 1e6):
        fast = _problem(model, [rec])
        fast.cap = cap
        slow = _problem(model, [rec])
        slow.cap = cap
        slow._reuse = {}
        r = fast.residual(z)
        assert r.tobytes() == _reference_residual(fast, z).tobytes()
        assert r.tobytes() == slow.residual(z).tobytes()
        Jf, Js = fast.jac(z), slow.jac(z)
        assert Jf.tobytes() == Js.tobytes(), np.argwhere(Jf != Js)[:5]
        if cap is not None and cap < 1e6:
            # the cap bites: the residual is clipped somewhere, and a law column's
            # perturbed prediction too (its difference quotient is then 0 there)
            assert np.any(np.abs(r) == cap)
            clipped_rows += int(np.any(Jf[np.abs(r) == cap] == 0.0))
    assert clipped_rows
