"""``pmalab emulate`` and the one-line errors of real rig files."""

from __future__ import annotations

import socket

from pmalab.cli import main
from pmalab.paths import RIGS_DIR
from pmalab.rig.emulators.launcher import free_tcp_port

T7 = str(RIGS_DIR / "labjack-t7.toml")


def test_emulate_prints_endpoints_and_stops(capsys):
    port = free_tcp_port()
    assert main(["emulate", "--rig", T7, "--port", str(port), "--duration", "0.3"]) == 0
    out = capsys.readouterr()
    assert f"Modbus TCP I/O module: tcp://127.0.0.1:{port}" in out.out
    assert "pmalab run --rig" in out.out
    assert "stopped" in out.err


def test_emulate_itv_rig_links_the_serial_ports(tmp_path, capsys):
    text = (RIGS_DIR / "itv-serial.toml").read_text().replace("/tmp/pmalab-emulator", str(tmp_path / "dev"))
    rig = tmp_path / "itv.toml"
    rig.write_text(text)
    assert main(["emulate", "--rig", str(rig), "--port", str(free_tcp_port()), "--duration", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "SMC ITV (RS-232C) for cylinder_regulator: /dev/pts/" in out
    assert "load-cell indicator: /dev/pts/" in out
    assert not (tmp_path / "dev" / "itv").exists()  # links removed on exit


def test_emulate_refuses_a_sim_rig_and_a_busy_port(capsys):
    assert main(["emulate", "--rig", str(RIGS_DIR / "sim.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "rig.kind: 'sim' is not 'modbus'" in err
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert main(["emulate", "--rig", T7, "--port", str(port), "--duration", "0.2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cannot start the Modbus emulator" in err


def test_run_against_no_device_is_one_line_before_anything_moves(tmp_path, capsys):
    text = (RIGS_DIR / "labjack-t7.toml").read_text().replace("port = 5020", f"port = {free_tcp_port()}")
    rig = tmp_path / "t7.toml"
    rig.write_text(text)
    out = tmp_path / "x.h5"
    code = main(["run", "--rig", str(rig), "--protocol", "quick", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 3
    assert err.count("\n") == 0 and "cannot connect" in err and str(rig) in err
    assert not out.exists()


def test_bad_rig_file_fields_are_one_line(tmp_path, capsys):
    cases = {
        'word_order = "big"  ': ('word_order = "middle"', "word_order: 'middle' is not"),
        "address = 4 ": ("address = -4 ", "[rig.inputs.position] address: -4 outside"),
        'type = "tcp"': ('type = "udp"', "[rig.transport] type 'udp'"),
    }
    base = (RIGS_DIR / "labjack-t7.toml").read_text()
    for old, (new, expect) in cases.items():
        assert old in base, old
        rig = tmp_path / "bad.toml"
        rig.write_text(base.replace(old, new, 1))
        code = main(["run", "--rig", str(rig), "--protocol", "quick", "--out", str(tmp_path / "y.h5")])
        err = capsys.readouterr().err.strip()
        assert code == 2, err
        assert err.count("\n") == 0 and expect in err and str(rig) in err
