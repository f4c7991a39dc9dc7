"""Pressure structures of the element laws: exact mapping back to the base law, and the
leave-one-pressure-out choice on campaigns whose pressure dependence is known.

The campaigns here are made by the Maxwell-slip law itself (a unit test of the structure
machinery, not of the law against the simulator — that is bench section ``laws``): five
pressure levels, one two-cycle 1 Hz run each, 1 N force noise, 0.015 mm position noise.  Slip
displacements growing in proportion to p must choose ``scaled-thresholds``; slip
displacements the same at every pressure with one stiffness profile must not (their
structure is ``scaled``, of which ``scaled-thresholds`` is a superset, so either of the two
simpler-or-equal structures that contain the truth is right, never a worse held-out error).
"""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.identify.campaign.fit import fit_campaign
from pmalab.identify.campaign.structure import STARTS
from pmalab.identify.laws import get_law
from pmalab.identify.laws.structures import base_laws, structured_law
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals
from pmalab.runfile import Run

KAPPA = np.array([0.4, 0.3, 0.2, 0.1])
DELTA = np.array([0.3, 1.0, 2.5, 5.0])


@pytest.mark.parametrize("structure", ["scaled", "scaled-thresholds"])
def test_structured_law_is_the_base_law_with_its_pressure_laws_mapped(structure):
    base = get_law("maxwell-slip")
    law = structured_law(base, structure, KAPPA, DELTA)
    rng = np.random.default_rng(3)
    coef = {"s": (20.0, 60.0, -15.0), "t": (0.5, 1.2, 0.4)}
    for n in law.shared_shape:
        coef[n] = (float(rng.uniform(0.6, 1.5)), 0.0, 0.0)
    mapped = base_laws(base, law, coef)
    x = 6.0 + 5.0 * np.sin(np.linspace(0.0, 6.0 * np.pi, 1500)) * np.linspace(0.3, 1.0, 1500)
    for p in (0.2, 0.37, 0.55):
        th_s = {n: q[0] + q[1] * p + q[2] * p * p for n, q in coef.items()}
        if structure == "scaled":
            th_s["t"] = 1.0
        th_s["h0"] = 0.0
        th_b = {n: q[0] + q[1] * p + q[2] * p * p for n, q in mapped.items()}
        th_b["h0"] = 0.0
        np.testing.assert_allclose(law.h(x, th_s), base.h(x, th_b), rtol=1e-12, atol=1e-9)


def test_structured_law_travels_to_a_worker_and_is_cached_apart_from_its_base():
    """A structured law is built at run time: a pickled copy (what a worker process gets) is
    rebuilt from its base law and profile and predicts the same, and its fits of a record
    are never taken for the base law's (they share the law's name)."""
    import pickle

    base = get_law("maxwell-slip")
    law = structured_law(base, "scaled-thresholds", KAPPA, DELTA)
    copy = pickle.loads(pickle.dumps(law))
    assert type(copy).__name__ == type(law).__name__ and copy.shared_shape == law.shared_shape
    x = 6.0 + 5.0 * np.sin(np.linspace(0.0, 6.0 * np.pi, 600))
    th = {"s": 80.0, "t": 1.3, "h0": 0.0, **dict.fromkeys(law.shared_shape, 1.1)}
    np.testing.assert_array_equal(copy.h(x, th), law.h(x, th))
    assert law.name == base.name and law.cache_key() != base.cache_key()
    other = structured_law(base, "scaled-thresholds", KAPPA[::-1], DELTA)
    assert other.cache_key() != law.cache_key() and copy.cache_key() == law.cache_key()


def test_prandtl_ishlinskii_scaled_keeps_its_threshold_grid():
    base = get_law("prandtl-ishlinskii")
    k, d = base.elements({f"w{i + 1}": 1.0 + i for i in range(15)} | {"h0": 0.0})
    law = structured_law(base, "scaled", k, d)
    assert law.r_index == () and "t" in law.default_fixed
    with pytest.raises(ValueError, match="scaled-thresholds"):
        structured_law(base, "scaled-thresholds", k, d)


