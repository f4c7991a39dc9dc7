"""Diagnosis on simulated campaigns with hidden effects (the simulated rig's truth files).

Protocol design (see ``campaign_protocol``): three pressure levels (0.3, 0.45, 0.6 MPa),
each at TWO frequencies, 3 cycles per run.  Two frequencies at one pressure are what let
the diagnosis tell rate-dependent effects from rate-independent hysteresis: the runs of a
pressure level share every muscle parameter, so viscous friction (∝ ẋ) cannot hide in a
wider hysteresis loop and inertia (∝ ω²x on a sine) cannot hide in the stiffness k.
Inertia needs a faster protocol to be visible at all (its force grows with ω²): 0.5 and
2 Hz instead of 0.25 and 1 Hz.  Sensor drift needs longer runs (its error grows with
elapsed time, 30 N/min is ~7 N over a 14 s run, about the clean model error): 6 cycles at
0.25 and 0.5 Hz.

Thresholds in :mod:`pmalab.identify.diagnosis.ranking` were chosen on seeds 0–2; these tests use
seeds 11 and 12.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from pmalab.cli import main as pmalab_main
from pmalab.identify.diagnosis import diagnose
from pmalab.paths import TRUTH_DIR
from pmalab.runfile import read_runs

LEVELS = ((0.25, 0.1, 0.16), (0.4, 0.18, 0.27), (0.55, 0.27, 0.4))  # p, amplitude, offset (MPa)
HIDDEN = ("viscous-friction", "asymmetric-hysteresis", "nonlinear-stiffness",
          "pressure-variation", "sensor-delay", "inertia", "sensor-drift")


def campaign_protocol(freqs: tuple[float, ...] = (0.25, 1.0), cycles: float = 3) -> str:
    """Protocol TOML: every pressure level at both frequencies (sine, cylinder kept in range)."""
    lines = ['[protocol]', 'name = "diagnose-test"', "",
             "[defaults]", 'waveform = "sine"', f"cycles = {cycles}", "ramp_s = 1.0",
             "settle_s = 0.5", ""]
    for p, amp, off in LEVELS:
        for f in freqs:
            lines += ["[[run]]", f'name = "p{int(p * 1000)}kPa-{f:g}Hz"', 'role = "identification"',
                      f"muscle_pressure_MPa = {p}", f"frequency_Hz = {f}",
                      f"amplitude_MPa = {amp}", f"offset_MPa = {off}", ""]
    return "\n".join(lines)


#: effects that need another protocol: (frequencies, cycles)
PROTOCOLS = {"inertia": ((1.0, 2.5), 6), "sensor-drift": ((0.25, 0.5), 6)}


def simulate(effect: str, out_dir: Path, seed: int, freqs: tuple[float, ...] | None = None) -> Path:
    """Run the protocol on data/rigs/sim-<effect>.toml (``clean``: data/rigs/sim.toml)."""
    f_default, cycles = PROTOCOLS.get(effect, ((0.25, 1.0), 3))
    freqs = freqs or f_default
    tag = "-".join(f"{f:g}" for f in freqs) + f"-{cycles}"
    proto = out_dir / f"protocol-{tag}.toml"
    if not proto.exists():
        proto.write_text(campaign_protocol(freqs, cycles))
    # a rig file of our own: the shipped ones pin seed = 0, and the seed must vary here
    truth = TRUTH_DIR / ("default.toml" if effect == "clean" else f"hidden-{effect}.toml")
    rig = out_dir / f"rig-{effect}-{seed}.toml"
    rig.write_text(f'[rig]\nkind = "sim"\ntruth = "{truth}"\nseed = {seed}\n')
    out = out_dir / f"{effect}-s{seed}-{tag}.h5"
    if not out.exists():
        rc = pmalab_main(["run", "--rig", str(rig), "--protocol", str(proto), "--out", str(out),
                          "--seed", str(seed), "--quiet"])
        assert rc == 0, f"pmalab run failed for {effect}"
    return out


@pytest.fixture(scope="module")
def simdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("diagnose-sim")


@pytest.mark.parametrize("effect", HIDDEN)
def test_hidden_effect_is_named_and_error_halves(effect: str, simdir: Path) -> None:
    runs = read_runs(simulate(effect, simdir, seed=11))
    d = diagnose(runs, model="bouc-wen", jobs=1)
    top = d.ranking[0]
    assert top["effect"] == effect, d.ranking_table()
    assert top["significant"], d.ranking_table()
    fall = 1.0 - top["nrmse_after"] / top["nrmse_before"]
    assert fall >= 0.5, f"{effect}: held-out nrmse fell only {100 * fall:.0f} %\n{d.ranking_table()}"
    assert d.ladder[1]["added"] == effect
    assert d.ladder[-1]["nrmse"] < d.ladder[0]["nrmse"]


def test_clean_data_claims_nothing(simdir: Path) -> None:
    runs = read_runs(simulate("clean", simdir, seed=12))
    d = diagnose(runs, model="bouc-wen", jobs=1)
    assert not any(r["significant"] for r in d.ranking), d.ranking_table()
    assert len(d.ladder) == 1
    assert d.ladder[0]["nrmse"] < 0.02  # the base law fits clean data to ~1 %
    assert d.ambiguous == []


@pytest.mark.slow
def test_two_effects_ladder_finds_both(simdir: Path) -> None:
    runs = read_runs(simulate("two-effects", simdir, seed=12))
    d = diagnose(runs, model="bouc-wen", jobs=2)
    added = {s["added"] for s in d.ladder[1:]}
    assert {"viscous-friction", "asymmetric-hysteresis"} <= added, d.ladder_table()
    nr = [s["nrmse"] for s in d.ladder]
    assert all(b < a for a, b in itertools.pairwise(nr)), d.ladder_table()


def test_single_frequency_delay_is_still_told_from_viscous_friction(simdir: Path) -> None:
    """One frequency only: a channel delay also shifts the hysteresis (its error follows the
    loop slope, largest after reversals) while viscous force follows the velocity, so the
    delay still wins clearly; the runner-up's partial explanation is not called ambiguous.
    (True look-alikes are: see test_diagnose_cli's duplicate user effect.)"""
    runs = read_runs(simulate("sensor-delay", simdir, seed=13, freqs=(0.5,)))
    d = diagnose(runs, model="bouc-wen", effects=["viscous-friction", "sensor-delay"], jobs=1)
    assert d.ranking[0]["effect"] == "sensor-delay", d.ranking_table()
    # on the full-amplitude cycles alone the runner-up explains part of it (1.35× in the
    # seed used here); the margin that matters is the ambiguity rule's (< 85 % of the gain)
    assert d.ranking[1]["nrmse_after"] > 1.2 * d.ranking[0]["nrmse_after"]
    assert d.ambiguous == []


def test_slow_single_frequency_delay_and_viscous_are_ambiguous(simdir: Path) -> None:
    """At 0.25 Hz only, a 40 ms channel delay and viscous friction fit equally well: the
    diagnosis says so and suggests runs at several frequencies."""
    runs = read_runs(simulate("sensor-delay", simdir, seed=14, freqs=(0.25,)))
    d = diagnose(runs, model="bouc-wen", effects=["viscous-friction", "sensor-delay",
                                                  "nonlinear-stiffness"], jobs=1)
    assert set(d.ambiguous) == {"viscous-friction", "sensor-delay"}, d.ranking_table()
    assert "frequenc" in d.suggested_experiment
    assert d.ranking[0]["effect"] in d.ambiguous and d.ranking[0]["significant"]
    assert "Ambiguous" in d.summary


def test_diagnosis_ladder_is_finite_and_falls(simdir: Path) -> None:
    # speed is measured by bench/bench_diagnose.py (make bench), not asserted here
    runs = read_runs(simulate("viscous-friction", simdir, seed=11))
    d = diagnose(runs, model="bouc-wen", jobs=1)
    nr = [s["nrmse"] for s in d.ladder]
    assert np.all(np.isfinite(nr)) and nr[-1] < 0.5 * nr[0], d.ladder_table()


def test_duhem_base_model_names_asymmetry(simdir: Path) -> None:
    """The same diagnosis on a Duhem base: asymmetry enters through direction-dependent α, b."""
    runs = read_runs(simulate("asymmetric-hysteresis", simdir, seed=11))
    d = diagnose(runs, model="duhem", jobs=1)
    assert d.ranking[0]["effect"] == "asymmetric-hysteresis", d.ranking_table()
    assert d.ranking[0]["nrmse_after"] <= 0.5 * d.ranking[0]["nrmse_before"]
