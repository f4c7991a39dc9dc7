"""The controllers on the simulated manipulator: stability, bounded adaptation, mismatch,
limits (short virtual-clock runs)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from pmalab.control.controllers import default_settings
from pmalab.control.metrics import summarize
from pmalab.control.model import HysteresisState, IdentifiedModel
from pmalab.control.pid import Gains
from pmalab.control.reference import parse_reference
from pmalab.control.runner import run_control
from pmalab.paths import TRUTH_DIR
from pmalab.rig.base import Limits
from pmalab.rig.sim.manipulator import make_sim_manipulator

MODEL = IdentifiedModel.load(None)


def _run(controller, ref="square:0.1Hz:15mm", duration=10.0, settings=None, truth=None, seed=0,
         limits=None):
    rig = make_sim_manipulator(truth, seed=seed, limits=limits)
    with rig:
        return run_control(rig, controller, parse_reference(ref), duration,
                           settings or default_settings(), MODEL), rig


def _position_metrics(run, duration):
    s = run.signals
    return summarize("square", s["time"], s["position"], s["position_reference"],
                     run.reference.step_times(duration))


@pytest.mark.parametrize("controller", ["pid", "sn-pid", "rbf-pid"])
def test_each_controller_stabilises_the_manipulator_on_a_square(controller):
    run, rig = _run(controller)
    assert run.completed, run.status
    m = _position_metrics(run, 10.0)
    assert len(m["steps"]) == 2  # up at 0 s, down at 5 s
    # both steps reach and hold the reference: settled inside the 5 s half period, within
    # 0.5 mm at the end of each (the sensor noise is 0.015 mm)
    assert m["settled"], m
    assert m["steady_state_error"] < 0.5
    assert np.all(np.isfinite(run.signals["muscle_pressure_command"]))
    # the run ends vented and the simulated valve confirms it
    assert run.attrs["vent_confirmed"] is True
    assert rig.info["physics"].command == 0.0


@pytest.mark.parametrize("controller", ["pid", "sn-pid", "rbf-pid"])
def test_each_controller_holds_the_pressure_loop(controller):
    run, _ = _run(controller, "square:0.1Hz:0.5MPa", 10.0)
    assert run.completed
    s = run.signals
    m = summarize("square", s["time"], s["muscle_pressure"], s["muscle_pressure_reference"],
                  run.reference.step_times(10.0))
    assert m["steady_state_error"] < 0.02  # MPa, at the end of each 5 s half period
    assert 0.2 < m["rise_time_s"] < 1.5  # regulator lag + dead time + filling the muscle


@pytest.mark.parametrize("controller", ["sn-pid", "rbf-pid"])
def test_adaptive_gains_stay_inside_their_bounds_even_with_the_largest_rates(controller):
    base = default_settings()
    # the largest gain rates allowed (max_rate = 10) on a network that learns
    rates = {controller: {"eta_p": 10.0, "eta_i": 10.0, "eta_d": 10.0, "eta": 0.5,
                          "alpha": 0.5, "jac_max": 10.0}}
    s = replace(base, outer=replace(base.outer, learning=rates, gain_bounds=(0.5, 2.0)),
                inner=replace(base.inner, learning=rates, gain_bounds=(0.5, 2.0)))
    run, _ = _run(controller, "sine:0.1Hz:20mm", 10.0, settings=s)
    # a run may be stopped by the limits, but never with gains outside their box or NaN
    for loop, ls in (("outer", s.outer), ("inner", s.inner)):
        for name, g0 in zip(("kp", "ki", "kd"), ls.gains.as_tuple()):
            g = run.gains[f"{loop}_{name}"]
            assert np.all(np.isfinite(g))
            assert g.min() >= 0.5 * g0 * (1 - 1e-12) and g.max() <= 2.0 * g0 * (1 + 1e-12)
    moved = [np.ptp(run.gains[k]) > 0 for k in run.gains]
    assert any(moved)  # the laws did adapt something


@pytest.mark.parametrize("hidden", ["hidden-viscous-friction.toml", "hidden-nonlinear-stiffness.toml"])
def test_a_plant_model_mismatch_is_survived(hidden):
    """The identification knows nothing of the hidden effect; every controller still
    follows the 15 mm square."""
    for controller in ("pid", "sn-pid", "rbf-pid"):
        run, _ = _run(controller, truth=TRUTH_DIR / hidden)
        assert run.completed, (controller, run.status)
        m = _position_metrics(run, 10.0)
        assert m["steady_state_error"] < 0.5, (controller, m)


def test_a_diverging_controller_is_stopped_by_the_limits_and_vented():
    """Bang-bang gains swing the link over its whole stroke; a rig whose travel limit is
    16 mm stops the 15 mm square at the first overshoot past it."""
    base = default_settings()
    wild = replace(base, outer=base.outer.with_gains(2000.0, 2000.0, 0.0))
    lim = Limits(max_muscle_pressure_MPa=0.6, min_position_mm=-3.0, max_position_mm=16.0)
    run, rig = _run("pid", "square:0.1Hz:15mm", 10.0, settings=wild, limits=lim)
    assert run.status.startswith("aborted:"), run.status
    assert "outside the travel" in run.status
    assert run.attrs["vent_confirmed"] is True
    assert rig.info["physics"].command == 0.0
    assert run.n > 10  # the samples up to the trip are kept
    assert run.signals["time"][-1] < 10.0


def test_model_inversion_returns_the_pressure_that_gives_the_force():
    rng = np.random.default_rng(3)
    for _ in range(200):
        x, p, h = rng.uniform(0, 22), rng.uniform(0.1, 0.6), rng.uniform(-30, 30)
        f = MODEL.force(x, p, h)
        assert MODEL.invert(f, x, h, 0.6) == pytest.approx(p, abs=1e-9)
    # out of reach: clamped to the regulator's range
    assert MODEL.invert(-1e4, 10.0, 0.0, 0.6) == 0.0
    assert MODEL.invert(1e5, 10.0, 0.0, 0.6) == 0.6


def test_hysteresis_state_steps_like_the_laws_batch_integrator():
    """h advanced sample by sample in the controller equals identify's batch integration
    at a fixed pressure (the controller has no integrator of its own)."""
    from pmalab.identify.laws import get_law

    law = get_law(MODEL.law)
    x = 10 + 5 * np.sin(np.linspace(0, 4 * math.pi, 2001))
    theta = MODEL.theta(0.3)
    batch = law.h(x, {**theta, "h0": 0.0}, {})
    hs = HysteresisState(MODEL, x[0])
    online = [0.0] + [hs.update(float(v), 0.3) for v in x[1:]]
    assert np.allclose(online, batch, atol=1e-9)


def test_same_initial_gains_for_every_controller():
    for c in ("pid", "sn-pid", "rbf-pid"):
        run, _ = _run(c, duration=0.02)
        first = {k: float(v[0]) for k, v in run.gains.items()}
        s = default_settings()
        assert first["outer_kp"] == pytest.approx(s.outer.gains.kp)
        assert first["inner_ki"] == pytest.approx(s.inner.gains.ki)
        assert Gains(first["outer_kp"], first["outer_ki"], first["outer_kd"]).as_tuple() == \
            pytest.approx(s.outer.gains.as_tuple())


def test_ctrl_c_mid_run_vents_and_keeps_the_samples():
    rig = make_sim_manipulator()
    real = rig.sampler.read_block
    calls = {"n": 0}

    def read_block():
        calls["n"] += 1
        if calls["n"] == 301:
            raise KeyboardInterrupt
        return real()

    rig.sampler.read_block = read_block
    with rig:
        run = run_control(rig, "sn-pid", parse_reference("square:0.1Hz:15mm"), 10.0,
                          default_settings(), MODEL)
    assert run.status == "aborted: interrupted (Ctrl-C)"
    assert run.n == 300 and np.all(np.isfinite(run.signals["position"]))
    assert run.attrs["vent_confirmed"] is True
    assert rig.info["physics"].command == 0.0


#: the issue's targets for the adaptive controllers (15 mm square; 20 mm sine), asserted
#: as they are: today's runs hold them with margin (overshoot ≈ 3.4 %, settling ≈ 1.6 s,
#: steady-state error ≈ 0.1 mm, sine RMS ≈ 0.25 mm; README table)
TARGETS = {"overshoot_pct": 5.0, "settling_time_s": 3.0, "steady_state_error": 0.3,
           "sine_rms_mm": 1.0}


@pytest.mark.parametrize("seed", [0, 5])
@pytest.mark.parametrize("controller", ["sn-pid", "rbf-pid"])
def test_adaptive_controllers_meet_the_targets_on_the_square_and_the_sine(controller, seed):
    """Full 20 s runs of the seed experiments (two noise seeds): the square's worst step
    and the sine's RMS error against the raw reference."""
    from pmalab.control.record import run_metrics

    run, _ = _run(controller, "square:0.1Hz:15mm", 20.0, seed=seed)
    m = run_metrics(run)
    assert m["overshoot_pct"] <= TARGETS["overshoot_pct"], m
    assert m["settled"] and m["settling_time_s"] <= TARGETS["settling_time_s"], m
    assert m["steady_state_error"] <= TARGETS["steady_state_error"], m
    run, _ = _run(controller, "sine:0.1Hz:20mm", 20.0, seed=seed)
    assert run_metrics(run)["rms_error"] <= TARGETS["sine_rms_mm"]