def _campaign(slip_exponent: float, kappa: np.ndarray = KAPPA) -> list[Run]:
    """One 1 Hz run (two cycles) per level; element i: k_i = s(p)·κ_i, d_i = δ_i·(p/0.4)^a."""
    law = get_law("maxwell-slip")
    runs = []
    for j, p in enumerate((0.2, 0.27, 0.34, 0.41, 0.48)):
        rng = np.random.default_rng(100 + j)
        n = 1000
        t = (np.arange(n) + 0.05 * rng.uniform(-1, 1, n)) / 500.0
        x = 8.0 + 6.0 * np.sin(2 * np.pi * 1.0 * t - np.pi / 2)
        sig = Signals.from_arrays(t, x, p, p_nom=p, frequency_Hz=1.0, cutoff_Hz=1e9)
        s = 30.0 + 150.0 * p
        th = {"k": -20 - 60 * p, "c0": 2500 * p - 100, "h0": 0.0}
        for i in range(4):
            th[f"k{i + 1}"] = s * kappa[i]
            th[f"d{i + 1}"] = DELTA[i] * (p / 0.4) ** slip_exponent
        F = ForceModel(law).predict(sig, th)
        runs.append(
            Run(
                name=f"p{int(p * 1000)}",
                time=t,
                position=x + 0.015 * rng.standard_normal(n),
                force=F + rng.standard_normal(n),
                muscle_pressure=p + 0.001 * rng.standard_normal(n),
                attrs={"muscle_pressure_MPa": p, "frequency_Hz": 1.0, "waveform": "sine"},
            )
        )
    return runs


def test_slip_displacements_growing_with_pressure_choose_scaled_thresholds():
    # d ∝ p²: over 0.2–0.48 MPa the slip displacements grow 5.8-fold (d ∝ p leaves the three
    # structures within 1 % of each other on these five two-cycle runs once the elements are
    # driven by their own narrower position band: no evidence either way)
    cf = fit_campaign(_campaign(2.0), "maxwell-slip")
    st = cf.structure
    assert st is not None and st.chosen == "scaled-thresholds", st and st.scores
    # the evidence: held-out error of the winner below the free structure's (which holds
    # the slip displacements constant in p), and the margin reported
    assert st.scores["scaled-thresholds"] < st.scores["free"]
    assert st.margin_percent > 0
    js = st.as_json()
    assert js["chosen"] == "scaled-thresholds" and len(js["candidates"]) == 3
    # each structured candidate says which of its two starts its kept fit came from
    assert {c["structure"]: c.get("start") for c in js["candidates"]}.keys() == {
        "free",
        "scaled",
        "scaled-thresholds",
    }
    assert all(c["start"] in STARTS for c in js["candidates"] if c["structure"] != "free")
    # the reported laws are the base law's: d1 grows with p (slope > 0), as simulated
    assert cf.pressure["d1"].coef[1] > 0 and cf.pressure["d1"].method.startswith("structure:")
    assert any(getattr(w, "code", "") == "pressure-structure" for w in cf.warnings)


def test_free_structure_keeps_the_law_as_its_file_says():
    cf = fit_campaign(_campaign(0.0), "maxwell-slip", structure="free")
    assert cf.structure is None
    assert all(cf.pressure[f"d{i}"].degree == 0 for i in range(1, 5))


