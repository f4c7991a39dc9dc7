"""The acquisition runner recording through the real drivers and the emulators (real time)."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
import time

import h5py
import numpy as np
import pytest
from timing_records import check_software_polled, kept_deadlines, read_timing_records

from pmalab.acquisition.protocol import load_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.errors import SafetyAbort
from pmalab.paths import RIGS_DIR
from pmalab.rig.drivers.modbus_daq import FALLBACK_RATES_HZ
from pmalab.rig.drivers.rigfile import build_modbus_rig, read_modbus_rig_file
from pmalab.rig.emulators.launcher import free_tcp_port, start_emulators
from pmalab.rig.loader import load_rig


def start_emulate_process(rig_file, port: int) -> subprocess.Popen:
    """``pmalab emulate`` in its own process (as a user runs it); waits until it listens."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "pmalab.cli", "emulate", "--rig", str(rig_file), "--port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    lines = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if "Ctrl-C to stop" in line:
            return proc
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise AssertionError("pmalab emulate did not start: " + "".join(lines))


def branch_means(path, run: str, bins: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean force per position bin on the two branches of the steady cycles, and force range."""
    with h5py.File(path) as f:
        g = f["runs"][run]
        t = g["time"][:]
        x, force, cmd = g["position"][:], g["force"][:], g["cylinder_pressure_command"][:]
        t0, t1 = float(g.attrs["steady_start_s"]), float(g.attrs["steady_end_s"])
    keep = (t >= t0) & (t <= t1)
    rising = np.gradient(cmd, t) > 0
    out = []
    for branch in (rising, ~rising):
        sel = keep & branch
        idx = np.digitize(x[sel], bins)
        out.append(np.array([force[sel][idx == i].mean() if np.any(idx == i) else np.nan for i in range(1, len(bins))]))
    return out[0], out[1], float(np.ptp(force[keep]))


@pytest.mark.slow
def test_emulated_t7_records_the_same_loops_as_the_in_process_sim(tmp_path):
    protocol = load_protocol("quick")
    run = protocol.runs[0].name
    sim_out = tmp_path / "sim.h5"
    with load_rig("sim", seed=0) as rig:
        run_protocol(rig, protocol, sim_out, options=RunnerOptions(progress=False))
    emu_out = tmp_path / "emu.h5"
    port = free_tcp_port()
    proc = start_emulate_process(RIGS_DIR / "labjack-t7.toml", port)
    try:
        spec = read_modbus_rig_file(RIGS_DIR / "labjack-t7.toml")
        spec.transport.port = port
        # the loops are the point: on a loaded 2-core machine the probe may measure a link
        # too slow for 500 Hz, and the rig then records at the reduced rate it announces
        spec.allow_reduced_rate = True
        # the emulator is a process on this machine: when it is busy, the emulator may wait
        # longer for a CPU than a T7 takes to answer (the rig file's 0.05 s)
        spec.transport.timeout_s = 0.5
        with build_modbus_rig(spec) as rig:
            rate = float(rig.info["timing"]["sample_rate_Hz"])
            assert rate in FALLBACK_RATES_HZ
            res = run_protocol(rig, protocol, emu_out, options=RunnerOptions(progress=False))
            stats = rig.sampler.stats()["modbus"]
    finally:
        proc.terminate()
        out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, out
    assert res[0].status == "completed"
    assert stats["failures"] == 0
    with h5py.File(emu_out) as f:
        g = f["runs"][run]
        t = g["time"][:]
        assert g.attrs["sample_rate_Hz"] == rate
    # real timestamps at the announced rate, as the file's own lateness and gap records
    # place them (on a machine shared with other work samples wake late and deadlines are
    # missed: the file says which), every scheduled deadline a sample or a recorded gap
    rec = read_timing_records(emu_out, run)
    n_scheduled = math.floor(protocol.runs[0].duration_s * rate + 1e-9) + 1
    read_max_s = (spec.transport.retries + 1) * spec.transport.timeout_s
    check_software_polled(rec, n_scheduled, read_max_s)
    if kept_deadlines(rec):  # the idle-machine figure: median period 1/rate
        assert np.median(np.diff(t)) == pytest.approx(1.0 / rate, rel=0.03)
    # the same loop shapes: branch-wise mean force per position bin agree
    with h5py.File(sim_out) as f:
        xs = f["runs"][run]["position"][:]
    bins = np.linspace(np.percentile(xs, 5), np.percentile(xs, 95), 9)
    su, sd, srange = branch_means(sim_out, run, bins)
    eu, ed, _ = branch_means(emu_out, run, bins)
    diff = np.concatenate([su - eu, sd - ed])
    assert np.nanmax(np.abs(diff)) < 0.04 * srange
    # hysteresis in the physical direction on both: the branches differ by the same width
    assert np.nanmean(np.abs(su - sd)) == pytest.approx(np.nanmean(np.abs(eu - ed)), rel=0.25)


def test_device_fault_mid_run_aborts_safely_vents_and_keeps_the_file(tmp_path):
    protocol = load_protocol("quick")
    out = tmp_path / "abort.h5"
    with start_emulators(RIGS_DIR / "labjack-t7.toml", tcp_port=0, make_links=False) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 50
        spec.allow_reduced_rate = True  # the fault is the point, not 500 Hz on a busy machine
        with build_modbus_rig(spec) as rig:
            # 4 dropped replies exhaust one request's retries; the 2 more hit the vent,
            # which retries through them
            timer = threading.Timer(3.5, emus.faults.arm, ("drop", 6))
            timer.start()
            with pytest.raises(SafetyAbort, match=r"device fault: .*after 4 attempts.*; "
                               r"cylinder regulator vented \(confirmed: write acknowledged"):
                run_protocol(rig, protocol, out, options=RunnerOptions(progress=False))
            timer.cancel()
            assert rig.sampler.link.stats.failures >= 1
        assert emus.plant.physics.cylinder_command == 0.0
        assert emus.plant.physics.muscle_supply == 0.0
    with h5py.File(out) as f:
        g = f["runs"][protocol.runs[0].name]
        n = len(g["time"])
    assert n > 200  # the samples before the fault are kept
