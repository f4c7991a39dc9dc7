"""The simulated rig through the pmalab.rig.base interface."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pmalab.errors import RigError
from pmalab.rig.base import Block, RealClock, Rig, VentOutcome, VirtualClock
from pmalab.rig.sim import RigPhysics, make_sim_rig


def _run_loop(rig: Rig, seconds: float, p_muscle: float = 0.4762, m: float = 0.35, f: float = 0.15):
    rig.muscle_supply.request(p_muscle)
    rig.clock.sleep_until(rig.clock.now() + 2.0)
    t0 = rig.clock.now()
    blocks = []
    n = round(seconds * 500)
    for i in range(n):
        rig.clock.sleep_until(t0 + i / 500)
        blocks.append(rig.sampler.read_block())
        t = rig.clock.now() - t0
        rig.cylinder_regulator.set_pressure(0.5 * m * (1 - math.cos(2 * math.pi * f * t)))
    return blocks


def test_virtual_rig_samples_stamped_at_clock_time():
    rig = make_sim_rig(seed=3)
    assert isinstance(rig.clock, VirtualClock)
    assert rig.sampler.hardware_timed is False and rig.sampler.sample_rate_Hz == 500.0
    assert rig.muscle_supply.automatic
    blocks = _run_loop(rig, 4.0)
    assert all(isinstance(b, Block) and len(b) == 1 for b in blocks)
    t = np.concatenate([b.time for b in blocks])
    assert np.allclose(np.diff(t), 0.002)
    assert t[0] == pytest.approx(2.0)
    x = np.concatenate([b.position for b in blocks])
    assert x[0] > 20 and x[-1] < x[0] - 5  # the cylinder stretches the muscle
    rig.close()
    rig.close()  # safe twice


def test_rig_and_direct_physics_agree_bit_for_bit():
    rig = make_sim_rig(seed=4)
    b = _run_loop(rig, 1.0)
    f_rig = np.concatenate([x.force for x in b])
    ph = RigPhysics(seed=4)
    ph.set_muscle_supply(0.4762)
    out = []
    for i in range(500):
        t = 2.0 + i / 500
        out.append(ph.advance_and_sample(t)[2])
        ph.set_cylinder_command(0.5 * 0.35 * (1 - math.cos(2 * math.pi * 0.15 * (t - 2.0))))
    assert np.array_equal(f_rig, np.array(out))


def test_manual_muscle_regulator_prompts_the_operator():
    seen = []
    rig = make_sim_rig(manual_muscle_regulator=True, prompt=seen.append)
    assert rig.muscle_supply.automatic is False
    rig.muscle_supply.request(0.3)
    assert seen and "0.3 MPa" in seen[0]
    other = []
    rig.muscle_supply.request(0.31, prompt=other.append)
    assert other and "0.31" in other[0]
    rig.clock.sleep_until(3.0)
    assert rig.sampler.read_block().muscle_pressure[0] == pytest.approx(0.31, abs=0.005)
    assert rig.muscle_supply.vent().outcome is VentOutcome.MANUAL  # left alone, and said so
    rig.clock.sleep_until(6.0)
    assert rig.sampler.read_block().muscle_pressure[0] == pytest.approx(0.31, abs=0.005)


def test_vent_never_raises_and_vents():
    rig = make_sim_rig()
    rig.muscle_supply.request(0.5)
    rig.cylinder_regulator.set_pressure(0.4)
    rig.clock.sleep_until(3.0)
    rig.close()
    assert rig.last_vent is not None and rig.last_vent.ok
    assert rig.last_vent.cylinder.ok and rig.last_vent.muscle.ok
    rig.clock.sleep_until(6.0)
    b = rig.sampler.read_block()
    assert b.cylinder_pressure[0] < 0.005 and b.muscle_pressure[0] < 0.005


def test_out_of_range_setpoint_is_rig_error():
    rig = make_sim_rig()
    with pytest.raises(RigError):
        rig.cylinder_regulator.set_pressure(0.95)
    with pytest.raises(RigError):
        rig.muscle_supply.request(0.7)


def test_real_clock_runs_in_real_time():
    clock = RealClock()
    rig = make_sim_rig(clock=clock)
    t0 = clock.now()
    stamps, woke = [], []
    for i in range(1, 101):  # 0.2 s at 500 Hz
        clock.sleep_until(t0 + i * 0.002)
        woke.append(clock.now())
        stamps.append(rig.sampler.read_block().time[0])
    stamps = np.array(stamps)
    assert np.all(np.diff(stamps) > 0)
    # never woken before a deadline; the last sample stamped with the real time it was read
    # at: 0.2 s, plus how late the loop woke for it (on an idle machine ~0; a busy one wakes
    # a process late, and the stamp must follow the clock, not the deadline)
    deadlines = t0 + 0.002 * np.arange(1, 101)
    assert np.all(np.array(woke) >= deadlines)
    assert stamps[-1] - t0 == pytest.approx(0.2 + (woke[-1] - deadlines[-1]), abs=0.02)
    assert abs(rig.info["physics"].time - clock.now()) < 0.05


def test_explicit_seed_overrides_the_rig_files_seed(tmp_path):
    from pmalab.paths import TRUTH_DIR
    from pmalab.rig.loader import load_rig

    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(f'[rig]\nkind = "sim"\ntruth = "{TRUTH_DIR / "default.toml"}"\nseed = 5\n')
    assert load_rig(rig_file).info["seed"] == 5  # the file's seed by default
    assert load_rig(rig_file, seed=9).info["seed"] == 9  # pmalab run --seed 9 wins
    assert load_rig("sim").info["seed"] == 0
