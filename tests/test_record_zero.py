"""The force zero of a predicted record after a ramp-in: no bias from the start state.

A recorded run's steady window opens after a ramp-in that leaves the braid's friction
elements in a minor-loop state an element law's one-number start state h0 cannot express;
the misfit lasts until the stroke has crossed its whole range once.  A force zero estimated
on samples that include that misfit carries it into the whole scored rest of the record.
Here the simulated muscles' own parameters (noise-free load cell and position) predict every
run of a campaign by the held-out rule (:func:`~pmalab.identify.estimation.records.predict_record`),
and the scored part's mean residual must stay within ``TOL_N``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from sim_campaign import noise_free_truth, truth_runs

from pmalab.identify.estimation.records import predict_record, scored_from

# bench/ belongs to the repository, not the package: import it from the checkout
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.bench_laws import truth_model  # noqa: E402

#: the largest scored-part mean residual (N) a noise-free truth may keep
TOL_N = 0.8


@pytest.mark.parametrize(
    "name", ["hysteresis-maxwell-slip.toml", "hysteresis-prandtl-ishlinskii.toml"]
)
def test_noise_free_truth_has_no_zero_bias_after_a_ramp_in(tmp_path: Path, name: str) -> None:
    truth = noise_free_truth(name, tmp_path)
    model, n = truth_model(truth)
    for r, sig, th in truth_runs(truth, tmp_path, 3, n):
        fm = predict_record(model, sig, th, force=r.force)
        s = scored_from(sig)
        bias = float(np.mean(r.force[s:] - fm[s:]))
        assert abs(bias) <= TOL_N, (r.name, bias)
