"""Shipped data (package data under ``pmalab/data``) is found by name or by the path a clone
shows, from any working directory; a path that names nothing shipped is left as typed, so
the reader's one-line error names what the user wrote."""

from __future__ import annotations

from pathlib import Path

import pytest

from pmalab.control.experiments import load_experiments
from pmalab.control.model import IdentifiedModel
from pmalab.errors import ConfigError
from pmalab.paths import DATA_DIR, PROTOCOLS_DIR, RIGS_DIR, TRUTH_DIR, shipped
from pmalab.rig.sim.truth import load_truth

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def elsewhere(tmp_path, monkeypatch) -> Path:
    """A working directory outside the repository (no ``data/`` link in sight)."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_data_dir_is_inside_the_package_and_the_clone_link_points_to_it():
    import pmalab

    assert DATA_DIR == Path(pmalab.__file__).parent / "data"
    assert (DATA_DIR / "protocols" / "seed-bouc-wen.toml").is_file()
    link = ROOT / "data"
    if link.exists():  # a clone (an installed wheel has no top-level data/)
        assert link.is_symlink() and link.resolve() == DATA_DIR.resolve()


@pytest.mark.parametrize(("spec", "folder", "want"), [
    ("seed-bouc-wen", PROTOCOLS_DIR, PROTOCOLS_DIR / "seed-bouc-wen.toml"),
    ("seed-bouc-wen.toml", PROTOCOLS_DIR, PROTOCOLS_DIR / "seed-bouc-wen.toml"),
    ("data/rigs/labjack-t7.toml", RIGS_DIR, RIGS_DIR / "labjack-t7.toml"),
    ("sim", RIGS_DIR, RIGS_DIR / "sim.toml"),
    ("subtle/clean", TRUTH_DIR, TRUTH_DIR / "subtle" / "clean.toml"),
    ("data/truth/subtle/clean.toml", TRUTH_DIR, TRUTH_DIR / "subtle" / "clean.toml"),
])
def test_shipped_names_resolve_from_anywhere(elsewhere, spec, folder, want):
    assert shipped(spec, folder) == want


def test_a_local_file_wins_over_a_shipped_one_and_unknown_names_stay_as_typed(elsewhere):
    (elsewhere / "sim.toml").write_text("# mine\n")
    assert shipped("sim.toml", RIGS_DIR) == Path("sim.toml")
    assert shipped("no-such-rig", RIGS_DIR) == Path("no-such-rig")
    assert shipped("data/rigs/no-such.toml", RIGS_DIR) == Path("data/rigs/no-such.toml")
    assert shipped("../rigs/sim.toml", TRUTH_DIR) == Path("../rigs/sim.toml")  # no climbing


def test_truth_experiments_and_identifications_by_clone_path_outside_a_clone(elsewhere):
    t = load_truth("data/truth/hidden-viscous-friction.toml")
    assert t.values == load_truth(TRUTH_DIR / "hidden-viscous-friction.toml").values
    assert t.enabled_effects() == ["viscous-friction"]
    assert t.source == "data/truth/hidden-viscous-friction.toml"  # messages name what was typed
    assert load_truth("subtle/clean").values == load_truth(TRUTH_DIR / "subtle" / "clean.toml").values
    a = load_experiments("data/control/seed-experiments.toml")
    b = load_experiments("seed-experiments")
    assert a == b
    m = IdentifiedModel.load("data/control/identification-duhem.json")
    assert m.law == "duhem" and m.coef == IdentifiedModel.load("identification-duhem").coef
    assert IdentifiedModel.load(None).law == "bouc-wen"  # the default


def test_a_missing_truth_is_one_line_naming_the_typed_path(elsewhere):
    with pytest.raises(ConfigError) as exc:
        load_truth("data/truth/hidden-nothing.toml")
    assert "data/truth/hidden-nothing.toml" in str(exc.value)
    assert "\n" not in str(exc.value)
