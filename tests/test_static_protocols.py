"""Isometric and isotonic protocols played by the 500 Hz runner on the simulated static
stand (a commanded muscle regulator, a clamp or a hanging mass), and their refusal by a rig
that cannot command the muscle pressure."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from pmalab.acquisition.protocol import load_protocol, parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.acquisition.safety import ProtocolRefused
from pmalab.cli import main as pmalab_main
from pmalab.errors import ConfigError
from pmalab.rig.loader import load_rig
from pmalab.rig.sim.static_stand import load_static_truth
from pmalab.runfile import read_runs


def _cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = pmalab_main(argv)
        except SystemExit as exc:
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


def _opts() -> RunnerOptions:
    return RunnerOptions(progress=False, realtime_priority=False)


def test_isometric_protocol_holds_lengths_ramps_pressure_and_identifies_the_braid_angle(
    tmp_path,
):
    out = tmp_path / "iso.h5"
    code, _, err = _cli(
        ["run", "--rig", "sim-static", "--protocol", "isometric", "--out", str(out)]
    )
    assert code == 0, err
    truth = load_static_truth("geometric")
    runs = read_runs(out)
    assert {r.name for r in runs} >= {"iso-0mm", "iso-12mm", "iso-24mm", "iso-36mm"}
    for r in runs:
        assert r.attrs["test_type"] == "isometric"
        held = float(r.attrs["held_position_mm"])
        # the clamp holds: the reading is the held length within the sensor's noise
        assert abs(float(np.mean(r.position)) - held) < 0.01
        assert float(np.max(np.abs(r.position - held))) < 6 * truth.position_noise_mm + 0.002
        # the muscle pressure goes up to ~0.6 MPa and back down to ~0
        p = r.muscle_pressure
        k = int(np.argmax(p))
        assert 0.58 < p[k] < 0.62 and p[0] < 0.01 and p[-1] < 0.03
        assert 0.3 < r.time[k] / r.time[-1] < 0.7  # a ramp up, then a ramp down
    code, _, err = _cli(
        [
            "identify",
            str(out),
            "--static",
            "chou-hannaford",
            "--length",
            "200",
            "--model",
            "duhem",
            "--out",
            str(tmp_path / "ch"),
        ]
    )
    assert code == 0, err
    doc = json.loads((tmp_path / "ch" / "identification.json").read_text())
    theta0 = doc["static_map"]["parameters"]["theta0_deg"]["value"]
    assert abs(theta0 - truth.braid_angle_deg) / truth.braid_angle_deg < 0.05


def test_isotonic_protocol_holds_its_load_while_the_length_follows_the_pressure(tmp_path):
    rig = load_rig("sim-static", seed=3)
    proto = load_protocol("isotonic")
    out = tmp_path / "ton.h5"
    run_protocol(rig, proto, out, options=_opts())
    runs = read_runs(out)
    noise = load_static_truth("geometric").force_noise_N
    for r in runs:
        load = float(r.attrs["load_N"])
        assert r.attrs["test_type"] == "isotonic"
        assert abs(float(np.mean(r.force)) - load) < 0.1
        assert float(np.std(r.force)) < 1.5 * noise
        # more pressure, more contraction: the length follows the pressure cycle (a loop:
        # the braid's friction) by tens of mm, measured, not held
        x, p = r.position, r.muscle_pressure
        assert np.corrcoef(x, p)[0, 1] > 0.8
        assert float(x[np.argmax(p)] - x[np.argmin(p)]) > 10.0
    assert rig.last_vent is not None and rig.last_vent.ok


def test_a_rig_without_a_commanded_muscle_regulator_refuses_before_anything_moves(tmp_path):
    out = tmp_path / "iso.h5"
    code, _, err = _cli(["run", "--rig", "sim", "--protocol", "isometric", "--out", str(out)])
    assert code != 0
    line = err.strip().splitlines()[-1]
    assert "rig 'sim'" in line and "muscle_pressure_command" in line and "Traceback" not in err
    assert not out.exists()
    rig = load_rig("sim")
    with pytest.raises(ProtocolRefused, match="no commanded muscle regulator"):
        run_protocol(rig, load_protocol("isometric"), tmp_path / "b.h5", options=_opts())


@pytest.mark.parametrize(
    "body, msg",
    [
        ('test_type = "isometric"\nmagnitude_MPa = 0.5', "missing field 'held_position_mm'"),
        (
            'test_type = "isotonic"\nmagnitude_MPa = 0.5\nheld_position_mm = 3',
            "'held_position_mm' does not apply",
        ),
        (
            'test_type = "isometric"\nmagnitude_MPa = 0.5\nheld_position_mm = 3\nmuscle_pressure_MPa = 0.3',
            "'muscle_pressure_MPa' does not apply",
        ),
        (
            'muscle_pressure_MPa = 0.3\nmagnitude_MPa = 0.5\nwaveform = "steps"',
            "'steps' is for isometric",
        ),
        ('test_type = "free"\nmagnitude_MPa = 0.5', "field 'test_type' must be one of"),
    ],
)
def test_static_run_fields_are_checked(body, msg):
    text = f'[[run]]\nname = "a"\nfrequency_Hz = 0.1\n{body}\n'
    with pytest.raises(ConfigError, match=msg):
        parse_protocol(text, "p.toml")


def test_the_muscle_command_is_recorded_and_a_stand_without_cylinder_refuses_isobaric(tmp_path):
    import h5py

    rig = load_rig("sim-static")
    proto = load_protocol("isometric").select(names=["iso-12mm"])
    out = tmp_path / "a.h5"
    run_protocol(rig, proto, out, options=_opts())
    with h5py.File(out) as f:
        g = f["runs"]["iso-12mm"]
        cmd = g["muscle_pressure_command"][:]
        assert float(cmd.max()) == pytest.approx(0.6, abs=1e-3) and float(cmd[0]) == 0.0
        assert float(np.abs(g["cylinder_pressure_command"][:]).max()) == 0.0
    with pytest.raises(ProtocolRefused, match="has none"):
        run_protocol(
            load_rig("sim-static"), load_protocol("quick"), tmp_path / "b.h5", options=_opts()
        )
    assert not (tmp_path / "b.h5").exists()


def test_a_trip_in_an_isometric_run_vents_the_muscle_regulator_and_keeps_the_samples(tmp_path):
    from pmalab.errors import SafetyAbort

    rig = load_rig("sim-static")
    rig.limits.max_force_N = 200.0  # the 0 mm ramp passes 200 N about 40 % of the way up
    out = tmp_path / "trip.h5"
    proto = load_protocol("isometric").select(names=["iso-0mm", "iso-12mm"])
    with pytest.raises(SafetyAbort, match="muscle regulator vented \\(confirmed"):
        run_protocol(rig, proto, out, options=_opts())
    physics = rig.sampler.physics  # type: ignore[attr-defined]
    assert physics.command == 0.0
    runs = read_runs(out, skip_incomplete=False)
    assert runs[0].attrs["status"].startswith("aborted") and len(runs[0]) > 1000
    assert float(runs[0].force.max()) > 195.0
