"""Model in the loop: ``pmalab control --plant MODEL_DIR`` and the report's sim-to-real page."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from pmalab.cli import main
from pmalab.control.model import SHIPPED_IDENTIFICATION
from pmalab.control.plant import make_plant_manipulator
from pmalab.identify.forward import IdentifiedPlant
from pmalab.runfile import decode_attr


def test_the_plant_settles_where_the_model_muscle_balances_the_spring():
    rig = make_plant_manipulator(SHIPPED_IDENTIFICATION)
    ph = rig.info["physics"]
    rig.muscle_regulator.set_pressure(0.4)
    rig.clock.sleep_until(6.0)
    o = rig.sampler.read_now()
    st = ph.truth_state()
    g = rig.geometry
    # at rest the muscle's tension (model, with its hysteretic state) holds the spring
    assert abs(st["velocity"]) < 0.05
    assert abs(o[2] - g.spring_force(st["contraction"])) < 0.5
    assert abs(o[3] - round(0.4 / ph._q) * ph._q) < 1e-6  # regulator settled, quantised
    # and where the identified static law says: k(p)·x + c0(p) + h = F_s0 + k_s·x
    th = IdentifiedPlant.read(SHIPPED_IDENTIFICATION).theta(float(o[3]))
    x = st["contraction"]
    f_model = th["k"] * x + th["c0"] + ph._h
    assert abs(f_model - g.spring_force(x)) < 0.5
    v = rig.close()
    assert v.ok


@pytest.mark.parametrize("controller", ["pid", "sn-pid", "rbf-pid"])
def test_every_controller_runs_against_the_identified_model(controller, tmp_path):
    out = tmp_path / f"{controller}.h5"
    assert main(["control", "--controller", controller, "--reference", "sine:0.2Hz:20mm",
                 "--duration", "5", "--plant", str(SHIPPED_IDENTIFICATION),
                 "--out", str(out)]) == 0
    with h5py.File(out) as f:
        assert decode_attr(f.attrs["plant"]) == str(SHIPPED_IDENTIFICATION)
        g = f[f"runs/{controller}"]
        x, r = g["position"][:], g["position_reference"][:]
        summary = json.loads(bytes(g["summary"][()]).decode())
        assert summary["metrics"]["completed"] and summary["vent_confirmed"] is True
    late = slice(len(x) // 2, None)  # after the vented start's transient
    assert np.sqrt(np.mean((x[late] - r[late]) ** 2)) < 2.0


def test_an_identification_missing_its_law_parameters_is_one_line(tmp_path, capsys):
    doc = json.loads(SHIPPED_IDENTIFICATION.read_text())
    doc["model"] = "prandtl-ishlinskii"
    bad = tmp_path / "identification.json"
    bad.write_text(json.dumps(doc))
    rc = main(["control", "--controller", "pid", "--reference", "sine:0.2Hz:20mm",
               "--duration", "2", "--plant", str(tmp_path), "--out", str(tmp_path / "o.h5")])
    assert rc != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--plant" in err[0]
    assert not (tmp_path / "o.h5").exists()


def test_report_overlays_model_in_the_loop_and_rig_runs(tmp_path):
    files = []
    for plant in (False, True):
        out = tmp_path / f"{'plant' if plant else 'rig'}.h5"
        args = ["control", "--controller", "pid", "--reference", "square:0.2Hz:15mm",
                "--duration", "5", "--out", str(out)]
        assert main(args + (["--plant", str(SHIPPED_IDENTIFICATION)] if plant else [])) == 0
        files.append(str(out))
    png = tmp_path / "png"
    assert main(["report", *files, "--out", str(tmp_path / "r.pdf"), "--png", str(png)]) == 0
    pages = sorted(p.name for p in png.iterdir())
    assert any("sim-to-real" in p for p in pages), pages
    # without a model-in-the-loop file there is no such page
    png2 = tmp_path / "png2"
    assert main(["report", files[0], "--out", str(tmp_path / "r2.pdf"), "--png", str(png2)]) == 0
    assert not any("sim-to-real" in p.name for p in png2.iterdir())


@pytest.mark.parametrize("controller", ["pid", "sn-pid", "rbf-pid"])
def test_inverse_hysteresis_feedforward_cuts_sine_tracking_error(controller, tmp_path, capsys):
    # the muscle's hysteresis is Maxwell-slip-shaped, the controller's model Bouc-Wen
    from pmalab.paths import DATA_DIR

    truth = str(DATA_DIR / "truth" / "hysteresis-maxwell-slip.toml")
    rms = {}
    for hc in ("on", "off"):
        assert main(["control", "--controller", controller, "--reference", "sine:0.2Hz:20mm",
                     "--duration", "10", "--truth", truth, "--hysteresis-compensation", hc,
                     "--out", str(tmp_path / f"{hc}.h5")]) == 0
        with h5py.File(tmp_path / f"{hc}.h5") as f:
            g = f[f"runs/{controller}"]
            assert json.loads(g.attrs["settings"])["hysteresis_compensation"] is (hc == "on")
            x, r = g["position"][:], g["position_reference"][:]
        late = slice(len(x) // 4, None)
        rms[hc] = float(np.sqrt(np.mean((x[late] - r[late]) ** 2)))
    assert rms["on"] <= 0.9 * rms["off"], rms
