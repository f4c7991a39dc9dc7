"""The hysteresis laws: one integrator, run as a whole trajectory or sample by sample."""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.errors import PmalabError
from pmalab.identify.laws import LAWS, HysteresisLaw, get_law


def _path(n: int = 3000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 6.0, n)
    # a sine with minor loops and a little noise: reversals of every size
    return 8.0 + 6.0 * np.sin(2 * np.pi * 0.5 * t) + 0.8 * np.sin(2 * np.pi * 3.1 * t) \
        + 0.01 * rng.standard_normal(n)


THETAS = {
    "bouc-wen": [{"A": -60.0, "beta": 0.4, "gamma": 0.1, "n": 1.0, "h0": 5.0},
                 {"A": -60.0, "beta": 0.05, "gamma": 0.02, "n": 1.7, "h0": -3.0}],
    "duhem": [{"alpha": 0.5, "a": 2.0, "b": -40.0, "h0": 1.0}],
    "prandtl-ishlinskii": [{**{f"w{i}": 1.5 * i for i in range(1, 16)}, "h0": 4.0},
                           {**{f"w{i}": 0.0 for i in range(1, 16)}, "w5": 25.0, "h0": -2.0}],
    "maxwell-slip": [{"k1": 40.0, "k2": 10.0, "k3": 5.0, "k4": 2.0, "d1": 0.2, "d2": 0.8,
                      "d3": 2.0, "d4": 6.0, "h0": 3.0}],
}


def _thetas(name: str) -> list[dict]:
    """The cases above; a law registered without any (a new file) is run at its defaults."""
    law = get_law(name)
    return THETAS.get(name) or [{p.name: p.init for p in law.params}]


@pytest.mark.parametrize("name", sorted(LAWS))
def test_step_reproduces_the_batch_trajectory(name: str) -> None:
    law = get_law(name)
    x = _path()
    for theta in _thetas(name):
        h_batch = law.h(x, theta)
        direction = 1.0 if x[np.argmax(np.abs(x - x[0]) > 1e-3 * np.ptp(x))] > x[0] else -1.0
        state = law.initial_state(theta, theta["h0"], direction)
        out = [law.output(state)]
        step = law.stepper(theta)
        for k in range(1, x.shape[0]):
            state = step(state, x[k - 1], x[k])
            out.append(law.output(state))
        np.testing.assert_allclose(out, h_batch, rtol=0, atol=1e-9 * np.max(np.abs(h_batch)))
        if law.state_size == 1:  # the convenience form agrees too (h is the whole state)
            assert law.step(h_batch[10], x[10], x[11], theta) == pytest.approx(h_batch[11],
                                                                               abs=1e-9)


@pytest.mark.parametrize("name", sorted(LAWS))
def test_every_law_declares_its_contract(name: str) -> None:
    law = get_law(name)
    assert isinstance(law, HysteresisLaw)
    names = {p.name for p in law.params}
    assert set(law.default_fixed) <= names and set(law.default_fixed_why) == set(law.default_fixed)
    assert {n for n, _ in law.collinear_fixes} <= names
    assert set(law.state_params) <= names
    assert law.scale_param is None or law.scale_param in names
    assert law.state_size >= 1
    for p in law.params:
        assert p.lo <= p.init <= p.hi, p


@pytest.mark.parametrize("name", sorted(LAWS))
def test_guess_sizes_the_loop_from_data(name: str) -> None:
    """A start, not a fit: the guessed loop has the measured loop's sign and size within ×3.

    Size = the loop's width (mean tension while stretching minus while releasing), which a
    stiffness the guess moves between k and h (the element laws' plays carry one) leaves
    alone."""
    law = get_law(name)
    x = _path(seed=1)
    theta = dict(_thetas(name)[0], h0=0.0)
    h = law.h(x, theta)
    force = -30.0 * x + 800.0 + h
    v = np.gradient(x)
    g = law.guess(x, force, v)
    h_g = law.h(x, {**theta, **g, "h0": 0.0})

    def width(hh: np.ndarray) -> float:
        hs, vs = hh[500:], v[500:]
        return float(np.mean(hs[vs < 0]) - np.mean(hs[vs > 0]))

    ratio = width(h_g) / width(h)
    assert 1 / 3 < ratio < 3
    if law.scale_param is not None:
        assert np.sign(g[law.scale_param]) == np.sign(theta[law.scale_param])
    # the guessed loop runs the physical way: higher tension while stretching (v < 0)
    assert np.mean(h_g[500:][v[500:] < 0]) > np.mean(h_g[500:][v[500:] > 0])


def test_scale_linearity_holds_where_the_law_says() -> None:
    law = get_law("bouc-wen")
    x = _path(seed=2)
    th = {"A": 1.0, "beta": 0.3, "gamma": 0.05, "n": 1.0, "h0": 0.0}
    assert law.scale_valid(th)
    for A in (1.0, -1.0):
        ref = law.h(x, {**th, "A": A})
        np.testing.assert_allclose(law.h(x, {**th, "A": 37.0 * A}), 37.0 * ref, rtol=1e-9, atol=1e-9)
    # a negative factor is NOT a scaling when gamma != 0 (sgn(h) flips against sgn(dx))
    assert not np.allclose(law.h(x, {**th, "A": -1.0}), -law.h(x, th), atol=1e-3)
    assert not law.scale_valid({**th, "n": 2.0})


def test_unknown_law_is_one_clear_line() -> None:
    with pytest.raises(PmalabError, match=r"unknown model 'maxwell'.*bouc-wen"):
        get_law("maxwell")
