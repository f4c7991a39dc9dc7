"""The antagonistic joint behind the one rig interface, and channels as data end to end:
a second muscle, or a new kind of channel, is the rig's declaration — the loop, the
safety monitor, the recorder and the reader are not touched."""

from __future__ import annotations

import numpy as np
import pytest
from pdf_pages import assert_same_pages

from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.channels import KINDS, Channel, Channels
from pmalab.errors import ConfigError, SafetyAbort
from pmalab.identify.api import identify, load
from pmalab.rig.base import SINGLE_MUSCLE_CHANNELS, Block, Rig
from pmalab.rig.loader import load_rig
from pmalab.runfile import muscles_of, read_run_datasets, read_runs
from tests.test_acq_fakes import TWO_RUNS, FakeSampler, make_fake_rig

SWEEPS = """
[[campaign]]
name = "sweep"
muscle = ["flexor", "extensor"]
muscle_pressure_MPa = [0.3, 0.5]
waveform = "sine"
frequency_Hz = 0.15
magnitude_MPa = 0.5
cycles = 3
"""


@pytest.fixture(scope="module")
def pair_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("pair") / "pair.h5"
    rig = load_rig("data/rigs/sim-pair.toml", seed=4)
    with rig:
        res = run_protocol(rig, parse_protocol(SWEEPS, "p.toml"), out,
                           options=RunnerOptions(progress=False))
    assert [r.status for r in res] == ["completed"] * 4
    assert rig.last_vent is not None and rig.last_vent.ok
    assert [role for role, _ in rig.last_vent.items] == ["flexor regulator", "extensor regulator"]
    return out, rig.info["physics"]


def test_one_file_holds_both_muscles_and_the_joint_angle(pair_file):
    out, _ = pair_file
    assert muscles_of(out) == ("flexor", "extensor")
    d = read_run_datasets(out, "sweep-300kPa-flexor")
    for ch in ("time", "angle", "position_flexor", "force_extensor", "muscle_pressure_extensor",
               "muscle_pressure_command_flexor", "muscle_pressure_command_extensor"):
        assert ch in d
    assert d["angle"][1] == "deg" and 5 < np.ptp(d["angle"][0]) < 80
    # the held muscle's command is its pressure; the driven one's is the sine (0 → 0.5 MPa)
    assert np.allclose(d["muscle_pressure_command_flexor"][0], 0.3)
    assert d["muscle_pressure_command_extensor"][0].max() == pytest.approx(0.5, abs=1e-6)
    # the joint links the muscles: what the flexor gains in contraction, the extensor gives
    s = d["position_flexor"][0] + d["position_extensor"][0]
    assert np.std(s) < 0.2 and abs(np.mean(s) - 20.0) < 0.5  # 2 × the 10 mm mount
    (fl,) = [r for r in read_runs(out, muscle="flexor") if r.name == "sweep-300kPa-flexor"]
    assert np.array_equal(fl.force, d["force_flexor"][0])


def test_identify_fits_each_muscle_within_5_percent_of_its_stiffness(pair_file):
    """Noisy pair records → each muscle's linear stiffness k within 5 % of the truth's static
    stiffness −∂F_s/∂x at the run's pressure (Bouc-Wen with n free)."""
    out, physics = pair_file
    for i, muscle in enumerate(("flexor", "extensor")):
        runs = load(out, muscle=muscle)
        assert {r.attrs["held_muscle"] for r in runs} == {muscle} and len(runs) == 2
        res = identify(runs, "bouc-wen", free=["n"])
        for rf in res.campaign.runs:
            k = -rf.result.params["k"].value
            truth = physics.stiffness(i, rf.p_nom)
            assert abs(k - truth) / truth < 0.05, (muscle, rf.p_nom, k, truth)


def test_a_pair_run_must_name_the_muscle_it_holds(tmp_path):
    rig = load_rig("data/rigs/sim-pair.toml")
    proto = parse_protocol(SWEEPS.replace('muscle = ["flexor", "extensor"]\n', ""), "p.toml")
    with rig, pytest.raises(ConfigError, match=r"field 'muscle' = '': the rig has 2 muscles"):
        run_protocol(rig, proto, tmp_path / "x.h5", options=RunnerOptions(progress=False))
    assert not (tmp_path / "x.h5").exists()
    single = make_fake_rig()
    proto = parse_protocol(TWO_RUNS.replace('name = "first"', 'name = "first"\nmuscle = "flexor"'),
                           "p.toml")
    with pytest.raises(ConfigError, match="the rig has one muscle"):
        run_protocol(single, proto, tmp_path / "y.h5", options=RunnerOptions(progress=False))


class _ThermoSampler(FakeSampler):
    """The fake single-muscle sampler plus a thermocouple on the muscle (a new kind)."""

    def read_block(self) -> Block:
        b = super().read_block()
        t = float(b.time[0])
        temp = 25.0 + 2.0 * t  # warms up: 2 K per second
        return Block.of(b.time, {
            "position": b.position, "force": b.force, "muscle_pressure": b.muscle_pressure,
            "cylinder_pressure": b.cylinder_pressure, "temperature": np.array([temp])})


