"""The parameter trajectory of a long record: a simulated muscle whose stiffness drifts
(``muscle.stiffness_drift_percent_per_hour``) recorded, identified, and the drift read back
from identification.json.  Scaled down to seconds: a fast drift over 100 s stands for a slow
one over hours (the same windows and fits; the 10-hour record is in bench/)."""

from __future__ import annotations

import json

import pytest

from pmalab.cli import main
from pmalab.identify.campaign.trajectory import MIN_CYCLES, trend

DRIFT = -600.0  # % of the switch-on stiffness per hour: −17 % over the 100 s record


def _record(tmp_path, cycles, drift=DRIFT, seed=3):
    (tmp_path / "truth.toml").write_text(
        f"[muscle]\nstiffness_drift_percent_per_hour = {drift}\n")
    (tmp_path / "rig.toml").write_text(
        f'[rig]\nkind = "sim"\ntruth = "truth.toml"\nseed = {seed}\n')
    (tmp_path / "p.toml").write_text(
        '[protocol]\nname = "fatigue"\n[[run]]\nname = "fatigue"\nmuscle_pressure_MPa = 0.4\n'
        f'waveform = "sine"\nfrequency_Hz = 0.5\nmagnitude_MPa = 0.3\ncycles = {cycles}\n'
        "ramp_s = 1.0\nsettle_s = 0.5\n")
    out = tmp_path / "fatigue.h5"
    assert main(["run", "--rig", str(tmp_path / "rig.toml"), "--protocol",
                 str(tmp_path / "p.toml"), "--out", str(out), "--quiet"]) == 0
    return out


def test_a_drifting_stiffness_is_recovered_from_the_trajectory(tmp_path, capsys):
    f = _record(tmp_path, 48)
    assert main(["identify", str(f), "--model", "bouc-wen", "--out", str(tmp_path / "id"),
                 "--quiet"]) == 0
    doc = json.loads((tmp_path / "id" / "identification.json").read_text())
    (tr,) = doc["trajectory"]
    assert tr["run"] == "fatigue" and tr["cycles_per_window"] == 4
    wins = tr["windows"]
    assert len(wins) == 12 and all(w["status"] == "ok" for w in wins)
    assert [w["cycle_start"] for w in wins] == list(range(0, 48, 4))
    assert all(w["stderr"]["k"] > 0 for w in wins)  # every window carries its uncertainty
    k = tr["trend"]["k"]
    # the truth: k(t) = k0·(1 + r·t) — the line through the windows recovers r within 10 %
    # and within 4 of its own standard errors
    assert k["percent_per_hour"] == pytest.approx(DRIFT, rel=0.10)
    se_pct = 100 * k["per_hour_stderr"] / abs(k["start"])
    assert abs(k["percent_per_hour"] - DRIFT) < 4 * se_pct
    # the tension at zero contraction does not drift (within 4 standard errors)
    c0 = tr["trend"]["c0"]
    assert abs(c0["per_hour"]) < 4 * c0["per_hour_stderr"]
    # what the read and the fits used is stated (a short record: read whole)
    assert doc["decimation"][0]["read"]["stride"] == 1
    # the report draws it: a plot page and a table page
    png = tmp_path / "png"
    assert main(["report", str(tmp_path / "id"), "--out", str(tmp_path / "r.pdf"),
                 "--png", str(png)]) == 0
    names = sorted(p.name for p in png.glob("*.png"))
    assert any(n.endswith("-trajectory-1.png") for n in names), names
    assert any(n.endswith("-trajectory-table-1.png") for n in names), names


def test_a_campaign_of_short_runs_has_no_trajectory(tmp_path):
    f = _record(tmp_path, MIN_CYCLES - 30, drift=0.0)
    assert main(["identify", str(f), "--model", "bouc-wen", "--out", str(tmp_path / "id"),
                 "--quiet"]) == 0
    doc = json.loads((tmp_path / "id" / "identification.json").read_text())
    assert doc["trajectory"] == []


def test_the_trend_line_weights_windows_by_their_errors():
    import numpy as np

    t = np.linspace(0, 10, 11)
    y = 100 - 2 * t
    y[5] += 50  # one window far off, with an error to match
    se = np.full(11, 0.5)
    se[5] = 500.0
    tr = trend(t, y, se)
    assert tr["per_hour"] == pytest.approx(-2, abs=0.01)
    assert tr["percent_per_hour"] == pytest.approx(-2, abs=0.01)
    # without errors the scatter sets the line's error
    loose = trend(t, y, None)
    assert loose["per_hour_stderr"] > 10 * tr["per_hour_stderr"]


def test_a_long_record_read_decimated_is_fitted_on_its_first_cycles(tmp_path, monkeypatch):
    """The long-record path end to end, scaled down: a record above the (lowered) long-run
    threshold is read decimated to 200 samples a cycle, its run-level fit uses its first
    (here 12) cycles, its trajectory all of it, and identification.json says so."""
    import pmalab.identify.long_records as lr

    monkeypatch.setattr(lr, "LONG_RUN_SAMPLES", 20_000)
    monkeypatch.setattr(lr, "FIT_CYCLES", 12)
    f = _record(tmp_path, 48)
    assert main(["identify", str(f), "--model", "bouc-wen", "--out", str(tmp_path / "id"),
                 "--quiet"]) == 0
    doc = json.loads((tmp_path / "id" / "identification.json").read_text())
    (dec,) = doc["decimation"]
    assert dec["read"]["stride"] == 5 and dec["read"]["samples_read"] > 48_000
    assert dec["read"]["samples_per_cycle"] == pytest.approx(200, rel=0.01)
    assert dec["fit_part"]["cycles"] == 12 and dec["samples"] == pytest.approx(12 * 200, abs=2)
    (tr,) = doc["trajectory"]
    assert len(tr["windows"]) == 12  # the whole record, not the fitted part
    assert tr["trend"]["k"]["percent_per_hour"] == pytest.approx(DRIFT, rel=0.15)
    assert doc["runs"][0]["fit_percent"] > 95
