"""A link that dies mid-run: the abort line states each regulator's vent outcome honestly.

The device (pmalab's emulator, or an independent pyModbusTCP server) runs in a separate
process that is killed with SIGKILL while ``pmalab run`` records: the vent writes cannot be
delivered, so the one-line abort must say FAILED for both Modbus regulators, tell the
operator what to do, and never claim they were vented.  An ITV that stops answering while
the muscle's DAC still does gives a FAILED cylinder and a confirmed muscle.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import pytest
from pty_support import needs_pty
from test_emulate_run import start_emulate_process

from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.cli import main
from pmalab.errors import SafetyAbort
from pmalab.paths import RIGS_DIR
from pmalab.rig.drivers.rigfile import build_modbus_rig
from pmalab.rig.emulators.launcher import free_tcp_port, start_emulators

HERE = Path(__file__).parent
PROTO = """
[protocol]
name = "dead-link"
[[run]]
name = "r"
muscle_pressure_MPa = 0.3
waveform = "sine"
frequency_Hz = 0.5
magnitude_MPa = 0.2
cycles = 3
ramp_s = 0.2
settle_s = 0.2
pressure_stable_s = 0.2
pressure_tolerance_MPa = 0.02
pressure_timeout_s = 20
"""


def t7_rig_file(tmp_path: Path, port: int) -> Path:
    """The shipped T7 rig file on ``port``, with a short probe and a reduced rate allowed
    (a loaded test machine must not refuse the link before the test starts)."""
    text = (RIGS_DIR / "labjack-t7.toml").read_text()
    text = text.replace("port = 5020", f"port = {port}")
    text = text.replace("allow_reduced_rate = false", "allow_reduced_rate = true")
    text = text.replace("probe_samples = 300", "probe_samples = 40")
    rig = tmp_path / "t7.toml"
    rig.write_text(text)
    return rig


def kill_when_recording(proc: subprocess.Popen, out: Path, after_s: float = 1.0) -> threading.Thread:
    """SIGKILL ``proc`` ``after_s`` after the run file appears (the runner is recording)."""

    def watch() -> None:
        deadline = time.monotonic() + 60
        while not out.exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(after_s)
        os.kill(proc.pid, signal.SIGKILL)

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    return th


def run_until_killed(tmp_path: Path, proc: subprocess.Popen, port: int, capsys) -> tuple[int, str]:
    proto = tmp_path / "p.toml"
    proto.write_text(PROTO)
    out = tmp_path / "x.h5"
    watcher = kill_when_recording(proc, out)
    try:
        code = main(["run", "--rig", str(t7_rig_file(tmp_path, port)), "--protocol", str(proto),
                     "--out", str(out), "--quiet"])
    finally:
        watcher.join(timeout=60)
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=20)
    assert proc.returncode == -signal.SIGKILL
    err = capsys.readouterr().err.strip()
    with h5py.File(out, "r") as f:  # closed cleanly, the run marked aborted
        assert f["runs/r/status"][()].decode().startswith("aborted: device fault")
    return code, err


def assert_both_failed(code: int, err: str) -> None:
    assert code == SafetyAbort.exit_code
    # one error line (a loaded machine may add the reduced-rate warning before it)
    errors = [ln for ln in err.splitlines() if not ln.startswith("pmalab: warning: ")]
    assert len(errors) == 1, err
    err = errors[0]
    assert "aborted: device fault" in err
    assert ("cylinder regulator vent FAILED (zero write to register 1000 not acknowledged "
            "after 4 attempts; last: ") in err
    assert ("): close the cylinder's supply valve and exhaust the cylinder by hand") in err
    assert ("muscle regulator vent FAILED (zero write to register 1002 not acknowledged "
            "after 4 attempts; last: ") in err
    assert "close the muscle's supply valve and exhaust the muscle by hand" in err
    assert "regulator vented" not in err and "confirmed" not in err


def test_killed_emulator_process_mid_run_reports_both_vents_failed(tmp_path, capsys):
    port = free_tcp_port()
    proc = start_emulate_process(RIGS_DIR / "labjack-t7.toml", port)
    code, err = run_until_killed(tmp_path, proc, port, capsys)
    assert_both_failed(code, err)


def test_killed_independent_server_mid_run_reports_both_vents_failed(tmp_path, capsys):
    port = free_tcp_port()
    proc = subprocess.Popen([sys.executable, str(HERE / "independent_modbus.py"), str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert proc.stdout.readline().strip() == "serving"
    code, err = run_until_killed(tmp_path, proc, port, capsys)
    assert_both_failed(code, err)


@needs_pty
def test_itv_that_stops_answering_fails_its_vent_while_the_dac_confirms(tmp_path):
    """Cylinder on an SMC ITV (RS-232C), muscle on a Modbus DAC: only the ITV is lost."""
    out = tmp_path / "itv.h5"
    with start_emulators(RIGS_DIR / "itv-serial.toml", make_links=False,
                         serial_pacing=False) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 0
        itv = emus.itvs["cylinder_regulator"]
        with build_modbus_rig(spec) as rig:
            rig.cylinder_regulator.vent_confirm_s = 0.3
            rig.cylinder_regulator.timeout = 0.05  # a dead ITV fails each vent in 0.15 s
            timer = threading.Timer(1.0, itv.faults.arm, ("drop", 10**6))
            timer.start()
            try:
                with pytest.raises(SafetyAbort) as ei:
                    run_protocol(rig, parse_protocol(PROTO, "itv.toml"), out,
                                 options=RunnerOptions(progress=False))
            finally:
                timer.cancel()
                itv.faults.clear()
        assert emus.plant.physics.muscle_supply == 0.0  # the DAC's vent reached the plant
    msg = str(ei.value)
    assert "\n" not in msg
    assert "cylinder regulator vent FAILED (SET 0 not acknowledged by serial://" in msg
    assert "close the cylinder's supply valve and exhaust the cylinder by hand" in msg
    assert "cylinder regulator vented" not in msg
    assert ("muscle regulator vented (confirmed: write acknowledged by tcp://127.0.0.1:"
            in msg and "register 1002 reads back 0)" in msg)
    assert ei.value.vent.failed == ["cylinder regulator"]
