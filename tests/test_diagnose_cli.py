"""`pmalab diagnose` end to end on a small simulated campaign: outputs, refusals, errors."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from pmalab.cli import main as pmalab_main
from pmalab.paths import RIGS_DIR

PROTOCOL = """
[protocol]
name = "diag-cli"
[defaults]
waveform = "sine"
cycles = 3
ramp_s = 1.0
settle_s = 0.5
[[run]]
name = "p300-0.25Hz"
muscle_pressure_MPa = 0.3
frequency_Hz = 0.25
amplitude_MPa = 0.12
offset_MPa = 0.19
[[run]]
name = "p300-1Hz"
muscle_pressure_MPa = 0.3
frequency_Hz = 1.0
amplitude_MPa = 0.12
offset_MPa = 0.19
[[run]]
name = "p500-0.25Hz"
muscle_pressure_MPa = 0.5
frequency_Hz = 0.25
amplitude_MPa = 0.24
offset_MPa = 0.36
[[run]]
name = "p500-1Hz"
muscle_pressure_MPa = 0.5
frequency_Hz = 1.0
amplitude_MPa = 0.24
offset_MPa = 0.36
"""


@pytest.fixture(scope="module")
def viscous_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("diag-cli")
    proto = d / "p.toml"
    proto.write_text(PROTOCOL)
    out = d / "visc.h5"
    assert pmalab_main(["run", "--rig", str(RIGS_DIR / "sim-viscous-friction.toml"),
                        "--protocol", str(proto), "--out", str(out), "--seed", "31",
                        "--quiet"]) == 0
    return out


def test_diagnose_writes_contract_outputs(viscous_file: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "diag"
    rc = pmalab_main(["diagnose", str(viscous_file), "--model", "bouc-wen", "--out", str(out),
                      "--max-steps", "1"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "Effect ranking" in text and "Ladder" in text and "viscous-friction" in text
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["model"] == "bouc-wen"
    top = doc["ranking"][0]
    assert top["effect"] == "viscous-friction" and top["significant"] is True
    for r in doc["ranking"]:
        assert {"effect", "nrmse_before", "nrmse_after", "significant", "fall_se_percent", "n_params",
                "explanation"} <= set(r)
        assert isinstance(r["significant"], bool)
    assert isinstance(doc["ambiguous"], list) and isinstance(doc["suggested_experiment"], str)
    lad = doc["ladder"]
    assert lad[0] == {**lad[0], "step": 0, "effects": [], "added": None}
    assert lad[1]["added"] == "viscous-friction" and lad[1]["nrmse"] < 0.5 * lad[0]["nrmse"]
    assert all("fit_percent" in s for s in lad)
    assert len(doc["diagnostics"]) == 4
    for key, dg in doc["diagnostics"].items():
        assert key.startswith("visc.h5:")
        assert set(dg["binned"]) >= {"position", "velocity", "velocity_sign", "acceleration",
                                     "pressure_deviation", "time", "branch"}
        for b in dg["binned"].values():
            assert len(b["centers"]) == len(b["mean"]) == len(b["ci95"]) and b["unit"]
        for k in ("acf", "ccf_input"):
            assert len(dg[k]["lags_s"]) == len(dg[k]["values"]) and dg[k]["bound95"] > 0
        assert "branch" in dg["worst_region"]
    assert doc["summary"]
    with h5py.File(out / "predictions.h5") as f:
        assert f.attrs["format"] == "pmalab.predictions"
        roles = [g.attrs["role"] for g in f["runs"].values()]
        assert roles.count("diagnosis") == 4 and roles.count("diagnosis-final") == 4
        g = next(iter(f["runs"].values()))
        for ch in ("time", "position", "muscle_pressure", "force", "force_model"):
            assert g[ch].shape == g["time"].shape
        for a in ("file", "run", "muscle_pressure_MPa", "frequency_Hz", "waveform", "model"):
            assert a in g.attrs
        finals = [g for g in f["runs"].values() if g.attrs["role"] == "diagnosis-final"]
        e = [np.sqrt(np.mean((g["force"][()] - g["force_model"][()]) ** 2)) for g in finals]
        assert max(e) < 15.0  # N: the final model follows the measurement
    # refuses to overwrite without --force
    rc = pmalab_main(["diagnose", str(viscous_file), "--model", "bouc-wen", "--out", str(out),
                      "--quiet"])
    assert rc != 0
    assert "already exists" in capsys.readouterr().err


def test_diagnose_errors_are_one_line(viscous_file: Path, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    rc = pmalab_main(["diagnose", str(viscous_file), "--model", "bouc-wen", "--out",
                      str(tmp_path / "a"), "--only", "magic", "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0 and "unknown effect 'magic'" in err and len(err.strip().splitlines()) == 1
    bad = tmp_path / "bad.py"
    bad.write_text("raise RuntimeError('boom')\n")
    rc = pmalab_main(["diagnose", str(viscous_file), "--model", "bouc-wen", "--out",
                      str(tmp_path / "b"), "--effects", str(bad), "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0 and "bad.py: could not load effects (line 1): RuntimeError: boom" in err
    rc = pmalab_main(["diagnose", str(tmp_path / "none.h5"), "--model", "bouc-wen", "--out",
                      str(tmp_path / "c"), "--quiet"])
    assert rc != 0 and "no such file" in capsys.readouterr().err


def test_validate_files_and_user_effect(viscous_file: Path, tmp_path: Path) -> None:
    """--validate scores on held-out runs; a user effect from --effects takes part."""
    from pmalab.identify.diagnosis import diagnose
    from pmalab.identify.effects import EFFECTS
    from pmalab.runfile import read_runs

    runs = read_runs(viscous_file)
    user = tmp_path / "my_effects.py"
    user.write_text(
        "from pmalab.identify.effects.base import Effect\n"
        "from pmalab.identify.params import Param\n\n"
        "class LinearDamping(Effect):\n"
        "    id = 'my-damping'\n"
        "    title = 'my damping'\n"
        "    explanation = 'a user copy of viscous friction'\n"
        "    signature = 'residual ~ velocity'\n\n"
        "    def params(self, sig, force_scale):\n"
        "        return [Param('my_c', 0.0, 0.0, 50.0, 'N·s/mm')]\n\n"
        "    def force(self, sig, h, theta):\n"
        "        return -theta['my_c'] * sig.v\n")
    try:
        d = diagnose([runs[0], runs[1], runs[2], runs[3]], validate=[runs[1], runs[3]],
                     effects=["viscous-friction", "sensor-drift"], effects_files=[user],
                     max_steps=1)
    finally:
        EFFECTS.pop("my-damping", None)
    ids = [r["effect"] for r in d.ranking]
    assert "my-damping" in ids
    assert set(ids[:2]) == {"viscous-friction", "my-damping"}
    assert d.ranking[0]["nrmse_after"] < 0.5 * d.ranking[0]["nrmse_before"]
    assert set(d.ambiguous) == {"viscous-friction", "my-damping"}
    assert d.suggested_experiment
