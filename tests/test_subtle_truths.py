"""data/truth/subtle/ is sized as documented: on the diagnosis-test campaign the base model
validates near the noise floor on clean data, and at 2–4× the floor with an effect hidden,
which ``identify --add`` brings back near the floor.

The floor is estimated from each validation record (pmalab.identify.noise).  Sizes were
chosen with sensor seed 5 (checked with 7); this test records with seed 13.  (`python -m bench
subtle` measures every subtle file; this test keeps to two so the suite stays fast.)
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pmalab.cli import main as pmalab_main
from pmalab.identify.noise import noise_floor_nrmse
from pmalab.paths import TRUTH_DIR
from pmalab.runfile import read_runs, write_runs

SEED = 13


def _record(truth: str, work: Path) -> tuple[Path, Path]:
    rig = work / "rig.toml"
    rig.write_text(f'[rig]\nkind = "sim"\ntruth = "{TRUTH_DIR / "subtle" / truth}"\n')
    both = work / "campaign.h5"
    assert pmalab_main(["run", "--rig", str(rig), "--protocol", "diagnosis-test", "--out",
                        str(both), "--seed", str(SEED), "--quiet"]) == 0
    runs = read_runs(both)
    val = [r for r in runs if r.attrs.get("role") == "validation"]
    assert len(val) == 2
    ident = [r for r in runs if r.attrs.get("role") != "validation"]
    return write_runs(work / "ident.h5", ident), write_runs(work / "val.h5", val)


def _ratio(ident: Path, val: Path, out: Path, *effects: str) -> float:
    """Mean validation nrmse / noise floor of ``identify --validate``."""
    args = ["identify", str(ident), "--model", "bouc-wen", "--validate", str(val), "--out",
            str(out), "--quiet", "--jobs", "1"]
    for e in effects:
        args += ["--add", e]
    assert pmalab_main(args) == 0
    nrmse = {v["run"]: v["nrmse"] for v in
             json.loads((out / "identification.json").read_text())["validation"]}
    floor = {r.name: noise_floor_nrmse(r.steady().force, r.steady().time)
             for r in read_runs(val)}
    assert set(nrmse) == set(floor)
    return float(np.mean([nrmse[k] / floor[k] for k in floor]))


def test_clean_base_model_validates_on_the_noise_floor(tmp_path) -> None:
    ident, val = _record("clean.toml", tmp_path)
    # measured 1.11× (seed 5): the law's shape mismatch hides under the 4 N noise
    assert _ratio(ident, val, tmp_path / "base") < 1.25


def test_viscous_friction_is_subtle_and_adding_it_reaches_the_floor(tmp_path) -> None:
    ident, val = _record("viscous-friction.toml", tmp_path)
    base = _ratio(ident, val, tmp_path / "base")
    added = _ratio(ident, val, tmp_path / "added", "viscous-friction")
    # measured 2.80× → 1.15× (seed 5)
    assert 2.0 <= base <= 4.0
    assert added < 1.3
