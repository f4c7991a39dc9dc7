"""Protocol files: validation (one clear line per mistake), campaigns, shipped seeds, waveforms."""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.acquisition.protocol import load_protocol, parse_protocol
from pmalab.acquisition.waveforms import (
    command,
    command_array,
    command_samples,
    envelope,
    unit_wave,
)
from pmalab.errors import ConfigError
from pmalab.paths import PROTOCOLS_DIR

GOOD_RUN = """
[[run]]
name = "a"
muscle_pressure_MPa = 0.4
frequency_Hz = 0.5
magnitude_MPa = 0.3
"""


def _err(text: str) -> str:
    with pytest.raises(ConfigError) as ei:
        parse_protocol(text, "p.toml")
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith("p.toml: ")
    return msg


@pytest.mark.parametrize(
    "text, needles",
    [
        ("[[run]\nname=1", ["not valid TOML at line 1, column 6"]),
        ("", ["no [[run]] or [[campaign]]"]),
        ("[runs]\nx=1", ["unknown section 'runs'"]),
        (GOOD_RUN.replace("frequency_Hz = 0.5", "frequency_Hz = -1"),
         ["run[0] 'a'", "field 'frequency_Hz'", "must be > 0"]),
        (GOOD_RUN.replace("frequency_Hz = 0.5", "frequency_Hz = 100"),
         ["field 'frequency_Hz'", "≤ 25 Hz"]),
        (GOOD_RUN.replace("frequency_Hz = 0.5", ""), ["missing field 'frequency_Hz'"]),
        (GOOD_RUN.replace("muscle_pressure_MPa = 0.4", "muscle_pressure_MPa = 'high'"),
         ["field 'muscle_pressure_MPa' must be a number", "'high'"]),
        (GOOD_RUN + 'waveform = "sawtooth"\n', ["field 'waveform' must be one of sine, triangle, square"]),
        (GOOD_RUN + 'role = "training"\n', ["field 'role' must be one of"]),
        (GOOD_RUN + "amplitude_MPa = 0.1\n", ["'amplitude_MPa' conflicts with 'magnitude_MPa'"]),
        (GOOD_RUN + "cycels = 3\n", ["unknown field 'cycels'"]),
        (GOOD_RUN + "cycles = 0\n", ["field 'cycles' must be > 0"]),
        (GOOD_RUN.replace("magnitude_MPa = 0.3", "amplitude_MPa = 0.2\noffset_MPa = 0.1"),
         ["field 'offset_MPa' must be ≥ amplitude_MPa"]),
        (GOOD_RUN.replace("magnitude_MPa = 0.3", ""), ["missing field 'amplitude_MPa'"]),
        (GOOD_RUN + GOOD_RUN, ["run[1]", "run name 'a' already used by run[0]"]),
        (GOOD_RUN.replace('name = "a"', 'name = "a/b"'), ["field 'name' must be"]),
        (GOOD_RUN.replace("muscle_pressure_MPa = 0.4", "muscle_pressure_MPa = [0.4, 0.5]"),
         ["field 'muscle_pressure_MPa' must be a single value"]),
        ("[[campaign]]\nname='c'\nmuscle_pressure_MPa=[0.1, 'x']\nfrequency_Hz=0.1\n"
         "magnitude_MPa=0.3", ["campaign[0] 'c'", "field 'muscle_pressure_MPa' must be a number"]),
        ("[[campaign]]\nname='c'\nmuscle_pressure_MPa=[]\nfrequency_Hz=0.1\nmagnitude_MPa=0.3",
         ["empty list"]),
        ("[defaults]\nbogus = 1\n" + GOOD_RUN, ["[defaults]: unknown field 'bogus'"]),
        ("[protocol]\nsample_rate_Hz = 0\n" + GOOD_RUN, ["field 'sample_rate_Hz'"]),
    ],
)
def test_validation_errors_are_one_line_naming_the_field(text, needles):
    msg = _err(text)
    for n in needles:
        assert n in msg, msg


def test_missing_protocol_file_is_one_line(tmp_path):
    with pytest.raises(ConfigError, match="no such protocol file"):
        load_protocol(tmp_path / "nope.toml")


def test_defaults_and_campaign_expansion():
    p = parse_protocol(
        """
[defaults]
cycles = 2
ramp_s = 1.0
[[campaign]]
name = "c"
role = "validation"
muscle_pressure_MPa = [0.1, 0.25]
waveform = ["sine", "triangle", "square"]
frequency_Hz = 0.2
magnitude_MPa = 0.3
""",
        "c.toml",
    )
    names = [r.name for r in p.runs]
    assert names == ["c-100kPa-sine", "c-100kPa-triangle", "c-100kPa-square",
                     "c-250kPa-sine", "c-250kPa-triangle", "c-250kPa-square"]
    r = p.runs[4]
    assert (r.muscle_pressure_MPa, r.waveform, r.role, r.cycles) == (0.25, "triangle",
                                                                     "validation", 2.0)
    assert r.amplitude_MPa == pytest.approx(0.15) and r.offset_MPa == pytest.approx(0.15)
    # settle 1 s + ramps 2 × 1 s + 2 cycles at 0.2 Hz
    assert r.duration_s == pytest.approx(1.0 + 2.0 + 10.0)


