"""``pmalab emulate --port P`` prints a ``pmalab run`` command that reaches port P, and
``pmalab run --host/--port`` override a Modbus TCP rig file's endpoint."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_vent_dead_link import PROTO, t7_rig_file

from pmalab.cli import main
from pmalab.paths import RIGS_DIR
from pmalab.rig.emulators.launcher import free_tcp_port
from pmalab.runfile import read_runs


def emulate(rig: Path, port: int) -> tuple[subprocess.Popen, str]:
    """``pmalab emulate --rig RIG --port PORT`` in its own process; its printed run command."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "pmalab.cli", "emulate", "--rig", str(rig), "--port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    command, lines = None, []
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if line.strip().startswith("now: "):
            command = line.strip()[len("now: "):]
        if "Ctrl-C to stop" in line or (not line and proc.poll() is not None):
            break
    if command is None:
        proc.kill()
        raise AssertionError("pmalab emulate printed no run command: " + "".join(lines))
    return proc, command


def test_the_printed_command_reaches_the_emulator_on_its_port(tmp_path):
    rig_port = free_tcp_port()  # what the rig file says; nothing listens there
    rig = t7_rig_file(tmp_path, rig_port)
    port = free_tcp_port()
    proc, command = emulate(rig, port)
    try:
        argv = shlex.split(command)
        assert argv[:2] == ["pmalab", "run"] and argv[argv.index("--port") + 1] == str(port)
        proto = tmp_path / "p.toml"
        proto.write_text(PROTO.replace("cycles = 3", "cycles = 1").replace(
            "frequency_Hz = 0.5", "frequency_Hz = 1.0"))
        out = tmp_path / "x.h5"
        argv = [str(proto) if a == "PROTOCOL.toml" else str(out) if a == "FILE.h5" else a
                for a in argv[1:]]
        assert main([*argv, "--quiet"]) == 0
    finally:
        proc.terminate()
        log, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, log
    (r,) = read_runs(out)
    assert r.attrs["status"] == "completed"
    assert json.loads(r.attrs["rig"])["transport"] == f"tcp://127.0.0.1:{port}"
    served = int(log.split("(")[-1].split()[0])  # "stopped (N block reads, ...)"
    assert served >= len(r)


def test_emulate_on_the_rig_files_port_prints_no_port_override(tmp_path, capsys):
    rig = t7_rig_file(tmp_path, free_tcp_port())
    assert main(["emulate", "--rig", str(rig), "--duration", "0.2"]) == 0
    out = capsys.readouterr().out
    assert f"now: pmalab run --rig {rig} --protocol PROTOCOL.toml --out FILE.h5" in out


@pytest.mark.parametrize("rig, args, needle", [
    ("sim", ["--port", "5020"], "--host/--port: the simulated rig 'sim' has no network link"),
    (str(RIGS_DIR / "sim.toml"), ["--host", "10.1.2.3"], "is a rig of kind 'sim'"),
    (str(RIGS_DIR / "generic-modbus-rtu.toml"), ["--port", "5020"],
     "--port: " + str(RIGS_DIR / "generic-modbus-rtu.toml") + " talks Modbus RTU on a serial"),
    ("sim", ["--port", "70000"], "--port: must be a TCP port 1…65535, got 70000"),
])
def test_host_port_where_they_do_not_apply_are_one_line(tmp_path, capsys, rig, args, needle):
    out = tmp_path / "x.h5"
    code = main(["run", "--rig", rig, "--protocol", "quick", "--out", str(out), *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and needle in err, err
    assert not out.exists()


def test_port_override_names_the_overridden_endpoint(tmp_path, capsys):
    port = free_tcp_port()  # nothing listens there
    out = tmp_path / "x.h5"
    code = main(["run", "--rig", str(RIGS_DIR / "labjack-t7.toml"), "--host", "127.0.0.1",
                 "--port", str(port), "--protocol", "quick", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 3 and err.count("\n") == 0
    assert f"tcp://127.0.0.1:{port}: cannot connect" in err
    assert not out.exists()
