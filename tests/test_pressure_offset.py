"""The diagnosis tells a wrong pressure label from pressure that varies within the run.

On the small two-frequency campaign (data/protocols/diagnosis-test.toml, realistic 4 N
load-cell noise of data/truth/subtle/):

* clean data whose labels are shifted by known offsets (±20–35 kPa, as a file name's "3bar"
  on a run that held 0.27 MPa): the ladder adds ``pressure-offset`` (each run at its measured
  mean), not ``pressure-variation``, and the fall it shows is ``identify --add
  pressure-offset``'s, which is ``identify --pressure measured``'s;
* a muscle whose pressure follows its volume within each run (correct labels): the ladder
  adds ``pressure-variation``, not ``pressure-offset``;
* clean data with correct labels: neither (and pressure-offset is not even scored when every
  label agrees with its measurement).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from sim_campaign import record_campaign

from pmalab.identify.api import identify, load
from pmalab.identify.diagnosis import diagnose
from pmalab.identify.labels import check_runs, use_measured
from pmalab.paths import DATA_DIR, TRUTH_DIR

PROTOCOL = DATA_DIR / "protocols" / "diagnosis-test.toml"
SEED = 7
#: label − measured (MPa) given to the campaign's runs, in file order
OFFSETS = [0.030, -0.025, 0.020, -0.035, 0.025, -0.030, 0.035, -0.020, 0.030, -0.025]
CANDIDATES = ["pressure-offset", "pressure-variation"]


def _record(truth: str, work: Path) -> list:
    return load(record_campaign(TRUTH_DIR / "subtle" / truth, work, SEED, PROTOCOL))


def _mislabel(runs: list) -> list:
    out = []
    for r, d in zip(runs, OFFSETS, strict=True):
        attrs = {**r.attrs, "muscle_pressure_MPa": float(r.nominal_pressure) + d}
        out.append(replace(r, attrs=attrs))
    return out


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> list:
    return _record("clean.toml", tmp_path_factory.mktemp("clean"))


def _split(runs: list) -> tuple[list, list]:
    return ([r for r in runs if r.attrs.get("role") != "validation"],
            [r for r in runs if r.attrs.get("role") == "validation"])


def test_label_offsets_are_added_as_pressure_offset_not_variation(clean):
    runs = _mislabel(clean)
    checks = check_runs(runs, whole_run=True)
    assert all(c.offset for c in checks)  # every label is seen to be off ...
    # ... by the offsets given (to the regulator's 1 kPa around its setpoint)
    got = [-1000 * c.offset_MPa for c in checks]
    want = [1000 * d for r, d in zip(clean, OFFSETS) for c in checks if c.run == r.label]
    np.testing.assert_allclose(got, want, atol=1.0)
    d = diagnose(runs, "bouc-wen", effects=CANDIDATES, laws=(), max_steps=2, jobs=1)
    added = [s["added"] for s in d.ladder[1:]]
    assert added[:1] == ["pressure-offset"] and "pressure-variation" not in added, d.summary
    row = {r["effect"]: r for r in d.ranking}
    assert row["pressure-offset"]["fall_percent"] > 50.0  # a 10 % label error is gross
    assert not row["pressure-variation"]["significant_alone"]
    assert "pressure-offset, step 1" in d.summary and "labels are off" in d.summary
    # the fall shown is identify's with the effect, and identify --pressure measured's
    train, val = _split(runs)
    res = identify(train, "bouc-wen", effects=["pressure-offset"], validate=val, jobs=1)
    mean = float(np.mean([v.metrics["nrmse"] for v in res.validation]))
    assert mean == pytest.approx(d.ladder[1]["nrmse"], rel=0.02)
    res = identify(use_measured(train), "bouc-wen", validate=use_measured(val), jobs=1)
    assert float(np.mean([v.metrics["nrmse"] for v in res.validation])) == pytest.approx(
        mean, rel=0.02
    )


def test_within_run_variation_is_added_as_pressure_variation_not_offset(tmp_path):
    runs = _record("pressure-variation.toml", tmp_path)
    d = diagnose(runs, "bouc-wen", effects=CANDIDATES, laws=(), max_steps=2, jobs=1)
    added = [s["added"] for s in d.ladder[1:]]
    assert added[:1] == ["pressure-variation"] and "pressure-offset" not in added, d.summary
    row = {r["effect"]: r for r in d.ranking}
    assert not row["pressure-offset"]["significant_alone"]


def test_clean_data_with_true_labels_adds_neither(clean):
    d = diagnose(clean, "bouc-wen", effects=CANDIDATES, laws=(), max_steps=2, jobs=1)
    assert len(d.ladder) == 1, d.summary
    assert not any(r["significant_alone"] for r in d.ranking)
    # by default (the whole catalogue) the offset is not scored where no label is off
    d = diagnose(clean, "bouc-wen", laws=(), max_steps=0, jobs=1)
    assert "pressure-offset" in d.settings["not_scored"]
    assert "pressure-offset" not in d.settings["candidates"]
