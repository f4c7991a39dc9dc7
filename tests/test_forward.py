"""The identified model as a plant: the forward integrator, output-error identification,
``pmalab simulate`` and the regenerated Bouc-Wen benchmark (Noël & Schoukens 2016)."""

from __future__ import annotations

import json
import math

import h5py
import numpy as np
import pytest

from pmalab.cli import main
from pmalab.identify.effects import get_effect
from pmalab.identify.forward import (
    Coefficients,
    ForwardError,
    Load,
    _integrate_py,
    simulate,
)
from pmalab.identify.model import ForceModel
from pmalab.rig.sim import bouc_wen_benchmark as bwb


def _bench_model() -> ForceModel:
    return ForceModel("bouc-wen", [get_effect("inertia"), get_effect("viscous-friction")])


def _theta() -> dict[str, float]:
    return {**bwb.AS_PMALAB, "h0": 0.0}


def test_free_oscillation_period_matches_the_mass_spring_law():
    # no hysteresis (A = 0), no damping: x(t) = x0·cos(ωt), ω² = −k/m (k N/mm, m kg -> ×1e3)
    model = _bench_model()
    th = {**_theta(), "A": 0.0, "visc_c": 0.0, "k": -20.0, "inertia_m": 0.5}
    t = np.arange(3000) / 500.0
    s = simulate(model, th, t, 0.0, 0.0, x0=1.0)
    w = math.sqrt(20.0 / 0.5 * 1e3)
    assert s.status == "ok"
    # period from the downward zero crossings (linear interpolation): the integrator's
    # stated accuracy, ω·Δt ≤ 0.05 per sub-step, is a frequency error ≤ (ω·Δt)²/24 ≈ 1e-4
    x = s.position
    i = np.flatnonzero((x[:-1] > 0) & (x[1:] <= 0))
    tc = t[i] + x[i] / (x[i] - x[i + 1]) * (t[1] - t[0])
    period = float(np.mean(np.diff(tc)))
    assert abs(period * w / (2 * math.pi) - 1.0) < 3e-4
    # no damping, no hysteresis: the amplitude stays (a symplectic integrator)
    assert abs(np.max(x[-500:]) - 1.0) < 2e-3
    # the stored tension is the muscle's: k·x (no hysteresis, no damping)
    np.testing.assert_allclose(s.tension, -20.0 * s.position, atol=1e-9)


def test_forward_model_matches_the_benchmark_equations_integrated_independently():
    # the benchmark's own RK4 of m·ÿ + c·ẏ + k·y + z = u at 15 kHz vs the forward model at
    # 750 Hz with its own sub-steps: a smooth 8 Hz input (linear interpolation exact enough)
    fine = 2 * bwb.UPSAMPLE
    n = 3000
    tf = np.arange(n * fine + 1) / (bwb.FS_HZ * fine)
    uf = 60.0 * np.sin(2 * np.pi * 8.0 * tf) * np.minimum(tf / 0.5, 1.0)
    y = bwb.respond(uf, 1.0 / (bwb.FS_HZ * bwb.UPSAMPLE))[:: bwb.UPSAMPLE]
    t = np.arange(n + 1) / bwb.FS_HZ
    s = simulate(_bench_model(), _theta(), t, uf[::fine], 0.0)
    x_true = -y * 1e3
    err = np.sqrt(np.mean((s.position - x_true) ** 2))
    assert err < 2e-3 * np.std(x_true), err


def test_python_loop_equals_the_compiled_loop():
    model = _bench_model()
    rng = np.random.default_rng(3)
    t = np.arange(2000) / 500.0
    u = np.cumsum(rng.normal(0, 3.0, t.size)) * 0.2 + 30 * np.sin(2 * np.pi * 2 * t)
    fast = simulate(model, _theta(), t, u, 0.0, x0=0.2, v0=1.0, h0=3.0)
    coef = Coefficients(model, _theta())
    xo, vo, ho, fo = (np.full(t.size, np.nan) for _ in range(4))
    code, _, _ = _integrate_py(model, coef, t, u, np.zeros(t.size), 0.0, Load(), 0.2, 1.0, 3.0,
                            fast.n_sub, xo, vo, ho, fo)
    assert code == 0
    np.testing.assert_allclose(xo, fast.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ho, fast.h, rtol=0, atol=1e-8)


