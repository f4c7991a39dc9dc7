"""Round-trip properties (hypothesis): the run-file codec, unit spellings, and the forward
model as the exact inverse of the force law."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pmalab.identify.forward import simulate
from pmalab.identify.model import ForceModel
from pmalab.runfile import UNIT_FACTORS, Run, normalize_unit, read_runs, write_runs

SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


@st.composite
def runs(draw):
    n = draw(st.integers(2, 300))
    dt = draw(st.floats(1e-4, 0.1))
    jitter = draw(st.lists(st.floats(0.0, 0.4), min_size=n, max_size=n))
    t = (np.arange(n) + np.asarray(jitter)) * dt
    vals = st.floats(-400.0, 400.0, allow_nan=False)
    x = np.asarray(draw(st.lists(vals, min_size=n, max_size=n)))
    f = np.asarray(draw(st.lists(st.floats(-15e3, 15e3), min_size=n, max_size=n)))
    p = np.asarray(draw(st.lists(st.floats(0.0, 1.0), min_size=n, max_size=n)))
    attrs = {"muscle_pressure_MPa": draw(st.floats(0.0, 1.0)),
             "waveform": draw(st.sampled_from(["sine", "triangle", "multisine", ""])),
             "frequency_Hz": draw(st.floats(0.01, 200.0))}
    return Run(draw(st.from_regex(r"[a-z][a-z0-9_-]{0,15}", fullmatch=True)), t, x, f, p,
               attrs=attrs)


@SETTINGS
@given(runs())
def test_run_file_codec_round_trips_exactly(tmp_path, run):
    # the codec alone: arbitrary values (a lone 1 MPa sample among zeros) are not a muscle's,
    # and the channel-health check that refuses them is tested on its own
    path = write_runs(tmp_path / "r.h5", [run], force=True)
    (back,) = read_runs(path, health=False)
    assert back.name == run.name
    for ch in ("time", "position", "force", "muscle_pressure"):
        np.testing.assert_array_equal(getattr(back, ch), getattr(run, ch))
    for k, v in run.attrs.items():
        assert back.attrs[k] == v


@given(st.sampled_from([(c, u) for c, us in UNIT_FACTORS.items() for u in us]),
       st.sampled_from(["{}", "[{}]", "({})", " {} ", "{{{}}}"]))
def test_every_unit_reads_back_in_every_bracket_style(cu, style):
    channel, unit = cu
    assert normalize_unit(channel, style.format(unit)) == unit


@settings(max_examples=30, deadline=None)
@given(st.floats(-80.0, -10.0), st.floats(-100.0, -5.0), st.floats(0.05, 1.0),
       st.floats(-0.04, 0.04), st.lists(st.floats(-1.0, 1.0), min_size=20, max_size=200))
def test_the_massless_forward_model_inverts_the_force_law(k, A, beta, gamma, steps):
    # any path x, F = k·x + c0 + h(x): driven by F, the forward model returns the path
    model = ForceModel("bouc-wen")
    th = {"k": k, "c0": 100.0, "A": A, "beta": beta, "gamma": gamma * beta, "n": 1.0,
          "h0": 0.0}
    x = 10.0 + np.cumsum(np.asarray(steps))
    t = np.arange(x.size) / 500.0
    f = k * x + th["c0"] + model.law.h(x, th)
    s = simulate(model, th, t, f, 0.3, x0=float(x[0]))
    assert s.status == "ok"
    np.testing.assert_allclose(s.position, x, rtol=0, atol=1e-7)
