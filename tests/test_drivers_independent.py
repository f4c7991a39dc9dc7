"""pmalab's Modbus drivers against an independent server (pyModbusTCP, from the package index).

The registers are written with ``struct`` from volts chosen here, and the expected
engineering values are worked out by hand from the rig files' calibrations, so decoding,
scaling, signedness and FLOAT32 word order are checked against software that shares no code
with pmalab (a bug mirrored in pmalab's emulator would pass the emulator tests).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from independent_modbus import T7_INPUT_VOLTS, float_words, serve, t7_bank
from pyModbusTCP.server import DataBank

from pmalab.paths import RIGS_DIR
from pmalab.rig.drivers.rigfile import build_modbus_rig, read_modbus_rig_file
from pmalab.rig.emulators.launcher import free_tcp_port

#: volts exactly representable in FLOAT32, so the expected values are exact
VOLTS = {"muscle_pressure": (0, 2.25), "cylinder_pressure": (2, 1.5),
         "position": (4, 5.0), "force": (6, 2.0)}
#: by hand from labjack-t7.toml: pressures 1–5 V = 0–1 MPa, position 0–10 V = −10…40 mm,
#: force 0–10 V = 0–2500 N
T7_EXPECTED = {"muscle_pressure": 0.3125, "cylinder_pressure": 0.125, "position": 15.0,
               "force": 500.0}


def rig_on(path: Path, port: int, tmp_path: Path, replace: tuple[str, str] | None = None):
    """A connected rig from a shipped rig file, on ``port``, without the rate probe."""
    if replace is not None:
        text = path.read_text()
        assert replace[0] in text
        path = tmp_path / path.name
        path.write_text(text.replace(*replace))
    spec = read_modbus_rig_file(path)
    spec.transport.port = port
    spec.probe_samples = 0
    return build_modbus_rig(spec)


@pytest.fixture
def port():
    return free_tcp_port()


@pytest.mark.parametrize("word_order", ["big", "little"])
def test_t7_float32_values_scaling_and_word_order(tmp_path, port, word_order):
    bank = t7_bank(VOLTS, word_order)
    server = serve(port, bank)
    try:
        with rig_on(RIGS_DIR / "labjack-t7.toml", port, tmp_path,
                    ('word_order = "big"', f'word_order = "{word_order}"')) as rig:
            v = rig.sampler.read_values()
            for name, expected in T7_EXPECTED.items():
                assert v[name] == pytest.approx(expected, abs=1e-12), name
    finally:
        server.stop()


def test_t7_regulator_writes_and_confirmed_vent(tmp_path, port):
    bank = t7_bank(T7_INPUT_VOLTS)
    server = serve(port, bank)
    try:
        with rig_on(RIGS_DIR / "labjack-t7.toml", port, tmp_path) as rig:
            # 0.45 MPa on a 0–5 V ITV1051 (0–0.9 MPa) = 2.5 V = 0x40200000, high word first
            rig.cylinder_regulator.set_pressure(0.45)
            rig.muscle_supply.request(0.18)  # 1.0 V = 0x3f800000 on DAC1
            assert bank.get_holding_registers(1000, 4) == [0x4020, 0x0000, 0x3F80, 0x0000]
            report = rig.vent()
            assert report.ok
            assert report.cylinder.detail == (f"write acknowledged by tcp://127.0.0.1:{port}, "
                                              "register 1000 reads back 0")
            assert "register 1002 reads back 0" in report.muscle.detail
            assert bank.get_holding_registers(1000, 4) == [0, 0, 0, 0]
            # a DAC stuck at 2.5 V acknowledges the zero write: the read-back catches it
            real_get = bank.get_holding_registers

            def stuck(address, number=1, srv_info=None):
                regs = real_get(address, number, srv_info)
                return float_words(2.5) if address == 1000 and number == 2 else regs

            bank.get_holding_registers = stuck
            res = rig.cylinder_regulator.vent()
            assert res.outcome.value == "failed" and "reads back 2.5 instead of 0" in res.detail
    finally:
        server.stop()


def test_generic_int16_input_registers_signed_and_scaled(tmp_path, port):
    """generic-modbus.toml: FC4 input registers, INT16 counts × 0.0003125 V (10 V / 32000)."""
    bank = DataBank()
    counts = {0: 16000, 1: -800 & 0xFFFF, 2: 9600, 3: 3200}  # 5 V, −0.25 V, 3 V, 1 V
    for address, c in counts.items():
        bank.set_input_registers(address, [c])
    bank.set_holding_registers(100, [0, 0])
    server = serve(port, bank)
    try:
        with rig_on(RIGS_DIR / "generic-modbus.toml", port, tmp_path) as rig:
            v = rig.sampler.read_values()
            # by hand: x = −10 + 5.1 V − 0.01 V² at 5 V; F = 250 N/V at −0.25 V (compression)
            assert v["position"] == pytest.approx(-10 + 5.1 * 5 - 0.01 * 25, abs=1e-9)
            assert v["force"] == pytest.approx(-62.5, abs=1e-9)
            assert v["muscle_pressure"] == pytest.approx(0.5, abs=1e-12)
            assert v["cylinder_pressure"] == pytest.approx(0.0, abs=1e-12)
            # AO0 (holding 100, UINT16 counts of 0.3125 mV): 0.45 MPa = 5 V = 16000 counts
            rig.cylinder_regulator.set_pressure(0.45)
            assert bank.get_holding_registers(100, 1) == [16000]
            assert rig.vent().ok and bank.get_holding_registers(100, 2) == [0, 0]
    finally:
        server.stop()
