"""An independent Modbus TCP server (pyModbusTCP, from the package index) for driver tests.

pmalab's own emulator and drivers share register codecs and calibrations, so a bug mirrored
in both would pass every emulator test.  This server shares nothing with pmalab: its
registers are filled with ``struct`` directly from the volts a test chooses, so the drivers'
decoding, scaling and word order are checked against an implementation nobody here wrote.

``python tests/independent_modbus.py PORT`` serves the LabJack T7 map of
``data/rigs/labjack-t7.toml`` (FC3 FLOAT32 volts, high word first) until killed; the tests
also start it in-process with :func:`serve`.
"""

from __future__ import annotations

import struct
import sys
import time

from pyModbusTCP.server import DataBank, ModbusServer

#: the T7 map's analog inputs: channel → (address, volts served)
#: muscle 2.2 V = 0.3 MPa, cylinder 1.0 V = 0 MPa, position 5.0 V = 15 mm, force 2.0 V = 500 N
T7_INPUT_VOLTS = {"muscle_pressure": (0, 2.2), "cylinder_pressure": (2, 1.0),
                  "position": (4, 5.0), "force": (6, 2.0)}
#: the T7 map's DAC registers (cylinder, muscle regulators)
T7_DACS = (1000, 1002)


def float_words(value: float, word_order: str = "big") -> list[int]:
    """IEEE-754 FLOAT32 as two 16-bit registers; ``big``: the high word first."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", value))
    return [hi, lo] if word_order == "big" else [lo, hi]


def words_float(words: list[int], word_order: str = "big") -> float:
    """The inverse of :func:`float_words`."""
    hi, lo = words if word_order == "big" else words[::-1]
    return struct.unpack(">f", struct.pack(">HH", hi, lo))[0]


def t7_bank(volts: dict[str, tuple[int, float]] | None = None, word_order: str = "big") -> DataBank:
    """A data bank holding the T7 map: inputs as FLOAT32 holding registers, DACs at 0 V."""
    bank = DataBank()
    for address, v in (volts or T7_INPUT_VOLTS).values():
        bank.set_holding_registers(address, float_words(v, word_order))
    for address in T7_DACS:
        bank.set_holding_registers(address, float_words(0.0, word_order))
    return bank


def serve(port: int, bank: DataBank, host: str = "127.0.0.1") -> ModbusServer:
    """Start a pyModbusTCP server on ``host:port`` in background threads."""
    server = ModbusServer(host=host, port=port, no_block=True, data_bank=bank)
    server.start()
    return server


if __name__ == "__main__":  # a separate process for the kill -9 test
    srv = serve(int(sys.argv[1]), t7_bank())
    print("serving", flush=True)
    while True:
        time.sleep(1.0)