@pytest.mark.parametrize("hidden", ["hidden-viscous-friction.toml",
                                    "hidden-nonlinear-stiffness.toml"])
def test_sine_tracking_holds_under_a_plant_model_mismatch(hidden):
    """The hidden effect is unknown to the model the feedforward inverts; the feedback
    still keeps the 20 mm sine within 1 mm RMS (measured 0.5 / 0.75 mm)."""
    from pmalab.control.record import run_metrics

    run, _ = _run("rbf-pid", "sine:0.1Hz:20mm", 20.0, truth=TRUTH_DIR / hidden)
    assert run.completed and run_metrics(run)["rms_error"] <= TARGETS["sine_rms_mm"]


def test_reference_shaper_limits_a_step_and_passes_a_slow_sine():
    from pmalab.control.reference import ReferenceShaper

    sh = ReferenceShaper(30.0, 100.0, 0.002)
    sh.start(0.0)
    out = np.array([sh.step(15.0, 0.0) for _ in range(1500)])  # a 15 mm step, 3 s
    s, v, a = out.T
    assert s.max() <= 15.0 + 1e-6 and abs(s[-1] - 15.0) < 1e-6  # arrives, no overshoot
    assert np.abs(v).max() <= 30.0 + 1e-9 and np.abs(a).max() <= 100.0 + 1e-6
    assert np.argmax(s > 14.7) * 0.002 < 0.9  # trapezoid: 0.3 + 0.2 + 0.3 s ≈ 0.8 s
    ref = parse_reference("sine:0.1Hz:20mm")
    sh = ReferenceShaper(30.0, 100.0, 0.002)
    sh.start(0.0)
    err = [abs(sh.step(*ref.value(k * 0.002)[:2])[0] - ref.value(k * 0.002)[0])
           for k in range(10000)]
    assert max(err) < 0.02  # within the limits the sine passes (to 0.1 % of its 20 mm)


