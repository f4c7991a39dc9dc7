"""The effect catalogue: registry, user effects, and each effect's force term and physics."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from pmalab.errors import PmalabError
from pmalab.identify.effects import BUILTIN_IDS, EFFECTS, Effect, get_effect, load_user_effects
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals

DESIGN_IDS = ("viscous-friction", "asymmetric-hysteresis", "nonlinear-stiffness",
              "pressure-variation", "sensor-delay", "inertia", "sensor-drift")


def _sig(f: float = 0.5, n_cycles: float = 3, fs: float = 500.0) -> Signals:
    t = np.arange(0, n_cycles / f, 1 / fs)
    x = 10.0 + 8.0 * np.sin(2 * np.pi * f * t)
    p = 0.4 + 0.01 * np.cos(2 * np.pi * f * t)
    return Signals.from_arrays(t, x, p, p_nom=0.4, frequency_Hz=f)


def _theta(model: ForceModel, sig: Signals, **kw: float) -> dict[str, float]:
    th = model.params(sig).values()
    th.update({"k": -40.0, "c0": 900.0, "A": -20.0, "beta": 0.8, "gamma": 0.3, "h0": 0.0})
    th.update(kw)
    return th


def test_catalogue_has_the_design_ids_with_docs() -> None:
    assert set(DESIGN_IDS) <= set(EFFECTS)
    for eid in DESIGN_IDS:
        e = get_effect(eid)
        assert e.id == eid and e.title and e.explanation and e.signature and e.experiment
        ps = e.params(_sig(), 200.0)
        assert ps, eid
        for p in ps:
            assert p.lo < p.value < p.hi or p.lo <= p.value <= p.hi, (eid, p)
            assert p.unit, (eid, p.name)


def test_unknown_effect_lists_valid_ids() -> None:
    with pytest.raises(PmalabError, match=r"unknown effect 'magic'.*viscous-friction"):
        get_effect("magic")


@pytest.mark.parametrize("eid", DESIGN_IDS)
def test_neutral_parameters_leave_the_base_force_unchanged(eid: str) -> None:
    sig = _sig()
    base = ForceModel("bouc-wen")
    with_e = ForceModel("bouc-wen", [get_effect(eid)])
    th = _theta(with_e, sig)
    np.testing.assert_allclose(with_e.predict(sig, th), base.predict(sig, th), atol=1e-9)


def test_viscous_friction_raises_tension_while_stretching() -> None:
    sig = _sig()
    m = ForceModel("bouc-wen", [get_effect("viscous-friction")])
    c = m.components(sig, _theta(m, sig, visc_c=2.0))["viscous-friction"]
    assert np.all(c[sig.v < -1.0] > 0) and np.all(c[sig.v > 1.0] < 0)
    np.testing.assert_allclose(c, -2.0 * sig.v)


def test_sensor_delay_shifts_position_in_time() -> None:
    sig = _sig()
    m = ForceModel("bouc-wen", [get_effect("sensor-delay")])
    s2 = get_effect("sensor-delay").transform(sig, {"delay_tau": 0.02})
    i = 1000
    assert s2.x[i] == pytest.approx(np.interp(sig.t[i] + 0.02, sig.t, sig.x), rel=1e-12)
    # a delayed prediction equals the undelayed one evaluated 20 ms later
    th = _theta(m, sig, delay_tau=0.02)
    f = m.predict(sig, th)
    f0 = ForceModel("bouc-wen").predict(sig, th)
    assert np.interp(sig.t[i] + 0.02, sig.t, f0) == pytest.approx(f[i], abs=0.5)


def test_inertia_is_minus_mass_times_acceleration() -> None:
    sig = _sig(f=2.0)
    m = ForceModel("bouc-wen", [get_effect("inertia")])
    c = m.components(sig, _theta(m, sig, inertia_m=10.0))["inertia"]
    # noise-free sine: the smoothed acceleration is the true −ω²·(x − x̄) away from the ends
    mid = slice(200, -200)
    true_a = -(2 * np.pi * 2.0) ** 2 * (sig.x - 10.0)
    np.testing.assert_allclose(c[mid], -10.0 * true_a[mid] * 1e-3, rtol=0.02, atol=0.3)
    assert np.max(np.abs(c)) > 10.0  # 10 kg at 2 Hz, 8 mm: ≈ 13 N


def test_pressure_variation_uses_measured_pressure() -> None:
    sig = _sig()
    m = ForceModel("bouc-wen", [get_effect("pressure-variation")])
    c = m.components(sig, _theta(m, sig, pv_g0=2000.0))["pressure-variation"]
    np.testing.assert_allclose(c, 2000.0 * (sig.p - 0.4), atol=1e-9)


def test_drift_and_stiffness_shapes() -> None:
    sig = _sig()
    m = ForceModel("bouc-wen", [get_effect("sensor-drift"), get_effect("nonlinear-stiffness")])
    comp = m.components(sig, _theta(m, sig, drift_d=0.5, stiff_k2=1.0))
    d = comp["sensor-drift"]
    assert d[-1] - d[0] == pytest.approx(0.5 * (sig.t[-1] - sig.t[0]))
    s = comp["nonlinear-stiffness"]
    np.testing.assert_allclose(s, sig.x**2)


@pytest.mark.parametrize("law", ["bouc-wen", "duhem"])
def test_asymmetric_hysteresis_changes_branches_differently(law: str) -> None:
    sig = _sig()
    e = get_effect("asymmetric-hysteresis")
    m = ForceModel(law, [e])
    th = m.params(sig).values()
    th.update({"k": -40.0, "c0": 900.0, "h0": 0.0})
    th.update({"A": -20.0, "beta": 0.8, "gamma": 0.3} if law == "bouc-wen"
              else {"alpha": 0.5, "a": 0.0, "b": -20.0})
    sym = m.predict(sig, th)
    if law == "bouc-wen":
        th.update(asym_psi_a=0.4, asym_psi_v=0.3, asym_psi_h=0.2)
    else:
        th.update(asym_psi_v=0.8, asym_psi_h=0.8)
    asym = m.predict(sig, th)
    diff = asym - sym
    up, down = sig.v > 1, sig.v < -1
    assert abs(np.mean(diff[up]) - np.mean(diff[down])) > 0.5
    assert ("asym_psi_a" in e.fixed_for_law("duhem")) and not e.fixed_for_law("bouc-wen")


def test_user_effect_file_registers_and_broken_file_is_one_line(tmp_path: Path) -> None:
    good = tmp_path / "my_effects.py"
    good.write_text(textwrap.dedent('''
        import numpy as np
        from pmalab.identify.effects.base import Effect
        from pmalab.identify.params import Param

        class Cubic(Effect):
            id = "test-cubic-velocity"
            title = "cubic damping"
            explanation = "force grows with the cube of velocity"
            signature = "residual ~ v^3"

            def params(self, sig, force_scale):
                return [Param("cub_c", 0.0, -1.0, 1.0, "N·s³/mm³")]

            def force(self, sig, h, theta):
                return -theta["cub_c"] * sig.v ** 3
    '''))
    ids = load_user_effects(good)
    assert ids == ["test-cubic-velocity"]
    e = get_effect("test-cubic-velocity")
    assert isinstance(e, Effect) and "test-cubic-velocity" not in BUILTIN_IDS
    sig = _sig()
    m = ForceModel("bouc-wen", [e])
    assert m.components(sig, _theta(m, sig, cub_c=0.01))["test-cubic-velocity"].shape == sig.t.shape
    EFFECTS.pop("test-cubic-velocity")

    broken = tmp_path / "broken.py"
    broken.write_text("from pmalab.identify.effects.base import Effect\nclass X(Effect:\n")
    with pytest.raises(PmalabError, match=r"broken.py: could not load effects \(line 2\)"):
        load_user_effects(broken)
    with pytest.raises(PmalabError, match="no such effects file"):
        load_user_effects(tmp_path / "missing.py")
    empty = tmp_path / "empty.py"
    empty.write_text("x = 1\n")
    with pytest.raises(PmalabError, match="defines no Effect subclass"):
        load_user_effects(empty)


@pytest.mark.parametrize("eid", [e for e in DESIGN_IDS if EFFECTS[e].absent])
def test_absent_values_remove_the_effect(eid: str) -> None:
    # diagnosis removes an effect from an identified model with its absent values (the
    # significance rule's "the fall must be the effect's own"): they must cover every
    # parameter of the effect and give the base law's force, whatever the effect's fit was
    sig = _sig(f=2.0)
    e = get_effect(eid)
    absent = type(e).absent or {}
    assert set(absent) == {p.name for p in e.params(sig, 200.0)}
    base = ForceModel("bouc-wen")
    with_e = ForceModel("bouc-wen", [e])
    fitted = _theta(with_e, sig, **{p.name: p.lo + 0.3 * (p.hi - p.lo) for p in e.params(sig, 200.0)})
    assert not np.allclose(with_e.predict(sig, fitted), base.predict(sig, fitted), atol=1e-6)
    removed = {**fitted, **absent}
    np.testing.assert_allclose(with_e.predict(sig, removed), base.predict(sig, removed), atol=1e-9)


@pytest.mark.parametrize("law", ["bouc-wen", "duhem", "maxwell-slip", "prandtl-ishlinskii"])
@pytest.mark.parametrize("eid", DESIGN_IDS)
def test_parameters_held_for_a_law_are_exactly_those_it_ignores(law: str, eid: str) -> None:
    # an effect parameter the law does not accept (an asymmetric shape term under an element
    # law) is held, not estimated; every parameter the law does use stays free
    sig = _sig(f=2.0)
    e = get_effect(eid)
    model = ForceModel(law, [e])
    held = set(e.fixed_for_law(law))
    start = _theta(model, sig)
    force = model.predict(sig, start)
    for p in e.params(sig, 200.0):
        moved = {**start, p.name: p.lo + 0.3 * (p.hi - p.lo)}
        changes = not np.allclose(model.predict(sig, moved), force, rtol=0.0, atol=1e-9)
        assert changes != (p.name in held), (law, p.name, sorted(held))