def test_a_new_channel_kind_is_the_rig_declaration_only(tmp_path, monkeypatch):
    """A thermocouple on the muscle: one kind in the declaration's table, one channel in the
    rig's declaration (with its limit); the runner, loop, safety monitor, recorder and reader
    record it, hold it to its limit, and read it back — none of them names it."""
    monkeypatch.setitem(KINDS, "temperature", "degC")
    decl = Channels((*SINGLE_MUSCLE_CHANNELS[:5],
                     Channel("temperature", "temperature", muscle="muscle", hi=40.0),
                     SINGLE_MUSCLE_CHANNELS[5]))
    base = make_fake_rig()
    rig = Rig(clock=base.clock, sampler=_ThermoSampler(base.clock, base.cylinder_regulator,
                                                        base.muscle_supply),
              cylinder_regulator=base.cylinder_regulator, muscle_supply=base.muscle_supply,
              limits=base.limits, info={"kind": "fake+thermo"})
    rig.channels = decl
    proto = parse_protocol(TWO_RUNS, "t.toml")
    out = tmp_path / "thermo.h5"
    # 2 K/s from 25 °C on the rig clock: the limit at 40 °C trips during the second run
    with pytest.raises(SafetyAbort, match=r"run .second. aborted: temperature 40\.\d+ degC above the limit 40 degC"):
        run_protocol(rig, proto, out, options=RunnerOptions(progress=False))
    d = read_run_datasets(out, "first")
    assert d["temperature"][1] == "degC"
    assert np.allclose(np.diff(d["temperature"][0]), 2.0 * np.diff(d["time"][0]), atol=1e-6)
    # the single-muscle channels beside it are unchanged
    assert all(len(d[c][0]) == len(d["temperature"][0]) for c in ("position", "force", "time"))
    assert d["force"][1] == "N" and d["muscle_pressure"][1] == "MPa"
    assert rig.cylinder_regulator.calls[-1][1] == "vent"


@pytest.mark.parametrize(("controller", "p0"), [("pid", 0.2), ("rbf-pid", 0.35)])
def test_joint_square_at_a_cocontraction_level(controller, p0):
    """The seeds' controllers on the joint angle: a 20° square step up and down within
    overshoot ≤ 5 % and settling ≤ 2 s (the bench holds all three at two levels)."""
    from pmalab.control.joint import StaticPair, default_joint_settings, run_joint
    from pmalab.control.model import IdentifiedModel
    from pmalab.control.reference import parse_reference

    rig = load_rig("data/rigs/sim-pair.toml")
    model = IdentifiedModel.load(None)
    g = rig.geometry
    with rig:
        run = run_joint(rig, controller, parse_reference("square:0.1Hz:20deg"), 10.0,
                        default_joint_settings(p0),
                        StaticPair(model, model, g.mount_contraction_mm, g.radius_mm))
    assert run.completed and run.vent_confirmed
    m = run.metrics
    assert len(m["steps"]) == 2  # the step up at 0 s and down at 5 s
    assert m["overshoot_pct"] <= 5.0 and m["settling_time_s"] <= 2.0, m
    # co-contraction: both muscles stay pressurised around p0 while the joint turns
    sig = run.signals
    late = sig["time"] > 3.0
    mean = 0.5 * (sig["muscle_pressure_command_flexor"] + sig["muscle_pressure_command_extensor"])
    assert np.allclose(mean[late], p0, atol=0.02)


def test_control_cli_runs_the_joint_and_records_it(tmp_path, capsys):
    from pmalab.cli import main
    from pmalab.runfile import read_run_datasets

    out = tmp_path / "joint.h5"
    rc = main(["control", "--rig", "data/rigs/sim-pair.toml", "--controller", "sn-pid",
               "--reference", "square:0.2Hz:15deg", "--cocontraction", "0.3",
               "--duration", "5", "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "joint angle, co-contraction 0.3 MPa" in text and "extensor regulator vented" in text
    d = read_run_datasets(out, "sn-pid")
    assert d["angle"][1] == "deg" and d["angle_reference"][0].max() == 15.0
    assert main(["control", "--rig", "data/rigs/sim-pair.toml", "--controller", "pid",
                 "--reference", "square:0.2Hz:15deg", "--duration", "5", "--out", str(out)]) != 0
    assert "exists" in capsys.readouterr().err  # never overwritten without --force
    assert main(["control", "--controller", "pid", "--reference", "square:0.1Hz:20deg",
                 "--duration", "5", "--out", str(tmp_path / "x.h5")]) != 0
    assert "needs a pair rig" in capsys.readouterr().err


@pytest.fixture(scope="module")
def pair_report(pair_file, tmp_path_factory):
    """``build_report`` of the pair file, its pages drawn in this process (``jobs=1``), with
    its PNGs: the report's own test reads it, and the worker-processes test compares
    against it (one rendering for both)."""
    from pmalab.reports.build import build_report

    out, _ = pair_file
    d = tmp_path_factory.mktemp("pair-report")
    return build_report([out], d / "pair.pdf", png_dir=d / "png", jobs=1), d / "png"


def test_the_report_draws_both_muscles(pair_file, pair_report):
    from pmalab.reports.pair import is_pair_file, load_pair_file, loops_figure

    out, _ = pair_file
    assert is_pair_file(out)
    pf = load_pair_file(out)
    fig = loops_figure(pf)
    axes = fig.axes
    assert [len(ax.lines) for ax in axes] == [2, 2]  # each muscle: its two held runs
    assert axes[0].get_title().startswith("flexor") and axes[1].get_title().startswith("extensor")
    pdf, png = pair_report
    assert pdf.stat().st_size > 0 and len(list(png.glob("*.png"))) == 5


def test_pair_pages_rendered_in_worker_processes_equal_one_process(pair_file, pair_report,
                                                                   tmp_path):
    from pmalab.reports.pair import build_pair_report

    out, _ = pair_file
    one, _ = pair_report  # drawn in one process
    two = build_pair_report([out], tmp_path / "two.pdf", jobs=2, start_method="spawn")
    assert assert_same_pages(one, two, at_least=5) == 5
