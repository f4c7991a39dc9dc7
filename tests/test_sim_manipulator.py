"""The simulated 1-DOF manipulator: home, static balance, regulator dead time and lag,
the volume's pressure dip, the rig interface."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pmalab.errors import RigError
from pmalab.rig.base import VentOutcome
from pmalab.rig.sim.manipulator import ManipulatorPhysics, ManipulatorSpec, make_sim_manipulator


def _hold(ph: ManipulatorPhysics, seconds: float, dt: float = 0.002) -> np.ndarray:
    """Advance ``seconds`` sampling every ``dt``; rows (t, position, force, p)."""
    out = []
    t0 = ph.time
    for k in range(1, int(round(seconds / dt)) + 1):
        out.append(ph.advance_and_sample(t0 + k * dt)[:4].copy())
    return np.array(out)


def test_home_is_where_the_spring_stretches_the_vented_muscle():
    ph = ManipulatorPhysics()
    s = ph.spec
    k_stretch = ph.truth.section("muscle")["stretch_stiffness_N_per_mm"]
    assert ph.home_contraction_mm == pytest.approx(-s.spring_preload_N / (k_stretch + s.spring_N_per_mm))
    rows = _hold(ph, 1.0)
    assert abs(rows[:, 1].mean()) < 0.01  # position is measured from home (noise 0.015 mm)


@pytest.mark.parametrize("p", [0.2, 0.3, 0.45])
def test_held_pressure_settles_where_muscle_tension_balances_the_spring(p):
    """At rest the truth's tension equals the spring force (bearing friction ≤ 2 N), and the
    static law alone is within the braid's friction band of it."""
    ph = ManipulatorPhysics()
    ph.set_command(p)
    _hold(ph, 4.0)
    st = ph.truth_state()
    assert abs(st["velocity"]) < 0.05
    spring = ph.spec.spring_preload_N + ph.spec.spring_N_per_mm * st["contraction"]
    assert st["tension"] == pytest.approx(spring, abs=ph.spec.bearing_coulomb_N + 0.5)
    # the braid's friction holds the rest of the balance: at most its slip force at p
    m, fr = ph.truth.section("muscle"), ph.truth.section("friction")
    q = (st["muscle_pressure"] - m["threshold_pressure_MPa"]) / (
        m["reference_pressure_MPa"] - m["threshold_pressure_MPa"])
    g = fr["pressure_curvature"]
    slip = fr["slip_force_N"] * ((1 - g) * q + g * q * q)
    static = ph.static_force(st["contraction"], st["muscle_pressure"])
    assert abs(static - spring) <= slip + 1.0
    assert st["muscle_pressure"] == pytest.approx(p, abs=0.002)  # 10-bit command quantum
    # higher pressure, more contraction (10–25 mm over this range)
    assert 5.0 < st["position"] < 25.0


def test_regulator_dead_time_lag_and_quantisation():
    ph = ManipulatorPhysics()
    dead = ph.truth.section("regulator")["dead_time_ms"] * 1e-3
    ph.set_command(0.3)
    rows = _hold(ph, 1.0, dt=0.001)
    t, p = rows[:, 0], rows[:, 3]
    before = p[t < dead - 0.002]
    assert np.all(np.abs(before) < 0.004)  # nothing moves inside the dead time (gauge noise)
    assert p[-1] == pytest.approx(0.3, abs=0.003)
    t63 = t[np.argmax(p > 0.63 * 0.3)]
    # regulator lag 70 ms + line filling ≈ 0.12 s·V/V0: the 63 % point in 0.1–0.4 s
    assert 0.1 < t63 - dead < 0.4
    levels = 2 ** ph.truth.section("regulator")["bits"] - 1
    ph.set_command(0.3 + 0.2 * 0.9 / levels)  # a fifth of a quantum: the same setpoint
    _hold(ph, 0.5)
    assert ph.truth_state()["regulator_pressure"] == pytest.approx(
        round(0.3 * levels / 0.9) * 0.9 / levels, abs=1e-6)


def test_a_contracting_muscle_loses_pressure_through_its_volume():
    """The same step with and without volume growth: the growing volume dips the pressure
    while the muscle contracts (isothermal p·V)."""
    dips = []
    for dv in (0.0, 2.0):
        ph = ManipulatorPhysics(spec=replace(ManipulatorSpec(), dvolume_cm3_per_mm=dv))
        ph.set_command(0.35)
        rows = _hold(ph, 0.6)
        dips.append(rows[:, 3][-1])
    assert dips[1] < dips[0] - 0.005


def test_rig_interface_vents_and_refuses_bad_commands():
    rig = make_sim_manipulator()
    rig.muscle_regulator.set_pressure(0.4)
    with pytest.raises(RigError, match=r"outside 0–0\.6 MPa"):
        rig.muscle_regulator.set_pressure(0.7)
    with pytest.raises(RigError):
        rig.muscle_regulator.set_pressure(float("nan"))
    res = rig.close()
    assert res.outcome is VentOutcome.CONFIRMED
    assert rig.info["physics"].command == 0.0


def test_implausible_manipulator_spec_is_refused():
    with pytest.raises(RigError, match="inertia_kg_m2: must be > 0"):
        ManipulatorPhysics(spec=replace(ManipulatorSpec(), inertia_kg_m2=0.0))
    with pytest.raises(RigError, match="stop_min_mm: must be < stop_max_mm"):
        ManipulatorPhysics(spec=replace(ManipulatorSpec(), stop_min_mm=30.0))