class _HardwareTimed:
    """A hardware-timed view of the simulated manipulator: blocks of 10 samples stamped
    by the device's sample clock; one block arrives 5 samples short (a hole in the stream)."""

    hardware_timed = True

    def __init__(self, rig) -> None:
        self.rig, self.k, self.blocks = rig, 0, 0

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def read_block(self):
        from pmalab.rig.base import Block

        rows = []
        self.blocks += 1
        for _ in range(10):
            if self.blocks == 5 and len(rows) == 2 and not getattr(self, "holed", False):
                self.holed = True
                self.k += 5  # five samples the device never delivered
            t = self.k / 500.0
            self.rig.clock.sleep_until(t)
            o = self.rig.info["physics"].advance_and_sample(t).copy()
            rows.append(o)
            self.k += 1
        a = np.array(rows)
        return Block(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4])


def test_control_on_a_hardware_timed_sampler_records_the_gap_and_invents_nothing():
    rig = make_sim_manipulator()
    hw = _HardwareTimed(rig)
    rig.sampler = hw
    with rig:
        run = run_control(rig, "pid", parse_reference("square:0.1Hz:15mm"), 1.0,
                          default_settings(), MODEL)
    assert run.completed, run.status
    assert run.attrs["n_missed"] == 5
    assert run.n == 501 - 5  # the deadlines of the hole have no rows
    t = run.signals["time"]
    assert np.all(np.isfinite(t)) and np.sum(np.diff(t) > 1.5 / 500) == 1
    assert run.attrs["vent_confirmed"] is True


def test_a_run_streams_its_samples_to_the_sink_in_blocks(monkeypatch):
    """The loop holds one block of buffers, not arrays for the whole run: with a sink every
    sample and gain goes to it block by block, and the run keeps only what its metrics
    read; the blocks joined equal the run recorded without a sink (same seed)."""
    import pmalab.control.runner as cr
    from pmalab.acquisition.loop import LoopStats

    class Sink:
        def __init__(self):
            self.stats, self.blocks = LoopStats(), []

        def due(self):
            return False

        def write(self, signals, gains, lateness):
            self.blocks.append(({**signals}, {**gains}, lateness))

    monkeypatch.setattr(cr, "BLOCK", 128)
    sink = Sink()
    with make_sim_manipulator(None, seed=3) as rig:
        run = run_control(rig, "pid", parse_reference("square:0.5Hz:10mm"), 2.0,
                          default_settings(), MODEL, sink=sink)
    plain, _ = _run("pid", "square:0.5Hz:10mm", 2.0, seed=3)
    assert run.completed and run.n == plain.n == 1001
    assert [len(b[2]) for b in sink.blocks] == [128] * 7 + [105]
    assert set(run.signals) == set(cr.KEPT_WITH_SINK) and run.gains == {}
    joined = np.concatenate([b[0]["position_setpoint"] for b in sink.blocks])
    np.testing.assert_array_equal(joined, plain.signals["position_setpoint"])
    gain = np.concatenate([b[1]["outer_kp"] for b in sink.blocks])
    np.testing.assert_array_equal(gain, plain.gains["outer_kp"])
    np.testing.assert_array_equal(run.signals["position"], plain.signals["position"])
