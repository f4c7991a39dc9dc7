"""Where a structured candidate's joint fit starts: a muscle whose slip displacements grow
with pressure, seen at two strokes per level.

The simulated rig's braid friction (pmalab/rig/sim, not identify's laws) is
``data/truth/laws/ms-slip-growing.toml``: four elasto-slide elements whose slip
displacements grow in proportion to the normalised pressure q = (p − p_th)/(p_ref − p_th),
4 N load-cell noise.  The campaign has four levels (0.17–0.53 MPa), each at a full stroke
(0.37 and 1.3 Hz) and at half of it (0.8 Hz), as ``laws-strokes`` has seven.  Started only
from the free structure's laws (every slip displacement where the free fit put it, t = 1),
the ``scaled-thresholds`` joint fit stops in a worse minimum on sensor seed 7: its slip
displacements grow by 2.28× from 0.2 to 0.5 MPa where the truth's grow by 2.82×, and the
500 kPa held-out run's nrmse is 0.056.  The second start, quadratics through the
structured law's own per-run s and t, reaches the truth's growth, and the lower training
cost is kept: growth 2.75× and held-out 0.021 (seeds 7–10: 2.73–2.78× and 0.020–0.022;
from the first start alone 2.28–2.99× and 0.021–0.056).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from sim_campaign import record_campaign

from pmalab.identify import identify
from pmalab.paths import TRUTH_DIR
from pmalab.rig.sim.truth import load_truth
from pmalab.runfile import read_runs

TRUTH = TRUTH_DIR / "laws" / "ms-slip-growing.toml"
LEVELS = (0.17, 0.29, 0.41, 0.53)


def _protocol(path: Path) -> Path:
    """laws-strokes on four of its seven levels (same amplitudes and offsets), one held-out
    run at 0.5 MPa."""
    amp = [0.069 + (0.205 - 0.069) * (p - 0.17) / 0.36 for p in LEVELS]
    off = [0.112 + (0.328 - 0.112) * (p - 0.17) / 0.36 for p in LEVELS]

    def lst(v: list[float]) -> str:
        return "[" + ", ".join(f"{x:.5f}" for x in v) + "]"

    path.write_text(
        '[protocol]\nname = "strokes-small"\ndescription = "two strokes at four levels"\n'
        '[defaults]\nwaveform = "sine"\ncycles = 2\nramp_s = 0.5\nsettle_s = 0.3\n'
        "preload_MPa = 0.03\n"
        '[[campaign]]\nname = "p{muscle_pressure_MPa}-{frequency_Hz}"\nrole = "identification"\n'
        'pair = ["muscle_pressure_MPa", "amplitude_MPa", "offset_MPa"]\n'
        f"muscle_pressure_MPa = {lst(list(LEVELS))}\namplitude_MPa = {lst(amp)}\n"
        f"offset_MPa = {lst(off)}\nfrequency_Hz = [0.37, 1.3]\n"
        '[[campaign]]\nname = "s{muscle_pressure_MPa}-{frequency_Hz}"\nrole = "identification"\n'
        'pair = ["muscle_pressure_MPa", "amplitude_MPa", "offset_MPa"]\n'
        f"muscle_pressure_MPa = {lst(list(LEVELS))}\namplitude_MPa = {lst([a / 2 for a in amp])}\n"
        f"offset_MPa = {lst(off)}\nfrequency_Hz = [0.8]\n"
        '[[run]]\nname = "valid-500kPa-1.7Hz"\nrole = "validation"\nmuscle_pressure_MPa = 0.5\n'
        "frequency_Hz = 1.7\namplitude_MPa = 0.194\noffset_MPa = 0.31\n"
    )
    return path


def test_slip_displacement_growth_is_reached_from_the_per_run_start(tmp_path):
    out = record_campaign(TRUTH, tmp_path, 7, protocol=_protocol(tmp_path / "p.toml"))
    # in this process: the suite runs a pytest worker per core (pools: test_start_methods)
    res = identify(read_runs(out), "maxwell-slip", jobs=1, structure="scaled-thresholds")
    cf = res.campaign
    assert cf.structure is not None and cf.structure.chosen == "scaled-thresholds"
    # the kept fit came from the per-run start (its training nrmse far below the first
    # start's on this campaign)
    assert cf.structure.starts == {"scaled-thresholds": "per-run fits"}

    mu = load_truth(TRUTH).section("muscle")
    pth, pref = mu["threshold_pressure_MPa"], mu["reference_pressure_MPa"]
    grow = (0.5 - pth) / (0.2 - pth)  # the truth's d_i(0.5) / d_i(0.2): 2.82

    def d(p: float) -> np.ndarray:
        th = cf.theta(p)
        return np.array([th[f"d{i}"] for i in range(1, 5)])

    # every slip displacement grows like the truth's within 5 % (measured 2.5 % short;
    # seeds 7-10 ≤ 3.3 %; from the free laws' start alone 19 % short)
    np.testing.assert_allclose(d(0.5) / d(0.2), grow, rtol=0.05)
    # and sits where the truth's does at 0.5 MPa within 10 % (measured ≤ 6.4 %, seeds 7-10
    # too; from the free laws' start alone the third 11 % short)
    fr = load_truth(TRUTH).section("friction")
    truth_d = np.asarray(fr["presliding_mm"]) * (0.5 - pth) / (pref - pth)
    np.testing.assert_allclose(d(0.5), truth_d, rtol=0.1)
    # the held-out run at 0.5 MPa: nrmse 0.021 (seeds 7-10 ≤ 0.022; from the free laws'
    # start alone 0.056)
    (val,) = res.validation
    assert val.metrics["nrmse"] < 0.03, val.metrics