def test_every_structure_reports_its_prior_chosen_by_the_same_evidence():
    """Each candidate's prior (shrinkage of the Maxwell-slip corrections) is scored at every
    strength by the leave-one-pressure-out influence approximation; the kept strength is
    the lowest score, or 0 when nothing beats the unpenalised fit by SIMPLER_WITHIN (or the
    kept step left the linear range: said in a note); the structure's score is the kept
    strength's."""
    from pmalab.identify.campaign.structure import PRIOR_GRID, SIMPLER_WITHIN

    cf = fit_campaign(_campaign(0.0), "maxwell-slip")
    st = cf.structure
    assert st is not None and set(st.priors) >= {"scaled", "scaled-thresholds"}
    for s, pr in st.priors.items():
        assert pr.strengths == list(PRIOR_GRID) and len(pr.scores) == len(PRIOR_GRID)
        assert all(np.isfinite(pr.scores)), (s, pr.scores)
        best = int(np.argmin(pr.scores))
        expected = (
            PRIOR_GRID[best] if pr.scores[best] < pr.scores[0] * (1 - SIMPLER_WITHIN) else 0.0
        )
        assert pr.chosen == expected or (pr.chosen == 0.0 and pr.note), (s, pr)
        assert st.scores[s] == pytest.approx(pr.scores[pr.strengths.index(pr.chosen)])
    js = st.as_json()
    assert js["priors"]["scaled"]["strengths"] == list(PRIOR_GRID)


def test_a_strong_prior_pulls_the_corrections_to_the_pooled_profile():
    """The penalised one-step solution: with λ large the shrunk corrections (c_i − 1,
    r_i − 1; the penalty is linear in them) go to ≤ 10 % of their unpenalised size, and
    every left-out level's runs get a finite held-out score with the prior in the fold."""
    from pmalab.identify.campaign.structure import _joint_structured, penalised_step, prior_rows
    from pmalab.identify.laws.structures import profile

    runs = _campaign(1.0)
    cf = fit_campaign(runs, "maxwell-slip", structure="free")
    base = get_law("maxwell-slip")
    thetas = [cf.theta(rf.p_nom) for rf in cf.runs]
    kappa, delta = profile(base, thetas)
    model = ForceModel(structured_law(base, "scaled-thresholds", kappa, delta))
    j, _ = _joint_structured(cf, runs, model, thetas)
    rows = prior_rows(j, base, model.law, "scaled-thresholds")
    assert rows is not None and rows[0].startswith("shrinkage")
    _, g_of, _ = rows
    g0 = g_of(j.z)
    assert np.linalg.norm(g0) > 1e-3  # the corrections moved from the pooled profile
    dz, _, lo = penalised_step(j, rows, 1e6)
    assert np.linalg.norm(g_of(j.z + dz)) < 0.1 * np.linalg.norm(g0)
    assert set(lo) == set(j.lopo) and all(np.isfinite(list(lo.values())))
    # λ = 0 is no step and the fit's own evidence
    dz0, _, lo0 = penalised_step(j, rows, 0.0)
    assert not np.any(dz0) and lo0 == j.lopo


def test_two_element_muscle_keeps_fewer_elements():
    """Slip displacements 0.3 and 2.5 mm only (the other two elements absent): the fitted
    elements that carry < 10 % of the friction are tried away by one joint fit per count,
    and fewer than four are kept (within 1 % of the best held-out score: never worse)."""
    from pmalab.identify.campaign.structure import SIMPLER_WITHIN

    # the structure named (the truth's: a shared shape scaled with pressure): on these five
    # runs the free laws score within 2 % of it, so "auto" may keep either; the element
    # count is what is under test
    cf = fit_campaign(
        _campaign(0.0, np.array([0.6, 0.0, 0.4, 0.0])), "maxwell-slip", structure="scaled"
    )
    st = cf.structure
    assert st is not None and st.chosen in st.elements, (st and st.chosen, st and st.elements)
    ec = st.elements[st.chosen]
    assert ec.counts[-1] == 4 and ec.chosen < 4 and ec.removed
    assert ec.scores[ec.counts.index(ec.chosen)] <= min(ec.scores) * (1 + SIMPLER_WITHIN)
    # the reported laws: the removed elements carry no stiffness at any pressure
    for i in ec.removed:
        assert cf.pressure[f"k{i}"].coef == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert st.as_json()["element_counts"][st.chosen]["chosen"] == ec.chosen


