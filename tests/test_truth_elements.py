"""A Prandtl-Ishlinskii-shaped simulated muscle's own parameters, predicted by identify's rule.

``bench law_seeds`` scores the truth's own parameters on the held-out runs to tell a fit's
miss from the held-out rule's.  A muscle of eight (or six) play operators off the
Prandtl-Ishlinskii law's grid is no parameter set of pmalab's laws, so the bench restates it
as that many elasto-slide elements (``bench/elasto_slide.py``; an operator of threshold r
and weight w is an element of stiffness w and slip displacement r) with
``pmalab.rig.sim.reference.maxwell_slip_theta(p, truth, elements=n)``, and predicts with
``predict_record`` (start state and force zero from the record's early part).  These tests
hold that restatement to the simulator's load cell, and the element sum to the Maxwell-slip
law it generalises.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from sim_campaign import noise_free_truth, truth_runs

from pmalab.identify.campaign.fit import _as_model
from pmalab.identify.estimation.records import predict_record
from pmalab.identify.model import ForceModel
from pmalab.paths import TRUTH_DIR
from pmalab.rig.sim.truth import load_truth

# bench/ belongs to the repository, not the package: import it from the checkout
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.bench_laws import truth_model  # noqa: E402
from bench.elasto_slide import elements_law  # noqa: E402


@pytest.mark.parametrize(
    "name",
    [
        "hysteresis-prandtl-ishlinskii.toml",  # 8 operators at 0.15·2^i mm, weights falling
        "laws/pi-rising-profile.toml",  # 6 operators, weights rising with the threshold
        "laws/pi-scaled-profile.toml",  # 8 operators, humped profile, curved pressure law
    ],
)
def test_a_play_operator_truth_restated_as_elements_reproduces_its_load_cell(
    tmp_path: Path, name: str
) -> None:
    truth = noise_free_truth(name, tmp_path)
    model, n = truth_model(truth)
    assert n == len(load_truth(truth).section("friction")["presliding_mm"]) > 4
    for r, sig, th in truth_runs(truth, tmp_path, 3, n):
        fm = predict_record(model, sig, th, force=r.force)
        half = len(fm) // 2  # the stroke has wiped the start state by then
        e = r.force[half:] - fm[half:]
        span = float(np.ptp(r.force))
        # the loop's shape: measured on seed 3, the residual's spread is 0.10-0.69 N
        # (<= 0.12 % of a 210-776 N force range; the sensors' 1 ms lags, which the law has
        # not).  Thresholds snapped to the Prandtl-Ishlinskii law's grid spread 0.56-5.1 N
        # (>= 0.18 %), the stiffness taken as the slip force (not ÷ the slip displacement)
        # 11-139 N, and the Maxwell-slip law's four smallest elements alone 5.7-56 N
        assert float(np.std(e)) < 0.0015 * span, (r.name, float(np.std(e)))
        # its level: the force zero estimated on the early part is biased on the 2 Hz runs
        # (mean +0.0 ... +2.2 N there, under 0.1 N at 0.5 Hz): the held-out rule's, kept
        assert float(np.sqrt(np.mean(e**2))) < 0.006 * span, (r.name, float(np.mean(e)))


def test_four_elements_predict_as_the_maxwell_slip_law(tmp_path: Path) -> None:
    # the project's own Maxwell-slip muscle (noise as shipped): the element sum with four
    # elements is that law, so every predicted record is the same to the last bit
    truth = TRUTH_DIR / "hysteresis-maxwell-slip.toml"
    law, mine = _as_model("maxwell-slip"), ForceModel(elements_law(4))
    model, n = truth_model(truth)
    assert n == 4 and model.law.name == "maxwell-slip"
    for r, sig, th in truth_runs(truth, tmp_path, 8):
        a = predict_record(law, sig, th, force=r.force)
        b = predict_record(mine, sig, th, force=r.force)
        assert np.array_equal(a, b), r.name


def test_the_element_sum_is_no_user_law() -> None:
    from pmalab.identify.laws import LAWS

    law = elements_law(8)
    assert law.name == "elasto-slide-8" and law.state_size == 8
    assert [p.name for p in law.params][:2] == ["k1", "k2"] and law.params[-1].name == "h0"
    assert "elasto-slide-8" not in LAWS
    with pytest.raises(ValueError, match="n must be"):
        elements_law(0)
