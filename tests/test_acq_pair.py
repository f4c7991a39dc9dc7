"""Campaign ``pair``: listed fields zipped together, the rest crossed; name templates."""

from __future__ import annotations

import pytest

from pmalab.acquisition.protocol import load_protocol, parse_protocol
from pmalab.errors import ConfigError

LEVELS = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
MAGNITUDES = [0.07, 0.20, 0.28, 0.35, 0.35, 0.35]


def _campaign(body: str) -> str:
    return "[[campaign]]\nname = 'c'\nfrequency_Hz = 0.2\n" + body


def test_pair_zips_the_listed_fields_and_crosses_the_rest():
    p = parse_protocol(_campaign(
        "pair = ['muscle_pressure_MPa', 'magnitude_MPa']\n"
        "muscle_pressure_MPa = [0.1, 0.4]\nmagnitude_MPa = [0.07, 0.35]\n"
        "waveform = ['sine', 'triangle']\n"), "c.toml")
    got = [(r.name, r.muscle_pressure_MPa, r.waveform, round(r.max_command_MPa, 9))
           for r in p.runs]
    assert got == [
        ("c-100kPa-mag70kPa-sine", 0.1, "sine", 0.07),
        ("c-100kPa-mag70kPa-triangle", 0.1, "triangle", 0.07),
        ("c-400kPa-mag350kPa-sine", 0.4, "sine", 0.35),
        ("c-400kPa-mag350kPa-triangle", 0.4, "triangle", 0.35),
    ]
    # without pair the same lists are a full cross product: 2 × 2 × 2
    q = parse_protocol(_campaign(
        "muscle_pressure_MPa = [0.1, 0.4]\nmagnitude_MPa = [0.07, 0.35]\n"
        "waveform = ['sine', 'triangle']\n"), "c.toml")
    assert len(q.runs) == 8


def test_name_template_fills_placeholders():
    p = parse_protocol(
        "[[campaign]]\nname = 'lvl-{muscle_pressure_MPa}-{frequency_Hz}-x'\n"
        "frequency_Hz = [0.1, 0.2]\nmuscle_pressure_MPa = 0.3\nmagnitude_MPa = 0.2\n", "t.toml")
    assert [r.name for r in p.runs] == ["lvl-300kPa-0.1Hz-x", "lvl-300kPa-0.2Hz-x"]


@pytest.mark.parametrize(
    "body, needles",
    [
        ("pair = ['muscle_pressure_MPa', 'magnitude_MPa']\nmuscle_pressure_MPa = [0.1, 0.2]\n"
         "magnitude_MPa = [0.07, 0.2, 0.3]\n",
         ["c.toml: campaign[0] 'c': field 'pair'", "equal lengths",
          "muscle_pressure_MPa has 2", "magnitude_MPa has 3"]),
        ("pair = ['muscle_pressure_MPa', 'magnitude_MPa']\nmuscle_pressure_MPa = [0.1, 0.2]\n"
         "magnitude_MPa = 0.2\n", ["field 'pair'", "'magnitude_MPa' must be given as a list"]),
        ("pair = ['muscle_pressure_MPa', 'cycles']\nmuscle_pressure_MPa = [0.1]\n"
         "magnitude_MPa = 0.2\n", ["field 'pair'", "'cycles' cannot be a list"]),
        ("pair = 'muscle_pressure_MPa'\nmuscle_pressure_MPa = [0.1]\nmagnitude_MPa = 0.2\n",
         ["field 'pair' must be a list of at least two field names"]),
    ],
)
def test_pair_mistakes_are_one_clear_line(body, needles):
    with pytest.raises(ConfigError) as ei:
        parse_protocol(_campaign(body), "c.toml")
    msg = str(ei.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg


def test_pair_outside_a_campaign_and_bad_placeholders_are_refused():
    with pytest.raises(ConfigError, match=r"run\[0\] 'r': field 'pair' is only allowed in"):
        parse_protocol("[[run]]\nname='r'\npair=['a','b']\nmuscle_pressure_MPa=0.1\n"
                       "frequency_Hz=0.1\nmagnitude_MPa=0.1\n", "r.toml")
    with pytest.raises(ConfigError, match=r"unknown placeholder '\{pressure\}'"):
        parse_protocol("[[campaign]]\nname='p-{pressure}'\nmuscle_pressure_MPa=[0.1]\n"
                       "frequency_Hz=0.1\nmagnitude_MPa=0.1\n", "p.toml")
    # a template that does not name a varying field repeats names: refused as duplicates
    with pytest.raises(ConfigError, match=r"run name 'p-0\.1Hz' already used"):
        parse_protocol("[[campaign]]\nname='p-{frequency_Hz}'\n"
                       "muscle_pressure_MPa=[0.1, 0.2]\nfrequency_Hz=0.1\nmagnitude_MPa=0.1\n",
                       "p.toml")


@pytest.mark.parametrize(
    "name, fmt, waveform, freq",
    [("seed-bouc-wen", "pressure-{}kPa", "sine", 0.15),
     ("seed-duhem", "pressure-{}kPa-tri", "triangle", 0.1)],
)
def test_seed_pressure_campaigns_expand_to_the_former_runs(name, fmt, waveform, freq):
    p = load_protocol(name)
    camp = [r for r in p.runs if r.origin.startswith("campaign")]
    assert [r.name for r in camp] == [fmt.format(round(v * 1000)) for v in LEVELS]
    assert [r.muscle_pressure_MPa for r in camp] == LEVELS
    assert [r.amplitude_MPa for r in camp] == pytest.approx([m / 2 for m in MAGNITUDES],
                                                           abs=1e-12)
    assert [r.offset_MPa for r in camp] == pytest.approx([m / 2 for m in MAGNITUDES],
                                                        abs=1e-12)
    for r in camp:
        assert (r.role, r.waveform, r.frequency_Hz) == ("identification", waveform, freq)
        assert (r.cycles, r.ramp_s, r.settle_s) == (3.0, 2.0, 1.0)
    # the campaign comes after the three single runs, as the [[run]] tables did
    assert len(p.runs) == 9 and p.runs[3] is camp[0]


def test_shipped_two_frequency_campaign_pairs_levels_and_crosses_frequencies():
    from pmalab.acquisition.protocol import load_protocol

    runs = load_protocol("two-frequency-campaign").runs
    assert len(runs) == 14 and runs[0].name == "p200kPa-0.25Hz" and runs[-1].name == "p500kPa-1Hz"
    assert {r.frequency_Hz for r in runs} == {0.25, 1.0}
    by_p = {r.muscle_pressure_MPa: (r.amplitude_MPa, r.offset_MPa) for r in runs}
    assert by_p[0.2] == (0.08, 0.13) and by_p[0.5] == (0.24, 0.36)