@pytest.mark.parametrize(
    "name", ["seed-bouc-wen", "seed-duhem", "quick", "two-frequency-campaign", "diagnosis-test"]
)
def test_shipped_protocols_load(name):
    p = load_protocol(PROTOCOLS_DIR / f"{name}.toml")
    assert p.runs
    for r in p.runs:
        assert 0 < r.muscle_pressure_MPa <= 0.6 and r.max_command_MPa <= 0.9
    assert p.duration_s < 400  # the demo simulates the campaign in seconds


def test_diagnosis_test_campaign_separates_rate_effects_and_stays_small():
    """The campaign the subtle-effect diagnosis tests record once per effect: two
    frequencies (one ≥ 1 Hz for inertia), 3–4 identification pressures, validation runs at
    interior pressures, and under a minute of rig time."""
    p = load_protocol("diagnosis-test")
    ident = [r for r in p.runs if r.role == "identification"]
    val = [r for r in p.runs if r.role == "validation"]
    freqs = {r.frequency_Hz for r in ident}
    assert len(freqs) >= 2 and max(freqs) >= 1.0
    levels = sorted({r.muscle_pressure_MPa for r in ident})
    assert 3 <= len(levels) <= 4
    assert val and all(levels[0] < r.muscle_pressure_MPa < levels[-1] for r in val)
    assert {r.frequency_Hz for r in val} == freqs  # each rate is validated
    assert p.duration_s < 60


def test_seed_bouc_wen_matches_the_paper():
    p = load_protocol("seed-bouc-wen")
    by = {r.name: r for r in p.runs}
    ident = [r for r in p.runs if r.role == "identification" and r.muscle_pressure_MPa == 0.4762]
    assert len(ident) == 1
    r = ident[0]
    assert (r.frequency_Hz, r.waveform, r.max_command_MPa, r.min_command_MPa) == \
        (0.15, "sine", pytest.approx(0.35), pytest.approx(0.0))
    val = sorted((r.muscle_pressure_MPa, r.frequency_Hz, round(r.max_command_MPa, 6))
                 for r in p.runs if r.role == "validation")
    assert val == [(0.304, 0.3, 0.25), (0.498, 0.1, 0.37)]
    levels = sorted(r.muscle_pressure_MPa for r in by.values() if r.name.startswith("pressure"))
    assert levels[0] <= 0.1 and levels[-1] == pytest.approx(0.6) and len(levels) >= 5


def test_seed_duhem_matches_the_paper():
    p = load_protocol("seed-duhem")
    ident = [r for r in p.runs if r.muscle_pressure_MPa == 0.3102]
    assert ident and ident[0].waveform == "triangle" and ident[0].frequency_Hz == 0.1
    val = {r.muscle_pressure_MPa: r for r in p.runs if r.role == "validation"}
    assert set(val) == {0.3984, 0.451}
    v = val[0.451]
    assert (v.waveform, v.frequency_Hz, round(v.max_command_MPa, 6)) == ("sine", 0.2, 0.31)
    assert max(r.muscle_pressure_MPa for r in p.runs) == pytest.approx(0.6)


# --------------------------------------------------------------------------- waveforms
def test_unit_waves_start_at_minimum_and_peak_mid_period():
    for wf in ("sine", "triangle", "square"):
        assert unit_wave(wf, 0.0) == pytest.approx(-1.0)
        assert unit_wave(wf, 0.5) == pytest.approx(1.0)
        assert unit_wave(wf, 1.0) == pytest.approx(-1.0)
    assert unit_wave("sine", 0.25) == pytest.approx(0.0, abs=1e-12)
    assert unit_wave("triangle", 0.25) == pytest.approx(0.0)
    assert unit_wave("triangle", 0.125) == pytest.approx(-0.5)  # linear
    assert unit_wave("triangle", 0.875) == pytest.approx(-0.5)
    # square: flat plateaus, raised-cosine edges of 5 % of a period centred on 1/4, 3/4
    assert unit_wave("square", 0.2) == -1.0 and unit_wave("square", 0.3) == 1.0
    assert unit_wave("square", 0.25) == pytest.approx(0.0, abs=1e-12)
    ph = np.linspace(0, 1, 20001)
    sq = np.array([unit_wave("square", p) for p in ph])
    assert np.max(np.abs(np.diff(sq))) < 0.01  # no step anywhere
    assert np.mean(sq) == pytest.approx(0.0, abs=1e-3)


