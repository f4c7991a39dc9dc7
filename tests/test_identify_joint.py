"""Joint refinement of the pressure laws (pmalab.identify.estimation.joint) and the validation guards.

The simulated-rig tests run the seed-bouc-wen protocol (7 identification runs 0.1–0.6 MPa,
validation at 0.498 and 0.304 MPa) on ``data/rigs/sim-<effect>.toml`` and compare the mean
validation nrmse of ``identify --add <effect>`` with the base model's.  The joint fit was
developed on seed 7 (and checked on seeds 3 and 5); these tests use seed 23.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from identify_synth import TRUTH, make_run

from pmalab.cli import main as pmalab_main
from pmalab.identify.api import Identification, check_prediction, identify, split_roles
from pmalab.identify.campaign import ModelSpec, fit_campaign, refine_pressure_laws
from pmalab.identify.estimation.joint import PressureBasis, start_laws
from pmalab.identify.outputs import identification_dict
from pmalab.paths import RIGS_DIR
from pmalab.runfile import read_runs

SEED = 23


# --------------------------------------------------------------------------- fast unit tests
def test_legendre_basis_round_trip() -> None:
    b = PressureBasis(0.1, 0.6)
    q = (3.0, -2.0, 5.0)
    c = b.from_monomial(q, 2)
    assert b.to_monomial(c) == pytest.approx(q, rel=1e-10, abs=1e-10)
    p = np.array([0.1, 0.33, 0.6])
    assert b.matrix(p, 2) @ c == pytest.approx(q[0] + q[1] * p + q[2] * p * p, rel=1e-12)
    # one level only: a constant
    b1 = PressureBasis(0.4, 0.4)
    assert b1.to_monomial(b1.from_monomial((7.0, 0.0, 0.0), 0)) == pytest.approx((7.0, 0, 0),
                                                                               abs=1e-9)


def test_start_laws_orders_and_wandering_parameters() -> None:
    p = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    lin = [1.0 + 2.0 * x for x in p]
    wander = [7.3, -0.4, 0.5, 7.2, 2.1, 2.7]  # two optima, collinear on most runs
    start, deg, notes = start_laws(
        ["lin", "wander"], p, {"lin": lin, "wander": wander},
        {"lin": [0.01] * 6, "wander": [2.0, 0.005, 0.01, 2.0, 1.0, 2.0]},
        {"lin": [False] * 6, "wander": [True, True, False, True, True, True]}, max_degree=2)
    assert deg["lin"] == 1 and start["lin"] == pytest.approx((1.0, 2.0, 0.0), abs=1e-9)
    # a wandering parameter starts from the median (not the 0.005-stderr outlier)
    assert start["wander"] == pytest.approx((float(np.median(wander)), 0.0, 0.0))
    assert any("wander" in n and "median" in n for n in notes)


def _synth(law: str, levels, seed0: int = 0, n: int = 6000):
    return [make_run(law, p, seed=seed0 + i, n=n)[0] for i, p in enumerate(levels)]


def test_joint_on_model_data_keeps_truth_and_lowers_orders() -> None:
    """On data from the model itself the joint laws recover θ(p); linear truths get order 1."""
    runs = _synth("duhem", (0.2, 0.3, 0.4, 0.5, 0.6))
    cf = fit_campaign(runs, "duhem")
    assert cf.pressure_model == "joint" and cf.joint is not None
    for pp in (0.25, 0.45):
        th, truth = cf.theta(pp), TRUTH["duhem"](pp)
        for name in ("k", "c0", "alpha"):
            assert th[name] == pytest.approx(truth[name], rel=0.02), name
    assert cf.joint.degree["k"] == 1 and cf.joint.degree["alpha"] == 1
    assert cf.joint.mean_nrmse <= 1.01 * float(np.mean(cf.per_run_nrmse))
    doc = identification_dict(Identification(campaign=cf, runs=runs))
    assert doc["pressure_model"] == "joint"
    assert doc["joint_fit"]["orders"]["k"] == 1
    assert doc["pressure_fit_stats"]["k"]["per_run_degree"] == 2
    assert doc["pressure_fits"]["k"] == pytest.approx(list(cf.pressure["k"].coef))


def test_extrapolation_is_flagged_and_clipped() -> None:
    runs = _synth("bouc-wen", (0.3, 0.4, 0.5))
    res = identify(runs, "bouc-wen", jobs=1)
    far, _ = make_run("bouc-wen", 0.6, seed=99, n=6000, name="far")
    near, _ = make_run("bouc-wen", 0.45, seed=98, n=6000, name="near")
    v_far, v_near = res.validate([far, near])
    assert v_far.status == "extrapolated" and v_near.status == "ok"
    assert any("far" in w and "outside the identified range" in w for w in res.warnings)
    # θ is clipped into the law's bounds however far the pressure
    th = res.theta(50.0)
    bounds = res.campaign.bounds
    for name, v in th.items():
        lo, hi = bounds[name]
        assert lo <= v <= hi or name == "h0", name
    doc = identification_dict(res)
    assert [v["status"] for v in doc["validation"]] == ["extrapolated", "ok"]


def test_diverged_prediction_reported_not_scored() -> None:
    runs = _synth("bouc-wen", (0.3, 0.4, 0.5))
    res = identify(runs, "bouc-wen", jobs=1)
    run, _ = make_run("bouc-wen", 0.4, seed=97, n=6000, name="runaway")
    assert check_prediction(run.force, run.force + 1.0) is None
    assert "not finite" in check_prediction(run.force, np.full_like(run.force, np.nan))
    res.campaign.predict = lambda *a, **k: 40.0 * run.force  # type: ignore[method-assign]
    (v,) = res.validate([run])
    assert v.diverged and "force band" in v.message
    assert v.metrics["nrmse"] > 10.0  # still computed, for readers of the JSON
    assert "DIVERGED" in repr(res)
    doc = identification_dict(res)
    entry = doc["validation"][-1]
    assert entry["status"] == "diverged" and "force band" in entry["message"]
    assert any("runaway" in w and "diverged" in w for w in doc["warnings"])


def test_cli_prints_diverged_not_numbers(tmp_path, monkeypatch, capsys) -> None:
    from pmalab.identify import campaign
    from pmalab.runfile import write_runs

    runs = _synth("bouc-wen", (0.3, 0.4, 0.5))
    val, _ = make_run("bouc-wen", 0.4, seed=97, n=7000, name="runaway")
    val.attrs["role"] = "validation"
    f = write_runs(tmp_path / "c.h5", [*runs, val])
    real = campaign.CampaignFit.predict

    def runaway(self, run, *a, **k):
        out = real(self, run, *a, **k)
        return out * 40.0 if len(out) == 7000 else out  # only the validation run runs away

    monkeypatch.setattr(campaign.CampaignFit, "predict", runaway)
    rc = pmalab_main(["identify", str(f), "--model", "bouc-wen", "--out", str(tmp_path / "o"), "--jobs", "1",
                      "--whole-run"])
    assert rc in (0, None)
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "validate" in ln)
    assert "DIVERGED" in line and "fit" not in line


# --------------------------------------------------------------------------- simulated rig
def _simulate(rig: str, tmp: Path, seed: int = SEED) -> tuple[list, list]:
    out = tmp / f"{rig}-{seed}.h5"
    if not out.exists():
        rc = pmalab_main(["run", "--rig", str(RIGS_DIR / f"{rig}.toml"), "--protocol",
                          "seed-bouc-wen", "--out", str(out), "--quiet", "--seed", str(seed)])
        assert rc in (0, None)
    runs = [r.steady() for r in read_runs(out)]
    ident, held = split_roles(runs)
    assert len(ident) == 7 and len(held) == 2
    return ident, held


def _mean_val_nrmse(cf, ident, held) -> float:
    res = Identification(campaign=cf, runs=ident)
    vals = res.validate(held)
    assert all(not v.diverged for v in vals), [v.message for v in vals]
    return float(np.mean([v.metrics["nrmse"] for v in vals]))


@pytest.fixture(scope="module")
def simdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("joint-sim")


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "min_fall"), [("asymmetric-hysteresis", 0.30),
                                                  ("nonlinear-stiffness", 0.0),
                                                  ("sensor-delay", 0.0)])
def test_added_hidden_effect_lowers_validation_error(simdir, effect, min_fall) -> None:
    ident, held = _simulate(f"sim-{effect}", simdir)
    # in this process: the suite runs a pytest worker per core (pools: test_start_methods)
    base = fit_campaign(ident, "bouc-wen", jobs=1)
    ext = fit_campaign(ident, ModelSpec("bouc-wen", (effect,)), jobs=1)
    assert base.pressure_model == "joint" and ext.pressure_model == "joint"
    nb, ne = _mean_val_nrmse(base, ident, held), _mean_val_nrmse(ext, ident, held)
    assert ne < (1.0 - min_fall) * nb, (effect, nb, ne)
    # every law is finite and inside the bounds at the validation pressures
    for v in held:
        th = ext.theta(v.nominal_pressure)
        assert all(np.isfinite(x) for x in th.values())


@pytest.mark.slow
def test_joint_no_worse_than_per_run_quadratics_on_clean_data(simdir) -> None:
    ident, held = _simulate("sim", simdir)
    per_run = fit_campaign(ident, "bouc-wen", jobs=1, pressure_model="per-run")
    joint = replace(per_run, warnings=list(per_run.warnings))
    refine_pressure_laws(joint, ident)
    assert joint.pressure_model == "joint"
    n_per, n_joint = (_mean_val_nrmse(per_run, ident, held),
                      _mean_val_nrmse(joint, ident, held))
    assert n_joint <= 1.05 * n_per, (n_per, n_joint)
    assert n_joint < 0.03  # and the clean model is good in absolute terms


def test_cli_pressure_model_option(tmp_path) -> None:
    import json

    from pmalab.runfile import write_runs

    f = write_runs(tmp_path / "c.h5", _synth("duhem", (0.2, 0.4, 0.6)))
    for pm in ("per-run", "joint"):
        out = tmp_path / pm
        rc = pmalab_main(["identify", str(f), "--model", "duhem", "--out", str(out), "--quiet",
                          "--jobs", "1", "--whole-run", "--pressure-model", pm])
        assert rc in (0, None)
        doc = json.loads((out / "identification.json").read_text())
        assert doc["pressure_model"] == pm
        assert (doc["joint_fit"] is None) == (pm == "per-run")
        assert doc["pressure_fits_per_run"]["k"] == pytest.approx(
            doc["pressure_fit_stats"]["k"].get("per_run_quadratic", doc["pressure_fits"]["k"]))
