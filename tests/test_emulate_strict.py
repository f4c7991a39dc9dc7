"""The Modbus emulator answers malformed requests as a device does, checked with an
independent client (pyModbusTCP) that sends raw PDUs and sees the raw reply frames."""

from __future__ import annotations

import logging
import struct

import pytest
from pty_support import needs_pty
from pyModbusTCP.client import ModbusClient

from pmalab.errors import RigError
from pmalab.paths import RIGS_DIR
from pmalab.rig.drivers.adapters import SerialAdapter
from pmalab.rig.drivers.modbus_link import FC_READ_INPUT, ModbusLink
from pmalab.rig.emulators.launcher import start_emulators


class RawClient(ModbusClient):
    """pyModbusTCP client that keeps the PDU of the last reply frame (MBAP stripped)."""

    last_reply: bytes = b""

    def on_tx_rx(self, frame: bytes, is_tx: bool) -> None:
        if not is_tx:
            self.last_reply = bytes(frame[7:])

    def ask(self, pdu: bytes) -> bytes:
        self.last_reply = b""
        self.custom_request(pdu)
        return self.last_reply


@pytest.fixture(scope="module")
def t7():
    with start_emulators(RIGS_DIR / "labjack-t7.toml", tcp_port=0, make_links=False) as emus:
        yield emus


@pytest.fixture
def client(t7):
    c = RawClient(port=t7.modbus.port, timeout=2.0)
    yield c
    c.close()


def fc16(address: int, words: list[int]) -> bytes:
    return struct.pack(f">BHHB{len(words)}H", 16, address, len(words), 2 * len(words), *words)


def f32(v: float) -> list[int]:
    return list(struct.unpack(">HH", struct.pack(">f", v)))  # high word first (T7)


# one row per malformed request: the reply PDU a device gives (function | 0x80, code)
CASES = [
    ("FC3 0 registers", struct.pack(">BHH", 3, 0, 0), "83 03"),
    ("FC3 126 registers", struct.pack(">BHH", 3, 0, 126), "83 03"),
    ("FC4 0 registers", struct.pack(">BHH", 4, 0, 0), "84 03"),
    ("FC4 126 registers", struct.pack(">BHH", 4, 0, 126), "84 03"),
    ("FC3 unmapped", struct.pack(">BHH", 3, 200, 2), "83 02"),
    ("FC16 to a read-only input (AIN0)", fc16(0, f32(1.0)), "90 02"),
    ("FC16 half a FLOAT32 (DAC0 high word)", fc16(1000, f32(1.0)[:1]), "90 02"),
    ("FC16 misaligned FLOAT32 (from 1001)", fc16(1001, f32(1.0)), "90 02"),
    ("FC6 half a FLOAT32", struct.pack(">BHH", 6, 1000, 0x4000), "86 02"),
    ("FC16 DAC0 6 V (> 5 V)", fc16(1000, f32(6.0)), "90 03"),
    ("FC16 DAC0 -0.5 V", fc16(1000, f32(-0.5)), "90 03"),
    ("FC16 DAC0 NaN", fc16(1000, f32(float("nan"))), "90 03"),
    ("FC16 DAC1 +inf", fc16(1002, f32(float("inf"))), "90 03"),
    ("FC16 DAC0 ok + DAC1 7 V (all or nothing)", fc16(1000, f32(1.0) + f32(7.0)), "90 03"),
    ("FC1 unmapped", struct.pack(">BHH", 1, 5000, 1), "81 02"),
    ("FC2 unmapped", struct.pack(">BHH", 2, 5000, 1), "82 02"),
    ("FC1 on a register address (no coils)", struct.pack(">BHH", 1, 0, 1), "81 02"),
]


@pytest.mark.parametrize("name, pdu, reply", CASES, ids=[c[0] for c in CASES])
def test_malformed_requests_get_the_devices_exception(t7, client, name, pdu, reply, caplog, capfd):
    caplog.set_level(logging.DEBUG)
    assert client.ask(pdu).hex(" ") == reply
    # nothing was commanded: both DACs still read back 0 V and the plant holds 0 MPa
    assert client.read_holding_registers(1000, 4) == [0, 0, 0, 0]
    assert t7.plant.physics.cylinder_command == 0.0 and t7.plant.physics.muscle_supply == 0.0
    # a device answers; it does not print tracebacks
    assert "Traceback" not in caplog.text and "Traceback" not in capfd.readouterr().err


def test_valid_requests_still_work(t7, client):
    assert client.ask(fc16(1000, f32(2.5))).hex(" ") == "10 03 e8 00 02"
    assert client.read_holding_registers(1000, 2) == f32(2.5)
    assert t7.plant.physics.cylinder_command == pytest.approx(0.45, abs=0.9 / 1023)
    assert client.ask(fc16(1000, f32(0.0))).hex(" ") == "10 03 e8 00 02"
    regs = client.read_holding_registers(0, 8)  # the four AINs, FLOAT32 volts
    volts = [struct.unpack(">f", struct.pack(">HH", *regs[i:i + 2]))[0] for i in (0, 2, 4, 6)]
    assert 0.8 < volts[0] < 5.2 and 0.8 < volts[1] < 5.2  # 1–5 V pressure sensors
    # 125 registers is a legal count: refused only because 8…124 are not mapped (02, not 03)
    assert client.ask(struct.pack(">BHH", 3, 0, 125)).hex(" ") == "83 02"


@needs_pty
def test_rtu_emulator_answers_only_its_device_id():
    with start_emulators(RIGS_DIR / "generic-modbus-rtu.toml", make_links=False,
                         baud_pacing=False) as emus:
        spec = emus.rig_spec()
        assert spec.transport.device_id == 1

        def link(unit: int) -> ModbusLink:
            lk = ModbusLink(SerialAdapter(str(spec.transport.port), spec.transport.baudrate),
                            "rtu", unit, timeout=0.1, retries=0)
            lk.connect()
            return lk

        mine = link(1)
        try:
            assert len(mine.read_registers(0, 4, FC_READ_INPUT)) == 4
        finally:
            mine.close()
        other = link(2)
        try:
            with pytest.raises(RigError, match="no reply"):
                other.read_registers(0, 4, FC_READ_INPUT)
            assert other.stats.timeouts == 1 and other.stats.exception_replies == 0
        finally:
            other.close()
