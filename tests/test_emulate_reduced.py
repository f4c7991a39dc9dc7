"""Reduced-rate recording end to end: Modbus RTU at 115200 baud on a pty, real time."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pty_support import needs_pty
from timing_records import (
    check_software_polled,
    kept_deadlines,
    read_timing_records,
    too_busy_refusal,
)

from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.errors import RigError
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
    proto = parse_protocol(PROTO, "rtu.toml")
    with start_emulators(RIGS_DIR / "generic-modbus-rtu.toml", make_links=False) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 60
        # the emulator answers from this process's threads: on a busy machine they may
        # wait longer for a CPU than a real device takes to answer (the rig file's 0.1 s)
        spec.transport.timeout_s = 1.0
        assert spec.allow_reduced_rate
        try:
            rig = build_modbus_rig(spec)
        except RigError as exc:
            # the probe itself says the computer, not the link, made the reads slow
            pytest.skip(too_busy_refusal(exc))
        with rig:
            rate = rig.sampler.sample_rate_Hz
            assert rig.info["timing"]["reduced"] and rate < 500
            assert math.isfinite(rig.info["timing"]["cpu_wait_share"])  # Linux reports it
            run_protocol(rig, proto, out, options=RunnerOptions(progress=False))
    err = capsys.readouterr().err
    assert f"reduced {rate:g} Hz instead of the protocol's 500 Hz" in err
    (r,) = read_runs(out)
    assert r.attrs["status"] == "completed"
    assert r.attrs["sample_rate_Hz"] == rate and r.attrs["requested_sample_rate_Hz"] == 500.0
    # real timestamps on the reduced grid, as the file's own lateness and gap records
    # place them (a busy machine wakes late and misses deadlines; the file says which),
    # every scheduled deadline a sample or a recorded gap
    rec = read_timing_records(out, "r")
    n_scheduled = math.floor(proto.runs[0].duration_s * rate + 1e-9) + 1
    check_software_polled(rec, n_scheduled, read_max_s=4 * spec.transport.timeout_s)
    if kept_deadlines(rec):  # the idle-machine figure
        assert np.median(np.diff(r.time)) == pytest.approx(1 / rate, rel=0.05)
    st = r.attrs["device_stats"]["modbus"]
    assert st["requests"] > len(r) and st["failures"] == 0