@pytest.mark.parametrize("wf", ["sine", "triangle", "square"])
def test_run_command_timeline(wf):
    (r,) = parse_protocol(GOOD_RUN + f'waveform = "{wf}"\nsettle_s = 1.0\nramp_s = 2.0\n'
                          "cycles = 3\n", "w.toml").runs
    dt = 1 / 500
    t = np.arange(0, r.duration_s + dt / 2, dt)
    c = command_array(r, t)
    assert np.all(c >= 0) and c.max() == pytest.approx(0.3, abs=1e-6)
    assert np.all(c[t < r.settle_s] == 0.0)  # settle at zero command
    assert c[0] == 0 and c[-1] == pytest.approx(0.0, abs=1e-9)  # starts and ends vented
    steady = (t >= r.steady_start_s) & (t <= r.steady_end_s)
    # in the steady window: offset + amplitude·w, periodic with 1/f, starting at the minimum
    assert command(r, r.steady_start_s) == pytest.approx(0.0, abs=1e-9)
    assert command(r, r.steady_start_s + 0.5 / r.frequency_Hz) == pytest.approx(0.3)
    period = int(round(500 / r.frequency_Hz))
    cs = c[steady]
    np.testing.assert_allclose(cs[period:2 * period], cs[:period], atol=1e-9)
    assert np.mean(cs[:3 * period]) == pytest.approx(0.15, abs=2e-3)  # offset
    # ramps are smooth: the envelope is C1 (raised cosine), no jumps in the command
    assert np.max(np.abs(np.diff(c))) < 0.3 * 2 * np.pi * r.frequency_Hz * dt * 3 + 0.02
    env = np.array([envelope(r, x) for x in t])
    assert np.all(np.diff(env[t <= r.steady_start_s]) >= -1e-12)
    assert np.all(np.diff(env[t >= r.steady_end_s]) <= 1e-12)


@pytest.mark.parametrize("wf", ["sine", "triangle", "square"])
def test_precomputed_commands_equal_the_scalar_definition(wf):
    (r,) = parse_protocol(GOOD_RUN + f'waveform = "{wf}"\n', "w.toml").runs
    n = int(r.duration_s * 500) + 1
    np.testing.assert_allclose(command_samples(r, 500.0, n),
                               command_array(r, np.arange(n) / 500.0), atol=1e-12)


def test_commands_generated_block_by_block_equal_the_whole_run():
    """The runner generates a run's commands a block at a time as it plays them (never the
    whole list): same values at every deadline, also across block edges and after a gap of
    missed deadlines skips ahead."""
    from pmalab.acquisition.runner import CommandBlocks

    (r,) = parse_protocol(GOOD_RUN + 'waveform = "triangle"\n', "w.toml").runs
    n = int(r.duration_s * 500) + 1
    whole = command_samples(r, 500.0, n)
    blocks = CommandBlocks(r, 500.0, n, block=97)
    ks = [*range(0, 300), *range(1000, n, 7)]  # a gap of 700 missed deadlines, then strided
    assert [blocks[k] for k in ks] == whole[ks].tolist()
    assert len(blocks._values) <= 97  # one block held at a time
    with pytest.raises(IndexError):
        blocks[n]


def test_preload_is_held_while_settling_and_blended_by_the_ramp():
    import numpy as np

    from pmalab.acquisition.protocol import parse_protocol
    from pmalab.acquisition.waveforms import command, command_array, command_samples

    spec = parse_protocol(
        '[[run]]\nname = "r"\nmuscle_pressure_MPa = 0.3\nfrequency_Hz = 0.5\n'
        'magnitude_MPa = 0.2\npreload_MPa = 0.03\nsettle_s = 1.0\nramp_s = 2.0\n'
    ).runs[0]
    assert command(spec, 0.5) == 0.03  # settle: preload
    t = np.arange(0, spec.steady_start_s + 0.2, 0.002)
    c = command_array(spec, t)
    assert np.max(np.abs(np.diff(c))) < 0.002  # continuous into and through the ramp
    assert abs(command(spec, spec.steady_start_s)) < 1e-9  # cycles start at the minimum
    np.testing.assert_allclose(command_samples(spec, 500.0, t.size), c, atol=1e-12)
    with pytest.raises(ConfigError, match="preload_MPa"):
        parse_protocol('[[run]]\nname = "r"\nmuscle_pressure_MPa = 0.3\nfrequency_Hz = 0.5\n'
                       'magnitude_MPa = 0.2\npreload_MPa = 0.5\n')