def test_a_model_without_a_forward_form_or_mass_is_refused_by_name():
    t = np.arange(10) / 500.0
    with pytest.raises(ForwardError, match="sensor-delay"):
        simulate(ForceModel("bouc-wen", [get_effect("sensor-delay")]), {}, t, 0.0, 0.0)
    th = {"k": -30.0, "c0": 0.0, "A": -40.0, "beta": 0.2, "gamma": 0.0, "n": 1.0, "h0": 0.0}
    from pmalab.identify.laws import get_law

    law = get_law("maxwell-slip")
    ms = {**{lp.name: lp.init for lp in law.params}, "k": -30.0, "c0": 0.0}
    with pytest.raises(ForwardError, match="moving mass"):
        simulate(ForceModel("maxwell-slip"), ms, t, 0.0, 0.0)
    # a load mass makes the same model a plant (pressure in, position out)
    s = simulate(ForceModel("bouc-wen"), th, t, 0.0, 0.3, load=Load(mass_kg=2.0, preload_N=10.0))
    assert s.status == "ok" and np.all(np.isfinite(s.position))


def test_massless_model_inverts_its_own_force_law_exactly():
    # F = k·x + c0 + h(x) along a path; driven by that F the quasi-static forward model
    # (no mass) returns the path: the inverse of identify's direction
    model = ForceModel("bouc-wen")
    th = {"k": -30.0, "c0": 200.0, "A": -40.0, "beta": 0.3, "gamma": 0.1, "n": 1.0, "h0": 0.0}
    t = np.arange(4000) / 500.0
    x = 8.0 + 6.0 * np.sin(2 * np.pi * 0.5 * t) + 1.5 * np.sin(2 * np.pi * 1.7 * t)
    f = th["k"] * x + th["c0"] + model.law.h(x, th)
    s = simulate(model, th, t, f, 0.3, x0=float(x[0]))
    assert s.n_sub == 0 and s.status == "ok"
    np.testing.assert_allclose(s.position, x, rtol=0, atol=1e-7)


@pytest.mark.parametrize("noise", [False, True])
def test_output_error_on_an_isobaric_campaign_recovers_the_law(noise, tmp_path):
    # no inertia identified on slow isobaric tests: the quasi-static forward model
    from identify_synth import bw_truth, make_run

    from pmalab.runfile import write_runs

    runs = [make_run("bouc-wen", p, n=6000, f=0.25, seed=i, noise=noise,
                     name=f"p{int(p * 1000)}")[0] for i, p in enumerate((0.2, 0.4, 0.6))]
    val = make_run("bouc-wen", 0.5, n=6000, f=0.25, seed=9, noise=noise, name="val")[0]
    write_runs(tmp_path / "c.h5", runs)
    write_runs(tmp_path / "v.h5", [val])
    out = tmp_path / "oe"
    assert main(["identify", str(tmp_path / "c.h5"), "--model", "bouc-wen", "--output",
                 "position", "--validate", str(tmp_path / "v.h5"), "--out", str(out)]) == 0
    doc = json.loads((out / "identification.json").read_text())
    v = doc["validation"][0]
    q = {n: np.polyval(list(reversed(c)), 0.5) for n, c in doc["pressure_fits"].items()}
    tr = bw_truth(0.5)
    if not noise:  # the model's own structure: recovered to the solver's tolerance
        assert v["nrmse_position"] < 1e-6, v["nrmse_position"]
        for name in ("k", "c0", "A", "beta"):
            assert abs(q[name] - tr[name]) < 1e-4 * max(abs(tr[name]), 1.0), name
    else:
        # the measured force *drives* the model here, so its noise (errors in the input
        # variable) is integrated by the law: 2.3 % nrmse where the position sensor's own
        # noise is 0.2 %; the force direction is the better fit when force is the noisier
        # channel
        assert v["nrmse_position"] < 0.04, v["nrmse_position"]


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    d = tmp_path_factory.mktemp("bwb")
    bwb.generate(d)
    return d


def test_benchmark_files_follow_the_published_system(bench):
    from pmalab.runfile import read_runs

    tr = read_runs(bench / "train.h5")[0]
    te = read_runs(bench / "test-multisine.h5")[0]
    assert len(tr) == 2 * bwb.PERIOD and len(te) == bwb.PERIOD
    assert abs(np.std(tr.force) - bwb.RMS_N) < 1e-6 * bwb.RMS_N
    # steady state: the multisine test's output repeats (one period kept after one skipped)
    u2 = bwb.multisine(1, 3, 2 * bwb.UPSAMPLE)
    y = bwb.respond(u2, 1.0 / (bwb.FS_HZ * bwb.UPSAMPLE))[:: bwb.UPSAMPLE]
    p1, p2 = y[bwb.PERIOD:2 * bwb.PERIOD], y[2 * bwb.PERIOD:3 * bwb.PERIOD]
    assert np.sqrt(np.mean((p1 - p2) ** 2)) < 0.02 * np.std(p1)


