"""Conformance of every registry: laws, effects, controllers, rig kinds.

One mechanism registers them all (``pmalab.registry.Registry``: each item declares its own
id, title and order where it is defined).  These tests iterate each registry, so a new law,
effect, controller or rig kind is tested the moment its file exists — shown here by
registering a throwaway one of each and running the same checks on it.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmalab.cli import main as pmalab_main
from pmalab.control.controllers import TITLES
from pmalab.control.pid import CONTROLLERS, IncrementalPID
from pmalab.errors import ConfigError, PmalabError
from pmalab.identify.effects import EFFECTS, Effect, get_effect
from pmalab.identify.laws import LAWS, get_law
from pmalab.identify.laws.duhem import Duhem
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals
from pmalab.registry import Registry
from pmalab.rig.loader import RIG_KINDS, load_rig
from pmalab.runfile import Run


def _cli(args) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, err.getvalue()


# ------------------------------------------------------------------ the registry itself
def test_registry_keeps_declared_order_refuses_clashes_and_names_valid_ids():
    r: Registry[int] = Registry("widget")
    r.register("b", 2, order=2)
    r.register("a", 1, order=1)
    r.register("c", 3)  # default order: after the declared ones
    assert list(r) == ["a", "b", "c"] and r["b"] == 2 and "c" in r and len(r) == 3
    with pytest.raises(PmalabError, match="widget 'a' is already registered"):
        r.register("a", 9)
    r.register("a", 9, replace=True, order=1)
    with pytest.raises(PmalabError, match=r"unknown widget 'z' \(choose from a, b, c\)"):
        r.lookup("z")


# ------------------------------------------------------------------ laws
def law_conforms(name: str) -> None:
    """What every law must satisfy (the engine, the controllers and diagnose rely on it)."""
    law = get_law(name)
    assert LAWS.title(name)
    names = {p.name for p in law.params}
    assert "h0" in names and set(law.default_fixed) <= names
    for p in law.params:
        assert p.lo <= p.init <= p.hi, p
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(0, 0.2, 400)) + 5.0
    theta = {p.name: p.init for p in law.params}
    h = law.h(x, theta)
    assert h.shape == x.shape and np.all(np.isfinite(h))
    state = law.initial_state(theta, theta["h0"], 1.0 if x[1] > x[0] else -1.0)
    step = law.stepper(theta)
    out = [law.output(state)]
    for k in range(1, len(x)):
        state = step(state, x[k - 1], x[k])
        out.append(law.output(state))
    np.testing.assert_allclose(out, h, atol=1e-9 * max(1.0, np.max(np.abs(h))))
    g = law.guess(x, -20 * x + 300 + h, np.gradient(x))
    assert all(np.isfinite(v) for v in g.values())


@pytest.mark.parametrize("name", list(LAWS))
def test_every_law_conforms(name):
    law_conforms(name)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.sampled_from(sorted(LAWS)),
       st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=2, max_size=120))
def test_step_equals_batch_on_random_paths(name, steps):
    """Property: the controllers' one-sample step and identify's batch h are one integrator."""
    law = get_law(name)
    x = 5.0 + np.cumsum(steps)
    theta = {p.name: p.init for p in law.params}
    h = law.h(x, theta)
    moved = np.flatnonzero(np.abs(x - x[0]) > 0)
    direction = 1.0 if moved.size == 0 or x[moved[0]] > x[0] else -1.0
    state = law.initial_state(theta, theta["h0"], direction)
    step = law.stepper(theta)
    out = [law.output(state)]
    for k in range(1, len(x)):
        state = step(state, x[k - 1], x[k])
        out.append(law.output(state))
    np.testing.assert_allclose(out, h, atol=1e-8 * max(1.0, float(np.max(np.abs(h)))))


def test_a_new_law_file_is_registered_and_checked_at_once():
    class ThrowawayLaw(Duhem):  # what a new file in pmalab/identify/laws/ would define
        name = "test-throwaway-law"
        title = "a throwaway law for the conformance test"
        order = 99

    try:
        assert "test-throwaway-law" in LAWS and list(LAWS)[-1] == "test-throwaway-law"
        law_conforms("test-throwaway-law")
    finally:
        LAWS.unregister("test-throwaway-law")
    assert "test-throwaway-law" not in LAWS


# ------------------------------------------------------------------ effects
def _signals() -> Signals:
    t = np.arange(0, 4, 0.002)
    x = 10 + 5 * np.sin(2 * np.pi * t)
    run = Run(name="r", time=t, position=x, force=400 - 8 * x, muscle_pressure=np.full(t.size, 0.4),
              attrs={"muscle_pressure_MPa": 0.4, "frequency_Hz": 1.0})
    return Signals.from_run(run)


def effect_conforms(effect_id: str) -> None:
    e = get_effect(effect_id)
    assert e.id == effect_id and EFFECTS.title(effect_id) and e.title
    sig = _signals()
    params = e.params(sig, 50.0)
    assert len({p.name for p in params}) == len(params)
    for p in params:
        assert isinstance(p, Param) and p.lo <= p.value <= p.hi, p
    theta = {p.name: p.value for p in params}
    s2 = e.transform(sig, theta)
    f = np.asarray(e.force(s2, np.zeros(len(sig.x)), theta), dtype=float)
    assert np.all(np.isfinite(f))
    for law in LAWS:
        assert set(e.fixed_for_law(law)) <= {p.name for p in params}


@pytest.mark.parametrize("effect_id", list(EFFECTS))
def test_every_effect_conforms(effect_id):
    effect_conforms(effect_id)
    cls = EFFECTS[effect_id]
    assert cls.explanation and cls.signature  # what the report tells the user


def test_a_new_effect_is_registered_and_checked_at_once():
    class Throwaway(Effect):
        id = "test-throwaway-effect"
        title = "a throwaway effect"

        def params(self, sig, force_scale):
            return [Param("tw_c", 0.0, -1.0, 1.0, "N·s/mm")]

        def force(self, sig, h, theta):
            return theta["tw_c"] * sig.v

    EFFECTS.register(Throwaway.id, Throwaway, title=Throwaway.title, order=99)
    try:
        effect_conforms("test-throwaway-effect")
    finally:
        EFFECTS.unregister("test-throwaway-effect")


# ------------------------------------------------------------------ controllers
def controller_conforms(name: str, tmp: Path) -> None:
    assert CONTROLLERS.title(name) and TITLES.get(name, CONTROLLERS.title(name))
    out = tmp / f"{name}.h5"
    code, err = _cli(["control", "--controller", name, "--reference", "square:0.5Hz:10mm",
                      "--duration", "1", "--out", out])
    assert code == 0, err
    assert out.exists()


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_every_controller_runs_the_manipulator(name, tmp_path):
    controller_conforms(name, tmp_path)


def test_a_new_controller_is_registered_and_runs_at_once(tmp_path):
    class Throwaway(IncrementalPID):
        name = "test-throwaway-pid"
        title = "a throwaway controller"
        order = 99

    try:
        assert "test-throwaway-pid" in CONTROLLERS
        controller_conforms("test-throwaway-pid", tmp_path)  # the verb runs it by its id
    finally:
        CONTROLLERS.unregister("test-throwaway-pid")


# ------------------------------------------------------------------ rig kinds
@pytest.mark.parametrize("kind", list(RIG_KINDS))
def test_every_rig_kind_refuses_an_unknown_key_in_one_line(kind, tmp_path):
    f = tmp_path / "rig.toml"
    f.write_text(f'[rig]\nkind = "{kind}"\nbogus_key = 1\n')
    with pytest.raises(ConfigError) as e:
        load_rig(f)
    msg = str(e.value)
    assert "\n" not in msg and str(f) in msg
    assert RIG_KINDS.title(kind)


def test_a_new_rig_kind_is_one_registration(tmp_path):
    seen = {}

    def factory(section, rig_file, *, seed=None, clock=None):
        seen.update(section)
        return RIG_KINDS["sim"]({}, None, seed=seed, clock=clock)

    RIG_KINDS["test-kind"] = factory
    try:
        f = tmp_path / "rig.toml"
        f.write_text('[rig]\nkind = "test-kind"\nspeed = 3\n')
        rig = load_rig(f)
        assert seen == {"speed": 3} and rig.info["rig_file"] == str(f)
    finally:
        RIG_KINDS.unregister("test-kind")


def test_an_unknown_controller_is_one_line_and_leaves_nothing(tmp_path):
    out = tmp_path / "x.h5"
    code, err = _cli(["control", "--controller", "nope", "--reference", "square:0.5Hz:10mm",
                      "--duration", "1", "--out", out])
    assert code == 2 and "unknown 'nope' (choose from pid, sn-pid, rbf-pid)" in err
    assert not out.exists()
