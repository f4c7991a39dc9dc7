"""Static characterization: physics static maps and pressure-domain hysteresis recovered
blind from simulated stands (noisy), cross-test validation, and the command line."""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
import pytest
from pdf_pages import assert_same_pages

from pmalab.cli import main as pmalab_main
from pmalab.errors import PmalabError
from pmalab.identify.schema import check_identification
from pmalab.identify.static import Geometry, StaticModel, fit_static, get_static_map
from pmalab.reports.static import build_static_report
from pmalab.rig.sim.static_stand import isometric_campaign, load_static_truth, run_test
from pmalab.runfile import write_runs

HELD = (0.0, 12.0, 24.0, 36.0)  # mm: 0 … 58 % of the truth's 62 mm free contraction


def _cli(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main(args)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def truth():
    return load_static_truth("geometric")


@pytest.fixture(scope="module")
def iso_fit(truth):
    """Chou–Hannaford + Duhem on the pressure, identified on 4 noisy isometric runs."""
    runs = isometric_campaign(truth, HELD, seed=11, period_s=10.0)
    isobaric = [
        run_test(truth, "isobaric", held_mm=15.0, pressure_MPa=p, seed=40 + i).to_run(f"b{p}")
        for i, p in enumerate((0.3, 0.5))
    ]
    model = StaticModel(
        get_static_map("chou-hannaford", Geometry(length_mm=200.0)), "duhem", "pressure"
    )
    return fit_static(model, runs, isobaric)


def test_the_map_and_the_stand_agree_on_the_geometric_force(truth):
    """Two independent writings of Chou–Hannaford with the end effect give one force."""
    m = get_static_map("chou-hannaford", Geometry(length_mm=truth.length_mm))
    theta = {"theta0_deg": 22.0, "diameter_mm": 10.0, "end_effect": 1.5, "offset_N": 0.0}
    x, p = np.linspace(0, 50, 11), np.linspace(0.1, 0.6, 11)
    np.testing.assert_allclose(m.force(x, p, theta), truth.static_force(x, p), rtol=1e-12)
    # the free contraction the map derives is the stand's
    assert m.derived(theta)["max_contraction_mm"][0] == pytest.approx(truth.max_contraction_mm)


def test_braid_angle_and_initial_radius_within_3_percent(iso_fit, truth):
    th = iso_fit.theta
    assert th["theta0_deg"] == pytest.approx(truth.braid_angle_deg, rel=0.03)
    assert th["diameter_mm"] / 2 == pytest.approx(truth.diameter_mm / 2, rel=0.03)
    assert th["end_effect"] == pytest.approx(truth.end_effect, rel=0.03)
    # standard errors are finite and the truth lies within a few of them
    se = iso_fit.stderr["theta0_deg"]
    assert se is not None and 0 < se < 1.0
    assert abs(th["theta0_deg"] - truth.braid_angle_deg) < 5 * se


def test_pressure_domain_hysteresis_width_within_10_percent(iso_fit, truth):
    assert iso_fit.hysteresis_widths()["p"] == pytest.approx(truth.pressure_friction_N, rel=0.10)
    # the loop runs the physical way: tension lower while inflating (h < 0 on the way up)
    assert iso_fit.theta["b_p"] < 0
    for rf in iso_fit.runs:  # the identification fits reach the noise floor
        assert rf.nrmse < 1.2 * rf.noise_floor_nrmse, rf.rec.label


def test_isometric_model_predicts_isobaric_runs_within_twice_the_noise_floor(iso_fit):
    assert [v.rec.run.test_type for v in iso_fit.validation] == ["isobaric", "isobaric"]
    for v in iso_fit.validation:
        assert v.nrmse < 2.0 * v.noise_floor_nrmse, (v.rec.label, v.nrmse, v.noise_floor_nrmse)


def test_a_static_map_alone_misses_the_loop(truth):
    """Without the pressure law the same data sit far above the noise floor (the test
    above is not passing on the map alone)."""
    runs = isometric_campaign(truth, HELD, seed=11, period_s=10.0)
    m = StaticModel(get_static_map("chou-hannaford", Geometry(length_mm=200.0)), None, "pressure")
    fit = fit_static(m, runs)
    assert all(rf.nrmse > 3.0 * rf.noise_floor_nrmse for rf in fit.runs)


def test_tondu_lopez_coefficients_are_the_ideal_braids(truth):
    runs = isometric_campaign(truth, HELD, seed=3, period_s=10.0)
    m = StaticModel(get_static_map("tondu-lopez", Geometry(200.0, 10.0)), "duhem", "pressure")
    th = fit_static(m, runs).theta
    a0 = math.radians(truth.braid_angle_deg)
    assert th["a"] == pytest.approx(3 / math.tan(a0) ** 2, rel=0.03)
    assert th["b"] == pytest.approx(1 / math.sin(a0) ** 2, rel=0.03)


def test_the_geometric_map_from_isobaric_runs_too(truth):
    runs = [
        run_test(
            truth, "isobaric", held_mm=18.0, stroke_mm=30.0, pressure_MPa=p, seed=5 + i
        ).to_run(f"b{p}")
        for i, p in enumerate((0.2, 0.35, 0.5, 0.6))
    ]
    m = StaticModel(
        get_static_map("chou-hannaford", Geometry(length_mm=200.0)), "duhem", "position"
    )
    th = fit_static(m, runs).theta
    assert th["theta0_deg"] == pytest.approx(truth.braid_angle_deg, rel=0.03)
    assert th["diameter_mm"] == pytest.approx(truth.diameter_mm, rel=0.03)


def test_free_runs_separate_the_loops_and_predict_every_other_test_type():
    truth = load_static_truth("geometric-both")
    runs = [
        run_test(
            truth, "free", held_mm=x, stroke_mm=10.0, seed=20 + i, period_s=10.0, x_period_s=2.5
        ).to_run(f"f{x:g}")
        for i, x in enumerate((5.0, 15.0, 25.0))
    ]
    others = [
        run_test(truth, "isometric", held_mm=18.0, seed=50, period_s=6.0).to_run("iso18"),
        run_test(truth, "isobaric", held_mm=15.0, pressure_MPa=0.4, seed=51).to_run("bar04"),
        run_test(truth, "isotonic", load_N=150.0, p_min=0.15, seed=52, period_s=6.0).to_run("t150"),
    ]
    m = StaticModel(get_static_map("chou-hannaford", Geometry(length_mm=200.0)), "duhem", "both")
    fit = fit_static(m, runs, others)
    w = fit.hysteresis_widths()
    assert w["p"] == pytest.approx(truth.pressure_friction_N, rel=0.10)
    assert w["x"] == pytest.approx(truth.position_friction_N, rel=0.10)
    # one model of the muscle predicts its isometric, isobaric and isotonic runs
    assert [v.rec.run.test_type for v in fit.validation] == ["isometric", "isobaric", "isotonic"]
    for v in fit.validation:
        assert v.nrmse < 2.0 * v.noise_floor_nrmse, (v.rec.label, v.nrmse, v.noise_floor_nrmse)


def test_identify_static_from_the_command_line(tmp_path, truth):
    write_runs(tmp_path / "iso.h5", isometric_campaign(truth, HELD, seed=2, period_s=6.0))
    write_runs(tmp_path / "held.h5", isometric_campaign(truth, (18.0,), seed=9, period_s=6.0))
    base = ["identify", str(tmp_path / "iso.h5"), "--model", "duhem"]
    code, _, err = _cli([*base, "--static", "chou-hannaford", "--out", str(tmp_path / "x")])
    assert code != 0 and "--length MM" in err and not (tmp_path / "x").exists()
    code, out, err = _cli(
        [
            *base,
            "--static",
            "chou-hannaford",
            "--length",
            "200",
            "--validate",
            str(tmp_path / "held.h5"),
            "--out",
            str(tmp_path / "id"),
        ]
    )
    assert code == 0, err
    assert "theta0_deg" in out and "isometric" in out and "validate" in out
    doc = json.loads((tmp_path / "id" / "identification.json").read_text())
    check_identification(doc, "identification.json")
    params = doc["static_map"]["parameters"]
    assert params["theta0_deg"]["unit"] == "deg" and params["diameter_mm"]["unit"] == "mm"
    assert doc["hysteresis"]["drive"] == "pressure"
    assert doc["hysteresis"]["parameters"]["alpha_p"]["unit"] == "1/MPa"
    assert [v["held_position_mm"] for v in doc["validation"]] == [18.0]
    assert doc["validation"][0]["nrmse"] < 2 * doc["validation"][0]["noise_floor_nrmse"]
    # isometric runs without --static: the static path with the linear map, said so
    code, out, err = _cli([*base, "--out", str(tmp_path / "auto")])
    assert code == 0, err
    assert "static characterization" in err and "linear" in out


def test_report_of_a_static_identification(tmp_path, truth):
    write_runs(tmp_path / "iso.h5", isometric_campaign(truth, HELD[:3], seed=4, period_s=4.0))
    code, _, err = _cli(
        [
            "identify",
            str(tmp_path / "iso.h5"),
            "--static",
            "chou-hannaford",
            "--length",
            "200",
            "--model",
            "duhem",
            "--hold-out",
            "iso-24mm",
            "--out",
            str(tmp_path / "id"),
        ]
    )
    assert code == 0, err
    code, _, err = _cli(
        [
            "report",
            str(tmp_path / "id"),
            "--out",
            str(tmp_path / "r.pdf"),
            "--png",
            str(tmp_path / "png"),
            "--jobs",
            "1",
        ]
    )
    assert code == 0, err
    pngs = sorted(p.name for p in (tmp_path / "png").iterdir())
    assert pngs == [
        "01-summary.png",
        "02-loops-1.png",
        "03-held-out-1.png",
        "04-static-map.png",
        "05-errors.png",
    ]
    assert (tmp_path / "r.pdf").stat().st_size > 10_000
    # pages rendered in worker processes show exactly what one process draws (the
    # command's own report above: --jobs 1)
    one = tmp_path / "r.pdf"
    two = build_static_report(tmp_path / "id", tmp_path / "two.pdf", jobs=2, start_method="spawn")
    assert assert_same_pages(one, two) == len(pngs)
    # a static directory is reported on its own
    code, _, err = _cli(
        ["report", str(tmp_path / "id"), str(tmp_path / "id"), "--out", str(tmp_path / "r2.pdf")]
    )
    assert code != 0 and "alone" in err and not (tmp_path / "r2.pdf").exists()


def test_diagnose_isometric_runs_ranks_the_pressure_laws_on_a_held_out_length(tmp_path):
    code, _, err = _cli(
        [
            "stand",
            "--test",
            "isometric",
            "--held",
            "0,12,24,36",
            "--period",
            "4",
            "--out",
            str(tmp_path / "iso.h5"),
            "--text",
            str(tmp_path / "raw"),
        ]
    )
    assert code == 0, err
    assert len(list((tmp_path / "raw").iterdir())) == 4
    code, _out, err = _cli(
        [
            "diagnose",
            str(tmp_path / "iso.h5"),
            "--model",
            "duhem",
            "--static",
            "chou-hannaford",
            "--length",
            "200",
            "--laws",
            "duhem",
            "--out",
            str(tmp_path / "d"),
        ]
    )
    assert code == 0, err
    doc = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert doc["settings"]["held_out"] == ["iso.h5:isometric_24mm"]
    assert doc["ladder"][0]["law"] is None and doc["ladder"][1]["law"] == "duhem"
    floor = doc["noise_floor"]["mean_nrmse"]
    # the map alone is far from the floor; the pressure law brings it there
    assert doc["ladder"][0]["nrmse"] > 3 * floor
    assert doc["laws"][0]["significant"] and doc["ladder"][1]["nrmse"] < 1.3 * floor
    assert doc["verdict"] == "floor"


def test_a_static_identification_is_refused_by_simulate_with_one_line(tmp_path, truth):
    write_runs(tmp_path / "iso.h5", isometric_campaign(truth, HELD[:2], seed=1, period_s=3.0))
    code, _, err = _cli(
        ["identify", str(tmp_path / "iso.h5"), "--model", "none", "--out", str(tmp_path / "id")]
    )
    assert code == 0, err
    code, _, err = _cli(
        [
            "simulate",
            str(tmp_path / "id"),
            str(tmp_path / "iso.h5"),
            "--out",
            str(tmp_path / "s.h5"),
        ]
    )
    assert code != 0 and "static characterization" in err and "Traceback" not in err
    assert not (tmp_path / "s.h5").exists()


def test_a_law_on_a_drive_no_run_moves_is_refused(truth):
    runs = isometric_campaign(truth, HELD[:2], seed=1, period_s=2.0)
    m = StaticModel(get_static_map("linear"), "duhem", "position")
    with pytest.raises(PmalabError, match=r"contraction is held in every run.*--drive pressure"):
        fit_static(m, runs)


def test_a_loop_proportional_to_pressure_needs_the_pressure_scale():
    """Friction ∝ contact pressure (the loop pinches at p = 0): a constant-width law stays
    ~3× the noise floor; --loop-scale pressure reaches it and recovers the width."""
    truth = load_static_truth("geometric-scaled")
    runs = isometric_campaign(truth, HELD, seed=1, period_s=6.0)
    geo = Geometry(length_mm=200.0)
    flat = fit_static(StaticModel(get_static_map("chou-hannaford", geo), "duhem", "pressure"), runs)
    m = StaticModel(get_static_map("chou-hannaford", geo), "duhem", "pressure", "pressure")
    fit = fit_static(m, runs)
    assert all(rf.nrmse > 2.0 * rf.noise_floor_nrmse for rf in flat.runs)
    assert all(rf.nrmse < 1.2 * rf.noise_floor_nrmse for rf in fit.runs)
    ref = truth.pressure_friction_reference_MPa
    assert m.p_ref is not None
    width_at_ref = fit.hysteresis_widths()["p"] * ref / m.p_ref
    assert width_at_ref == pytest.approx(truth.pressure_friction_N, rel=0.10)
    assert fit.theta["theta0_deg"] == pytest.approx(truth.braid_angle_deg, rel=0.03)


def test_options_outside_the_static_characterization_are_refused(tmp_path, truth):
    write_runs(tmp_path / "iso.h5", isometric_campaign(truth, HELD[:2], seed=1, period_s=2.0))
    base = ["identify", str(tmp_path / "iso.h5"), "--out", str(tmp_path / "o")]
    for extra, word in (
        (["--model", "duhem", "--add", "viscous-friction"], "--add"),
        (["--model", "duhem,bouc-wen", "--static", "linear"], "diagnose --static"),
    ):
        code, _, err = _cli([*base, *extra])
        assert code != 0 and word in err and "Traceback" not in err
        assert not (tmp_path / "o").exists()