def test_element_counts_remove_only_elements_the_law_has(monkeypatch):
    """An element at zero weight is not one of the law's: a count never 'removes' it (that
    refitted the candidate's own law and labelled it one element fewer).  The small element
    that carries force is the one taken out, the count is the elements left, and that law is
    fitted once.  The fits are stand-ins: only which laws get fitted is under test."""
    from types import SimpleNamespace

    import pmalab.identify.campaign.structure as S

    base = get_law("maxwell-slip")
    # element 2 has no share; element 1 carries < 10 % of the friction (0.15 of 1.9)
    law = structured_law(base, "scaled", [0.5, 0.0, 0.3, 0.2], DELTA)
    th = {lp.name: float(lp.init) for lp in law.params} | {"k": -50.0, "c0": 100.0}

    class Fit:
        def __init__(self) -> None:
            self.lopo = {"p300": 0.02}

        def theta(self, p):
            return th

    fitted = []

    def joint_structured(cf, runs, model, thetas, per_run=None, jobs=1):
        fitted.append(model.law)
        return Fit(), STARTS[0]

    monkeypatch.setattr(S, "_joint_structured", joint_structured)
    cf = SimpleNamespace(runs=[SimpleNamespace(p_nom=p) for p in (0.2, 0.3, 0.4)])
    choice = S.StructureChoice(
        law="maxwell-slip", chosen="auto", criterion="", scores={}, n_params={}, folds=[0.3]
    )
    models = {"scaled": ForceModel(law)}
    S._element_counts(cf, [], base, models, {"scaled": Fit()}, [], choice)
    ec = choice.elements["scaled"]
    # three elements carry force; the one count tried removes element 1 (7.9 % of it), not
    # element 2 (none), and leaves two
    assert ec.counts == [2, 3] and ec.removed == [1], ec
    assert len(fitted) == 1
    np.testing.assert_allclose(fitted[0].kappa, [0.0, 0.0, 0.6, 0.4])  # the profile, renormed


def _gate_case(joint_free: float, first: float | Exception):
    """A campaign of four runs whose free per-run fits reach nrmse 0.010 and free joint laws
    ``joint_free``; the structured law's own per-run fits reach 0.011 and its first start's
    joint fit ``first`` (nrmse on every run, or the error it raised)."""
    from types import SimpleNamespace

    from pmalab.identify.campaign.structure import PerRunLaws

    n = 4
    runs = [SimpleNamespace(result=SimpleNamespace(nrmse=0.010)) for _ in range(n)]
    cf = SimpleNamespace(runs=runs, joint=SimpleNamespace(nrmse=[joint_free] * n))
    z = np.zeros(n)
    per_run = PerRunLaws(KAPPA, DELTA, z, z, z, None, np.full(n, 0.011))
    fit = first if isinstance(first, Exception) else SimpleNamespace(nrmse=[first] * n)
    return cf, fit, per_run


def test_second_start_is_refined_only_when_the_first_falls_short_of_the_data():
    """The gate on the second (per-run) start: the free joint laws cost (0.012/0.010)² =
    1.44 over the free per-run fits, so a structured first start at 0.0132 (excess
    (0.0132/0.011)² = 1.44, the same) stands and one at 0.0180 (2.68, +86 %) is refined from
    its second start too; so is a failed first start; without per-run fits there is no
    second start."""
    from pmalab.identify.campaign.structure import SECOND_START_MARGIN, needs_second_start

    cf, fit, pr = _gate_case(0.012, 0.0132)
    assert not needs_second_start(cf, fit, pr)
    cf, fit, pr = _gate_case(0.012, 0.0180)
    assert needs_second_start(cf, fit, pr)
    # just inside and just outside the margin
    edge = 0.0132 * np.sqrt(1.0 + SECOND_START_MARGIN)
    assert not needs_second_start(*_gate_case(0.012, edge * 0.99))
    assert needs_second_start(*_gate_case(0.012, edge * 1.01))
    assert needs_second_start(*_gate_case(0.012, ValueError("diverged")))
    cf, fit, _ = _gate_case(0.012, 0.0180)
    assert not needs_second_start(cf, fit, None)


