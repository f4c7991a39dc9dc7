"""LabJack T7 stream mode over Modbus TCP, wire-level against the emulator (real time).

The emulator (pmalab.rig.emulators.modbus_server.StreamEngine) scans the simulated rig on
its own clock into a buffer of STREAM_BUFFER_SIZE_BYTES; the driver (pmalab.rig.drivers.
t7_stream) configures the scan list and rate, starts the stream in command-response mode
and reads the backlog from STREAM_DATA_CR.  A stall the device recovers from (skipped
scans, marked by a 0xFFFF dummy scan and counted in status 2941) must show as a recorded
gap of exactly that many scans and a warning — never as invented samples.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest

from pmalab.acquisition.protocol import load_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.paths import RIGS_DIR
from pmalab.rig.drivers.t7_stream import NOMINAL, codes_to_volts, volts_to_codes
from pmalab.rig.emulators.launcher import free_tcp_port, start_emulators
from pmalab.rig.loader import load_rig
from pmalab.runfile import decode_attr, read_runs

RIG = RIGS_DIR / "labjack-t7-stream.toml"


def _rig(tmp_path) -> Path:
    """The shipped stream rig with a longer reply timeout: the emulator is a process (or
    threads) on this machine, and when it is busy it may wait longer for a CPU than a T7
    takes to answer (the rig file's 0.05 s).  The device's clock stamps the samples, so
    a late reply changes no stamp, and the scans of a few late replies fit its buffer
    (16384 samples: ~8 s of four-channel scans at 500 Hz)."""
    text = RIG.read_text()
    assert "timeout_s = 0.05 " in text
    rig = tmp_path / "t7-stream.toml"
    rig.write_text(text.replace("timeout_s = 0.05 ", "timeout_s = 0.5 "))
    return rig


def test_code_conversion_round_trips_within_one_lsb():
    v = np.linspace(-9.9, 9.9, 2001)
    back = codes_to_volts(volts_to_codes(v))
    assert np.max(np.abs(back - v)) <= abs(NOMINAL["positive_slope"])  # one code
    assert volts_to_codes(np.array([50.0]))[0] == 65534  # never the dummy code


def test_stream_records_on_the_device_clock_with_nothing_missed(tmp_path):
    rig = _rig(tmp_path)
    port = free_tcp_port()
    proc = subprocess.Popen([sys.executable, "-m", "pmalab.cli", "emulate", "--rig", str(rig),
                             "--port", str(port)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        while "Ctrl-C to stop" not in (line := proc.stdout.readline()):
            assert line, "pmalab emulate did not start"
        out = tmp_path / "x.h5"
        p = subprocess.run([sys.executable, "-m", "pmalab.cli", "run", "--rig", str(rig),
                            "--port", str(port), "--protocol", "quick", "--out", str(out)],
                           capture_output=True, text=True, timeout=120)
        assert p.returncode == 0, p.stderr
        assert "missed 0" in p.stdout + p.stderr
    finally:
        proc.terminate()
        proc.wait(10)
    with h5py.File(out) as f:
        assert decode_attr(f.attrs["time_base"]) == "device sample clock"
        (g,) = f["runs"].values()
        t = g["time"][:]
        assert g["gaps"].shape == (0, 2)
    np.testing.assert_allclose(np.diff(t), 1 / 500, rtol=0, atol=1e-12)  # k / rate
    (r,) = read_runs(out)
    assert r.state == "completed" and len(r) == 2751
    assert np.ptp(r.position) > 5 and np.ptp(r.force) > 100  # the muscle moved


def test_an_overflow_in_the_device_is_a_recorded_gap_never_invented_samples(tmp_path):
    protocol = load_protocol("quick")
    out = tmp_path / "gap.h5"
    with start_emulators(_rig(tmp_path), tcp_port=0, make_links=False) as emus:
        port = int(emus.endpoints()[0].rsplit(":", 1)[1])
        rig = load_rig(_rig(tmp_path), port=port)
        timer = threading.Timer(3.0, emus.faults.arm, ("stream_overflow", 1))
        timer.start()
        try:
            res = run_protocol(rig, protocol, out, options=RunnerOptions(progress=False))
        finally:
            timer.cancel()
            rig.close()
        skipped = emus.modbus.model.stream.INJECTED_SKIP
    (r,) = read_runs(out)
    with h5py.File(out) as f:
        gaps = next(iter(f["runs"].values()))["gaps"][:]
    assert gaps.shape == (1, 2) and gaps[0, 1] == skipped  # exactly the scans skipped
    dt = np.diff(r.time)
    jumps = np.flatnonzero(dt > 1.5 / 500)
    assert len(jumps) == 1 and dt[jumps[0]] == pytest.approx((skipped + 1) / 500, abs=1e-12)
    assert len(r) == 2751 - skipped  # nothing filled in
    assert r.attrs["timing"]["missed"] == skipped
    stats = rig.sampler.stats()["stream"]
    assert stats["skipped_scans"] == skipped and stats["dummy_scans"] == 1
    assert res[0].n_samples == len(r)
    assert f"skipped {skipped} sample(s)" in res[0].warning
