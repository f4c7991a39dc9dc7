"""Reduced-rate recording end to end: Modbus RTU at 115200 baud on a pty, real time."""

from __future__ import annotations

import numpy as np
import pytest
from pty_support import needs_pty

from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.paths import RIGS_DIR
from pmalab.rig.drivers.rigfile import build_modbus_rig
from pmalab.rig.emulators.launcher import start_emulators
from pmalab.runfile import read_runs

PROTO = """
[protocol]
name = "rtu-short"
[[run]]
name = "r"
muscle_pressure_MPa = 0.3
waveform = "sine"
frequency_Hz = 0.5
magnitude_MPa = 0.25
cycles = 1
ramp_s = 0.2
settle_s = 0.2
pressure_stable_s = 0.2
pressure_tolerance_MPa = 0.02
pressure_timeout_s = 20
"""


@needs_pty
def test_rtu_records_at_the_reduced_rate_with_link_counters(tmp_path, capsys):
    out = tmp_path / "rtu.h5"
    with start_emulators(RIGS_DIR / "generic-modbus-rtu.toml", make_links=False) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 60
        assert spec.allow_reduced_rate
        with build_modbus_rig(spec) as rig:
            rate = rig.sampler.sample_rate_Hz
            assert rig.info["timing"]["reduced"] and rate < 500
            run_protocol(rig, parse_protocol(PROTO, "rtu.toml"), out,
                         options=RunnerOptions(progress=False))
    err = capsys.readouterr().err
    assert f"reduced {rate:g} Hz instead of the protocol's 500 Hz" in err
    (r,) = read_runs(out)
    assert r.attrs["status"] == "completed"
    assert r.attrs["sample_rate_Hz"] == rate and r.attrs["requested_sample_rate_Hz"] == 500.0
    # real timestamps on the reduced grid (a busy machine misses a few deadlines, counted)
    assert np.median(np.diff(r.time)) == pytest.approx(1 / rate, rel=0.05)
    assert len(r) >= 0.8 * (0.2 + 0.4 + 2.0) * rate
    st = r.attrs["device_stats"]["modbus"]
    assert st["requests"] > len(r) and st["failures"] == 0
