"""Regression: a hidden channel delay on the Bouc-Wen seed campaign (seed-bouc-wen protocol:
identification at 0.15 Hz over six pressures plus two validation runs at 0.1 and 0.3 Hz).

It used to be named viscous friction with sensor-delay 4th and not even ambiguous: the delay
fit stopped in a local minimum of τ, every pressure group got its own τ, and the mean
held-out nrmse was decided by the 100 kPa run alone (the simulated muscle goes slack there,
which no catalogue effect models, and its error is 10× the others').  Seed 23 was not used
while debugging (the demo's seed 0 was).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pmalab.cli import main as pmalab_main
from pmalab.identify.diagnosis import diagnose
from pmalab.paths import TRUTH_DIR
from pmalab.runfile import read_runs

SEED = 23
TRUE_DELAY_S = 0.040  # data/truth/hidden-sensor-delay.toml: position_ms = 40


def test_seed_campaign_delay_is_named_or_ambiguous_with_viscous(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    rig.write_text(f'[rig]\nkind = "sim"\ntruth = "{TRUTH_DIR / "hidden-sensor-delay.toml"}"\n'
                   f"seed = {SEED}\n")
    out = tmp_path / "delay.h5"
    assert pmalab_main(["run", "--rig", str(rig), "--protocol", "seed-bouc-wen", "--out",
                        str(out), "--seed", str(SEED), "--quiet"]) == 0
    d = diagnose(read_runs(out), model="bouc-wen", jobs=1)
    rank = {r["effect"]: r for r in d.ranking}
    delay = rank["sensor-delay"]
    # named outright, or listed as ambiguous with its single-frequency look-alike
    assert d.winner == "sensor-delay" or {"sensor-delay", "viscous-friction"} <= set(d.ambiguous)
    assert delay["significant_alone"]
    # one τ for the whole campaign, near the hidden 40 ms (single-frequency groups pull it
    # somewhat low: there τ trades off against the loop width)
    tau = delay["campaign_params"]["delay_tau"]
    assert abs(tau - TRUE_DELAY_S) < 0.015, tau
    # the delay model brings the held-out error well down on the runs the base law can fit
    r1 = next(r for r in d.rounds if r["step"] == 1)
    cand = next(c for c in r1["candidates"] if c["effect"] == "sensor-delay")
    assert cand["fall_percent"] >= 25.0
    # and the ΔAIC (one parameter for the campaign) is strongly negative
    assert delay["delta_aic"] < -50.0
    # the ranking's fall is the per-run geometric mean, so it is finite and ordered
    falls = [r["fall_percent"] for r in d.ranking if r["ladder_step"] is None]
    assert all(np.isfinite(falls)) and falls == sorted(falls, reverse=True)