def test_a_first_start_as_good_as_the_data_allow_is_refined_once(monkeypatch):
    """Slip displacements the same at every pressure: the free laws' start is already where
    the structured laws belong, so no candidate's second start is refined (each kept from
    the free laws: gate excess 1.03 and 1.13 against the free laws' 1.35) — while the
    element-count refits that drop elements still may be."""
    from pmalab.identify.campaign import structure as mod

    refines: list[int] = []
    gates: list[bool] = []
    refine, gate = mod._refine_start, mod.needs_second_start

    def counted_refine(args):
        refines.append(1)
        return refine(args)

    def counted_gate(*a):
        gates.append(gate(*a))
        return gates[-1]

    monkeypatch.setattr(mod, "_refine_start", counted_refine)
    monkeypatch.setattr(mod, "needs_second_start", counted_gate)
    cf = fit_campaign(_campaign(0.0), "maxwell-slip")
    st = cf.structure
    assert st is not None
    # the two candidates' gates come first: both skipped
    assert gates[:2] == [False, False], gates
    assert len(refines) == len(gates) + sum(gates) < 2 * len(gates)


def test_per_run_laws_hold_a_campaign_wide_delay_at_the_joint_fits_value(monkeypatch):
    """A sensor delay's τ is one value for the whole campaign (order 0 in every joint fit):
    the structured candidates' per-run fits hold it at the free joint fit's value instead of
    fitting it (with its multi-start grid) on every run again; every other parameter they
    fit as before (the campaign's constants held, the profile's corrections at 1).  The
    per-run fits are stand-ins: only what they are asked to hold is under test."""
    from types import SimpleNamespace

    import pmalab.identify.campaign.fit as fitmod
    from pmalab.identify.campaign.fit import ModelSpec
    from pmalab.identify.campaign.structure import per_run_laws

    model = ModelSpec("maxwell-slip", ("viscous-friction", "sensor-delay")).build()
    runs = _campaign(0.0)[:3]
    ps = [model.params(Signals.from_run(r), np.asarray(r.force)) for r in runs]
    tau = 0.0123
    joint = SimpleNamespace(
        constants={"visc_c": 0.5},
        theta=lambda p: {"k": -30.0, "c0": 200.0 + p, "delay_tau": tau, "visc_c": 0.5},
    )
    cf = SimpleNamespace(
        model=model,
        joint=joint,
        runs=[
            SimpleNamespace(p_nom=r.nominal_pressure, result=SimpleNamespace(params=p))
            for r, p in zip(runs, ps)
        ],
    )
    asked: list[dict] = []

    def fit_runs(rs, m, *, jobs=1, scheduler=None, fixed=None):
        asked.append(dict(fixed or {}))
        return [SimpleNamespace(values={"s": 100.0, "t": 1.0}, nrmse=0.01) for _ in rs]

    monkeypatch.setattr(fitmod, "fit_runs", fit_runs)
    base = get_law("maxwell-slip")
    models = {
        s: ForceModel(structured_law(base, s, KAPPA, DELTA), model.effects)
        for s in ("scaled", "scaled-thresholds")
    }
    out = per_run_laws(cf, runs, models)
    assert set(out) == set(models) and len(asked) == 2
    for fx, m in zip(asked, models.values()):
        assert fx["delay_tau"] == tau, fx
        # the rest as before: the joint's constants and the profile held, nothing else
        assert fx == {"visc_c": 0.5, "delay_tau": tau, **dict.fromkeys(m.law.shared_shape, 1.0)}