# the benchmark's output-error identification (its published goal, the benchmark's own
# parameters, `pmalab simulate` reproducing it, the report) is checked on the installed
# wheel in test_wheel.py: the suite runs it once


def test_simulate_position_in_reproduces_identify_force_predictions(bench, tmp_path):
    out = tmp_path / "fd"
    assert main(["identify", str(bench / "train.h5"), "--model", "bouc-wen", "--add",
                 "inertia", "--validate", str(bench / "test-sweep.h5"), "--out", str(out)]) == 0
    sim = tmp_path / "sim.h5"
    assert main(["simulate", str(out), str(bench / "test-sweep.h5"), "--out", str(sim)]) == 0
    with h5py.File(sim) as f, h5py.File(out / "predictions.h5") as g:
        fs = f["runs/sweep-test/force"][:]
        key = next(k for k in g["runs"] if g["runs"][k].attrs["role"] == "validation")
        fm = g["runs"][key]["force_model"][:]
    assert np.max(np.abs(fs - fm)) <= 1e-9 * np.max(np.abs(fm))
    # outputs are never overwritten without --force
    assert main(["simulate", str(out), str(bench / "test-sweep.h5"), "--out", str(sim)]) != 0


def test_simulate_bad_model_dir_is_one_line(tmp_path, capsys, bench):
    assert main(["simulate", str(tmp_path / "nothing"), str(bench / "train.h5"), "--out",
                 str(tmp_path / "s.h5")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "identification.json" in err[0]
    assert not (tmp_path / "s.h5").exists()


def test_simulate_pressure_in_moves_a_load_to_the_static_balance(tmp_path):
    # the shipped identification driven by a pressure step, moving a 5 kg load on a spring
    from pmalab.control.model import SHIPPED_IDENTIFICATION
    from pmalab.identify.forward import IdentifiedPlant
    from pmalab.runfile import Run, read_runs, write_runs

    t = np.arange(3000) / 500.0
    p = np.where(t < 1.0, 0.3, 0.45)
    run = Run("step", t, np.full(t.size, 10.0), np.zeros(t.size), p,
              attrs={"muscle_pressure_MPa": 0.4, "waveform": "step", "frequency_Hz": 0.1})
    write_runs(tmp_path / "in.h5", [run])
    out = tmp_path / "sim.h5"
    assert main(["simulate", str(SHIPPED_IDENTIFICATION), str(tmp_path / "in.h5"), "--input",
                 "pressure", "--load-mass", "5", "--load-stiffness", "10", "--preload", "100",
                 "--whole-run", "--out", str(out)]) == 0
    (sim,) = read_runs(out)
    x = sim.position
    assert np.all(np.isfinite(x)) and sim.attrs["simulated_input"] == "pressure"
    assert np.ptp(x[-200:]) < 0.05  # at rest at the end
    # at rest the muscle's tension (its own h included) holds preload + spring (averaged
    # over the last 0.4 s: a lightly damped load still rings by a few hundredths of a mm)
    assert abs(np.mean(sim.force[-200:] - (100.0 + 10.0 * x[-200:]))) < 0.3
    # more pressure, more contraction (the muscle pulls harder)
    assert x[-1] > x[int(0.9 * 500)] + 1.0
    # a load without mass cannot be driven by pressure: one line, nothing written
    assert main(["simulate", str(SHIPPED_IDENTIFICATION), str(tmp_path / "in.h5"), "--input",
                 "pressure", "--out", str(tmp_path / "none.h5")]) != 0
    assert not (tmp_path / "none.h5").exists()
    assert IdentifiedPlant.read("identification-bouc-wen").model.law.name == "bouc-wen"


def test_a_runaway_simulation_writes_nothing(tmp_path, capsys):
    from pmalab.runfile import Run, write_runs

    doc = json.loads((_shipped_bw()).read_text())
    # negative stiffness and a light load: the link runs away
    doc["pressure_fits"]["k"] = [50.0, 0.0, 0.0]
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "identification.json").write_text(json.dumps(doc))
    t = np.arange(2000) / 500.0
    write_runs(tmp_path / "in.h5", [Run("r", t, np.full(t.size, 10.0), np.zeros(t.size),
                                        np.full(t.size, 0.4),
                                        attrs={"muscle_pressure_MPa": 0.4})])
    rc = main(["simulate", str(tmp_path / "m"), str(tmp_path / "in.h5"), "--input", "pressure",
               "--load-mass", "0.1", "--whole-run", "--out", str(tmp_path / "s.h5")])
    assert rc != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not finite" in err[0]
    assert not (tmp_path / "s.h5").exists()


def _shipped_bw():
    from pmalab.control.model import SHIPPED_IDENTIFICATION

    return SHIPPED_IDENTIFICATION
