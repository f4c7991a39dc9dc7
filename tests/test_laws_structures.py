"""Pressure structures of the element laws: exact mapping back to the base law, and the
leave-one-pressure-out choice on campaigns whose pressure dependence is known.

The campaigns here are made by the Maxwell-slip law itself (a unit test of the structure
machinery, not of the law against the simulator — that is bench section ``laws``): five
pressure levels, one two-cycle 1 Hz run each, 1 N force noise, 0.015 mm position noise.  Slip
displacements growing in proportion to p must choose ``scaled-thresholds``; slip
displacements the same at every pressure with one stiffness profile must not (their
structure is ``scaled``, of which ``scaled-thresholds`` is a superset, so either of the two
simpler-or-equal structures that contain the truth is right, never a worse held-out error).
"""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.identify.campaign.fit import fit_campaign
from pmalab.identify.laws import get_law
from pmalab.identify.laws.structures import base_laws, structured_law
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals
from pmalab.runfile import Run

KAPPA = np.array([0.4, 0.3, 0.2, 0.1])
DELTA = np.array([0.3, 1.0, 2.5, 5.0])


@pytest.mark.parametrize("structure", ["scaled", "scaled-thresholds"])
def test_structured_law_is_the_base_law_with_its_pressure_laws_mapped(structure):
    base = get_law("maxwell-slip")
    law = structured_law(base, structure, KAPPA, DELTA)
    rng = np.random.default_rng(3)
    coef = {"s": (20.0, 60.0, -15.0), "t": (0.5, 1.2, 0.4)}
    for n in law.shared_shape:
        coef[n] = (float(rng.uniform(0.6, 1.5)), 0.0, 0.0)
    mapped = base_laws(base, law, coef)
    x = 6.0 + 5.0 * np.sin(np.linspace(0.0, 6.0 * np.pi, 1500)) * np.linspace(0.3, 1.0, 1500)
    for p in (0.2, 0.37, 0.55):
        th_s = {n: q[0] + q[1] * p + q[2] * p * p for n, q in coef.items()}
        if structure == "scaled":
            th_s["t"] = 1.0
        th_s["h0"] = 0.0
        th_b = {n: q[0] + q[1] * p + q[2] * p * p for n, q in mapped.items()}
        th_b["h0"] = 0.0
        np.testing.assert_allclose(law.h(x, th_s), base.h(x, th_b), rtol=1e-12, atol=1e-9)


def test_prandtl_ishlinskii_scaled_keeps_its_threshold_grid():
    base = get_law("prandtl-ishlinskii")
    k, d = base.elements({f"w{i + 1}": 1.0 + i for i in range(15)} | {"h0": 0.0})
    law = structured_law(base, "scaled", k, d)
    assert law.r_index == () and "t" in law.default_fixed
    with pytest.raises(ValueError, match="scaled-thresholds"):
        structured_law(base, "scaled-thresholds", k, d)


def _campaign(slip_exponent: float) -> list[Run]:
    """One 1 Hz run (two cycles) per level; element i: k_i = s(p)·κ_i, d_i = δ_i·(p/0.4)^a."""
    law = get_law("maxwell-slip")
    runs = []
    for j, p in enumerate((0.2, 0.27, 0.34, 0.41, 0.48)):
        rng = np.random.default_rng(100 + j)
        n = 1000
        t = (np.arange(n) + 0.05 * rng.uniform(-1, 1, n)) / 500.0
        x = 8.0 + 6.0 * np.sin(2 * np.pi * 1.0 * t - np.pi / 2)
        sig = Signals.from_arrays(t, x, p, p_nom=p, frequency_Hz=1.0, cutoff_Hz=1e9)
        s = 30.0 + 150.0 * p
        th = {"k": -20 - 60 * p, "c0": 2500 * p - 100, "h0": 0.0}
        for i in range(4):
            th[f"k{i + 1}"] = s * KAPPA[i]
            th[f"d{i + 1}"] = DELTA[i] * (p / 0.4) ** slip_exponent
        F = ForceModel(law).predict(sig, th)
        runs.append(
            Run(
                name=f"p{int(p * 1000)}",
                time=t,
                position=x + 0.015 * rng.standard_normal(n),
                force=F + rng.standard_normal(n),
                muscle_pressure=p + 0.001 * rng.standard_normal(n),
                attrs={"muscle_pressure_MPa": p, "frequency_Hz": 1.0, "waveform": "sine"},
            )
        )
    return runs


def test_slip_displacements_growing_with_pressure_choose_scaled_thresholds():
    cf = fit_campaign(_campaign(1.0), "maxwell-slip")
    st = cf.structure
    assert st is not None and st.chosen == "scaled-thresholds", st and st.scores
    # the evidence: held-out error of the winner below the free structure's (which holds
    # the slip displacements constant in p), and the margin reported
    assert st.scores["scaled-thresholds"] < st.scores["free"]
    assert st.margin_percent > 0
    js = st.as_json()
    assert js["chosen"] == "scaled-thresholds" and len(js["candidates"]) == 3
    # the reported laws are the base law's: d1 grows with p (slope > 0), as simulated
    assert cf.pressure["d1"].coef[1] > 0 and cf.pressure["d1"].method.startswith("structure:")
    assert any(getattr(w, "code", "") == "pressure-structure" for w in cf.warnings)


def test_free_structure_keeps_the_law_as_its_file_says():
    cf = fit_campaign(_campaign(0.0), "maxwell-slip", structure="free")
    assert cf.structure is None
    assert all(cf.pressure[f"d{i}"].degree == 0 for i in range(1, 5))
