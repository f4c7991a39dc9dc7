"""Truth and rig files: defaults, validation with one clear line per mistake."""

from __future__ import annotations

from pathlib import Path

import pytest

from pmalab.errors import ConfigError
from pmalab.paths import RIGS_DIR, TRUTH_DIR
from pmalab.rig.loader import RIG_KINDS, load_rig
from pmalab.rig.sim.truth import EFFECT_SECTIONS, SCHEMA, default_truth, load_truth


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_default_file_matches_schema_defaults_all_effects_off():
    t = load_truth(None)
    assert t.values == default_truth().values
    assert t.enabled_effects() == []
    # the shipped default spells out every field
    import tomllib

    doc = tomllib.loads((TRUTH_DIR / "default.toml").read_text())
    for sec, fields in SCHEMA.items():
        node = doc
        for part in sec.split("."):
            node = node[part]
        assert set(node) == set(fields), sec


@pytest.mark.parametrize("eid", [*EFFECT_SECTIONS, "two-effects"])
def test_hidden_truth_files_enable_their_effect(eid):
    t = load_truth(TRUTH_DIR / f"hidden-{eid}.toml")
    if eid == "two-effects":
        assert t.enabled_effects() == ["viscous-friction", "asymmetric-hysteresis"]
    else:
        assert t.enabled_effects() == [eid]
    # and the matching rig file loads it
    rig = load_rig(RIGS_DIR / f"sim-{eid}.toml")
    assert rig.info["enabled_effects"] == t.enabled_effects()


@pytest.mark.parametrize("name", [*EFFECT_SECTIONS, "sensor-drift-carried", "two-effects",
                                  "three-modest-effects", "clean"])
def test_subtle_truth_files(name):
    """data/truth/subtle/: the realistic load-cell noise everywhere, one effect each."""
    t = load_truth(TRUTH_DIR / "subtle" / f"{name}.toml")
    expected = {"two-effects": ["viscous-friction", "asymmetric-hysteresis"], "clean": [],
                "three-modest-effects": ["asymmetric-hysteresis", "nonlinear-stiffness",
                                         "sensor-delay"],
                "sensor-drift-carried": ["sensor-drift"]}.get(name, [name])
    assert t.enabled_effects() == expected
    assert t.sensors["force_noise_N"] == 4.0
    if name.startswith("sensor-drift"):
        assert t.effect("sensor-drift")["tare_each_run"] is (name == "sensor-drift")


def test_negative_value_message(tmp_path):
    p = _write(tmp_path, "truth.toml", "[effects.viscous_friction]\nenabled = true\nc = -1\n")
    with pytest.raises(ConfigError) as ei:
        load_truth(p)
    assert str(ei.value) == f"{p}: effects.viscous_friction.c: must be ≥ 0"


def test_one_line_per_mistake(tmp_path):
    p = _write(
        tmp_path,
        "t.toml",
        "[muscle]\nmax_force_N = 'big'\nbogus = 1\n[effects.telepathy]\nenabled = true\n"
        "[effects.inertia]\nenabled = 1\n[extra]\na = 1\n",
    )
    with pytest.raises(ConfigError) as ei:
        load_truth(p)
    lines = str(ei.value).splitlines()
    assert len(lines) == 5, lines
    assert all(line.startswith(f"{p}: ") for line in lines)
    text = str(ei.value)
    assert "muscle.max_force_N: must be a number" in text
    assert "muscle.bogus: unknown key" in text
    assert "effects.telepathy: unknown effect" in text
    assert "effects.inertia.enabled: must be true or false" in text
    assert "extra: unknown section" in text


def test_cross_field_and_list_checks(tmp_path):
    p = _write(tmp_path, "t.toml", "[friction]\npresliding_mm = [1.0, 2.0]\nweights = [1.0]\n")
    with pytest.raises(ConfigError, match=r"friction.weights: must have as many"):
        load_truth(p)
    p = _write(tmp_path, "t2.toml", "[friction]\npresliding_mm = [1.0, -2.0]\n")
    with pytest.raises(ConfigError, match=r"friction.presliding_mm: every element must be > 0"):
        load_truth(p)
    p = _write(tmp_path, "t3.toml", "[effects.sensor_delay]\nposition_ms = 500\n")
    with pytest.raises(ConfigError, match=r"effects.sensor_delay.position_ms: must be ≤ 200"):
        load_truth(p)


def test_missing_and_malformed_truth(tmp_path):
    with pytest.raises(ConfigError, match="truth file not found"):
        load_truth(tmp_path / "nope.toml")
    p = _write(tmp_path, "bad.toml", "[muscle\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_truth(p)


def test_load_rig_sim_and_limits(tmp_path):
    rig = load_rig("sim")
    assert rig.info["kind"] == "sim" and not rig.sampler.hardware_timed
    truth = _write(tmp_path, "my-truth.toml", "[effects.inertia]\nenabled = true\nmass_kg = 3\n")
    rf = _write(
        tmp_path,
        "rig.toml",
        '[rig]\nkind = "sim"\ntruth = "my-truth.toml"\nseed = 7\n[limits]\nmax_force_N = 1800\n',
    )
    rig = load_rig(rf)
    assert rig.limits.max_force_N == 1800.0
    assert rig.info["seed"] == 7 and rig.info["enabled_effects"] == ["inertia"]
    assert rig.info["truth"] == str(truth)
    assert "sim" in RIG_KINDS


@pytest.mark.parametrize(
    "text, message",
    [
        ('[rig]\nkind = "warp"\n', "rig.kind: unknown kind 'warp'"),
        ("[rig]\nseed = 1\n", "rig.kind: missing"),
        ('[rig]\nkind = "sim"\nseed = -3\n', "rig.seed: must be an integer ≥ 0"),
        ('[rig]\nkind = "sim"\ntruth = "absent.toml"\n', "rig.truth: file not found"),
        ('[rig]\nkind = "sim"\ncolour = "red"\n', "rig.colour: unknown key"),
        ('[rig]\nkind = "sim"\n[limits]\nmax_speed = 3\n', "limits.max_speed: unknown limit"),
        (
            '[rig]\nkind = "sim"\n[limits]\nmax_force_N = "x"\n',
            "limits.max_force_N: must be a number",
        ),
        ('[rigg]\nkind = "sim"\n', "rigg: unknown section"),
    ],
)
def test_bad_rig_files_one_line(tmp_path, text, message):
    rf = _write(tmp_path, "rig.toml", text)
    with pytest.raises(ConfigError) as ei:
        load_rig(rf)
    msg = str(ei.value)
    assert "\n" not in msg
    assert msg.startswith(f"{rf}: ") and message in msg, msg


def test_rig_file_with_bad_truth_reports_truth_file(tmp_path):
    _write(tmp_path, "t.toml", "[cylinder]\nbore_mm = 0\n")
    rf = _write(tmp_path, "rig.toml", '[rig]\nkind = "sim"\ntruth = "t.toml"\n')
    with pytest.raises(ConfigError, match=r"t.toml: cylinder.bore_mm: must be > 0"):
        load_rig(rf)


def test_missing_rig_file(tmp_path):
    with pytest.raises(ConfigError, match="rig file not found"):
        load_rig(tmp_path / "none.toml")
