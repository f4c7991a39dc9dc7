"""Each hidden effect, when enabled, changes what it should (and only that)."""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.paths import TRUTH_DIR
from pmalab.rig.sim.demo import hysteresis_width, run_isobaric
from pmalab.rig.sim.reference import baseline_tension, static_force
from pmalab.rig.sim.truth import default_truth, load_truth

P0 = 0.4762


def _run(eid: str | None, **kw) -> dict:
    truth = None if eid is None else TRUTH_DIR / f"hidden-{eid}.toml"
    kw.setdefault("muscle_MPa", P0)
    return run_isobaric(truth, **kw)


def _branch_masks(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k = 25
    xs = np.convolve(x, np.ones(k) / k, mode="same")
    v = np.gradient(xs)
    return v < -0.002, v > 0.002


def test_sensor_delay_shifts_position_against_force():
    def lag(d):
        meas, true = d["position"], d["true_position"]
        errs = [np.sqrt(np.mean((meas[k:] - true[: len(true) - k]) ** 2)) for k in range(0, 40)]
        return int(np.argmin(errs))

    assert lag(_run(None)) <= 1  # 1 ms sensor lag only
    assert 19 <= lag(_run("sensor-delay")) <= 21  # 40 ms at 500 Hz
    # the force channel is not delayed
    d = _run("sensor-delay")
    ok = np.abs(d["force"] - d["true_tension"])
    assert np.sqrt(np.mean(ok**2)) < 1.5


def test_pressure_variation_makes_pressure_follow_x_and_force_the_actual_pressure():
    base = _run(None)
    d = _run("pressure-variation")
    r0 = np.corrcoef(base["muscle_pressure"], base["position"])[0, 1]
    r1 = np.corrcoef(d["muscle_pressure"], d["position"])[0, 1]
    assert abs(r0) < 0.2
    assert r1 < -0.5, r1  # volume grows with contraction: pressure falls as x rises
    # (the slow regulator's refill puts it partly in phase with ẋ, hence not −1)
    swing = np.ptp(d["true_muscle_pressure"])
    assert 0.01 < swing < 0.06, swing
    # force follows the ACTUAL pressure: the truth law with the true pressure history fits,
    # with the nominal pressure it does not
    truth = load_truth(TRUTH_DIR / "hidden-pressure-variation.toml")
    x = np.concatenate([d["true_position"][:1] - 20, d["true_position"]])
    p = np.concatenate([d["true_muscle_pressure"][:1], d["true_muscle_pressure"]])
    sl = slice(len(x) // 4, None)
    actual = baseline_tension(x, p, truth)[1:]
    nominal = baseline_tension(x, np.full_like(x, P0), truth)[1:]
    e_act = np.sqrt(np.mean((d["true_tension"][sl] - actual[sl]) ** 2))
    e_nom = np.sqrt(np.mean((d["true_tension"][sl] - nominal[sl]) ** 2))
    assert e_act < 1.0 and e_nom > 8.0, (e_act, e_nom)


def test_viscous_friction_widens_the_loop_with_speed():
    def widths(eid):
        return [
            hysteresis_width(d["position"], d["force"])
            for d in (
                _run(eid, frequency_Hz=0.1, magnitude_MPa=0.35),
                _run(eid, frequency_Hz=0.3, magnitude_MPa=0.35),
            )
        ]

    w0 = widths(None)
    w1 = widths("viscous-friction")
    assert abs(w0[1] - w0[0]) < 6.0, w0  # the baseline is (nearly) rate independent
    assert w1[1] - w1[0] > 15.0, w1  # 2 N·s/mm: wider at 0.3 Hz
    # and the viscous term is −c·ẋ
    d = _run("viscous-friction", frequency_Hz=0.3)
    v = np.gradient(d["true_position"], d["time"])
    x = np.concatenate([d["true_position"][:1] - 20, d["true_position"]])
    ref = baseline_tension(x, np.full_like(x, P0))[1:]
    sl = slice(len(v) // 4, -5)
    c = np.linalg.lstsq(-v[sl, None], (d["true_tension"] - ref)[sl], rcond=None)[0][0]
    assert c == pytest.approx(2.0, rel=0.05)


def test_asymmetric_hysteresis_is_not_point_symmetric():
    def friction_split(eid):
        d = _run(eid, cycles=1)
        x, f = d["true_position"], d["force"]
        fs = static_force(x, P0)
        dn, up = _branch_masks(x)
        lo, hi = np.percentile(x, [5, 95])
        span = hi - lo

        def band(a, b):
            m = (x > lo + a * span) & (x < lo + b * span)
            return np.mean((f - fs)[dn & m]), np.mean((fs - f)[up & m])

        return band(0.4, 0.6), band(0.15, 0.35), band(0.65, 0.85)

    (s0, r0), (sl0, rl0), (sh0, rh0) = friction_split(None)
    assert s0 / r0 == pytest.approx(1.0, abs=0.1)
    w_lo0, w_hi0 = sl0 + rl0, sh0 + rh0
    (s1, r1), (sl1, rl1), (sh1, rh1) = friction_split("asymmetric-hysteresis")
    # more friction while stretching than while contracting (slip force ×1.3, and the
    # longer pre-sliding keeps the contraction branch from saturating fully)
    assert 1.2 < s1 / r1 < 2.0, s1 / r1
    # the loop is wide where the muscle is stretched (small x), narrow near free contraction
    w_lo1, w_hi1 = sl1 + rl1, sh1 + rh1
    assert w_lo1 / w_hi1 > 1.3 * (w_lo0 / w_hi0), (w_lo1, w_hi1, w_lo0, w_hi0)


def test_nonlinear_stiffness_curves_the_static_characteristic():
    def curvature(eid):
        d = _run(eid, cycles=1)
        x, f = d["true_position"], d["force"]
        dn, up = _branch_masks(x)
        grid = np.linspace(np.percentile(x, 10), np.percentile(x, 90), 25)
        o1, o2 = np.argsort(x[dn]), np.argsort(x[up])
        mean_branch = 0.5 * (
            np.interp(grid, x[dn][o1], f[dn][o1]) + np.interp(grid, x[up][o2], f[up][o2])
        )
        return np.polyfit(grid, mean_branch, 2)[0]  # N/mm²

    c0 = curvature(None)
    c1 = curvature("nonlinear-stiffness")
    assert abs(c0) < 0.05, c0
    # F0(1−s)(1−κs) has second derivative 2κ·F0/x_max² > 0
    assert c1 > 0.3, c1


def test_inertia_load_cell_reads_tension_minus_mass_times_acceleration():
    d = _run("inertia", frequency_Hz=2.0, magnitude_MPa=0.35, cycles=2)
    t = d["time"]
    a = np.gradient(np.gradient(d["true_position"], t), t)  # mm/s²
    sl = slice(100, -100)
    m = np.linalg.lstsq(-1e-3 * a[sl, None], (d["force"] - d["true_tension"])[sl], rcond=None)[0][0]
    assert m == pytest.approx(15.0, rel=0.15), m
    base = _run(None, frequency_Hz=2.0, magnitude_MPa=0.35, cycles=2)
    a0 = np.gradient(np.gradient(base["true_position"], t), t)
    m0 = np.linalg.lstsq(
        -1e-3 * a0[sl, None], (base["force"] - base["true_tension"])[sl], rcond=None
    )[0][0]
    assert abs(m0) < 1.0, m0


def test_sensor_drift_is_a_ramp_in_time():
    # drift touches only the sensors: with the same seed, the difference to the
    # drift-free run is the ramp itself (up to the sensors' quantization)
    d = _run("sensor-drift", cycles=1)
    b = _run(None, cycles=1)
    t = d["time"]
    assert np.array_equal(d["true_position"], b["true_position"])
    assert np.allclose(d["force"] - b["force"], 30.0 / 60.0 * t, atol=0.11)
    assert np.allclose(d["position"] - b["position"], 0.03 / 60.0 * t, atol=0.0011)
    assert np.array_equal(d["muscle_pressure"], b["muscle_pressure"])


@pytest.mark.parametrize("tare_each_run", [False, True])
def test_sensor_drift_carried_over_or_tared_at_each_run(tare_each_run):
    """Two runs on the simulated rig (each starts with a muscle-supply request): a drifting
    zero carried over from switch-on, or tared at each run's start so it grows from 0."""
    from pmalab.rig.base import VirtualClock
    from pmalab.rig.sim import make_sim_rig

    drift = {"enabled": True, "force_N_per_min": 60.0, "position_mm_per_min": 0.06,
             "tare_each_run": tare_each_run}
    truth = default_truth().with_changes(**{"effects.sensor_drift": drift})
    rigs = [make_sim_rig(t, seed=4, clock=VirtualClock()) for t in (truth, default_truth())]
    diffs = {"force": [], "position": []}
    starts = []
    for p in (0.3, 0.45):  # run 1 from t = 0, run 2 after 20 s
        for rig in rigs:
            rig.clock.sleep_until(20.0 if p == 0.45 else 0.0)
            rig.muscle_supply.request(p)
        starts.append(rigs[0].clock.now())
        for k in range(2500):  # 5 s at 500 Hz
            blocks = []
            for rig in rigs:
                rig.clock.sleep_until(starts[-1] + k / 500.0)
                blocks.append(rig.sampler.read_block())
            for ch in diffs:
                diffs[ch].append(float(getattr(blocks[0], ch)[0] - getattr(blocks[1], ch)[0]))
    t = np.r_[starts[0] + np.arange(2500) / 500.0, starts[1] + np.arange(2500) / 500.0]
    origin = np.r_[np.full(2500, starts[0]), np.full(2500, starts[1] if tare_each_run else 0.0)]
    # the same seed, physics untouched: the difference is the drift itself (± quantisation)
    np.testing.assert_allclose(diffs["force"], 1.0 * (t - origin), atol=0.11)
    np.testing.assert_allclose(diffs["position"], 0.001 * (t - origin), atol=0.0011)
    second_start = diffs["force"][2500]
    assert (abs(second_start) < 0.2) if tare_each_run else (second_start > 19.0)


def test_every_effect_off_by_default():
    t = default_truth()
    assert t.enabled_effects() == []
    for sec in t.effects.values():
        assert sec["enabled"] is False


def _record_breakaway(tmp_path, enabled: bool) -> np.ndarray:
    """Force of one 2 Hz run (the rate at which the turning points chatter) with the
    break-away look-alike on or off, same sensor seed; the run file is read back through
    the channel-health check."""
    from pmalab.cli import main as pmalab_main
    from pmalab.runfile import read_runs

    src = (TRUTH_DIR / "lookalike" / "breakaway.toml").read_text()
    truth = tmp_path / f"truth-{enabled}.toml"
    truth.write_text(src if enabled else src.replace("enabled = true", "enabled = false"))
    rig = tmp_path / f"rig-{enabled}.toml"
    rig.write_text(f'[rig]\nkind = "sim"\ntruth = "{truth}"\nseed = 300\n')
    proto = tmp_path / "p.toml"
    # the 0.3 MPa pair of the diagnosis-test campaign: its 2 Hz run's turning points chatter
    runs = "".join(
        f'[[run]]\nname = "p300kPa-{f}Hz"\nrole = "identification"\nmuscle_pressure_MPa = 0.3\n'
        f'waveform = "sine"\nfrequency_Hz = {f}\namplitude_MPa = 0.12\noffset_MPa = 0.19\n'
        "cycles = 2\nramp_s = 0.5\nsettle_s = 0.3\npreload_MPa = 0.03\n" for f in (0.5, 2.0))
    proto.write_text(f'[protocol]\nname = "brk"\n{runs}')
    out = tmp_path / f"brk-{enabled}.h5"
    assert pmalab_main(["run", "--rig", str(rig), "--protocol", str(proto), "--out", str(out),
                        "-q"]) == 0
    runs = read_runs(out)  # refuses a one-sample spike as damaged data
    return np.asarray(runs[-1].force, float)


def test_breakaway_spikes_once_per_reversal_with_alternating_sign(tmp_path):
    """Stick-slip chatter at a turning point is one break-away, not a spike that flips sign
    from one sample to the next (the health check would rightly refuse that as damage)."""
    d = _record_breakaway(tmp_path, True) - _record_breakaway(tmp_path, False)
    spike = float(load_truth(TRUTH_DIR / "lookalike" / "breakaway.toml").effect("breakaway")["spike_N"])
    big = np.abs(d) > 0.4 * spike
    onsets = np.flatnonzero(big[1:] & ~big[:-1]) + 1
    signs = np.sign(d[onsets])
    # 2 cycles: two reversals per cycle (+ the ramp's and the settling's turning points),
    # each a quarter-period (≈ 125 samples at 2 Hz) from the next, never a sample apart
    assert 4 <= len(onsets) <= 8, onsets
    assert np.min(np.diff(onsets)) > 50, onsets
    assert np.all(signs[1:] == -signs[:-1]), signs
    assert np.max(np.abs(d)) == pytest.approx(spike, rel=0.05)
