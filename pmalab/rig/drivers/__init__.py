"""Real device drivers: transports (adapters) separate from devices, as in PyMeasure.

* :mod:`.adapters` — byte transports: TCP socket, serial port (pyserial);
* :mod:`.modbus_link` — Modbus TCP/RTU client (pymodbus framing) with bounded retry,
  reconnect and fault counters;
* :mod:`.modbus_daq` — analog inputs read in one block request per sample, analog-output
  regulators, muscle supplies, rate probe;
* :mod:`.itv_serial` — SMC ITV regulator over RS-232C (``SET n`` / ``MON``);
* :mod:`.loadcell_serial` — load-cell indicator streaming ASCII weight lines;
* :mod:`.calibration` — register encodings and raw → engineering-unit calibrations;
* :mod:`.rigfile` — ``kind = "modbus"`` rig files → a connected, checked :class:`Rig`;
* :mod:`.nidaqmx_rig` — ``kind = "nidaqmx"``: an NI DAQ card, hardware-timed analog input
  and analog-output regulators (on NI's ``nidaqmx`` package);
* :mod:`.testing` — recorded request/reply checking (``expected_protocol``).

Importing this package is cheap; pymodbus and pyserial load when a rig is built.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pmalab.rig.base import Clock, Rig


def make_modbus_rig(
    section: dict[str, Any],
    rig_file: Path | None = None,
    *,
    seed: int = 0,
    clock: Clock | None = None,
) -> Rig:
    """``RIG_KINDS["modbus"]``: build a rig of Modbus/serial devices from a ``[rig]`` table."""
    from pmalab.rig.drivers.rigfile import make_modbus_rig as make

    return make(section, rig_file, seed=seed, clock=clock)


def make_t7_stream_rig(
    section: dict[str, Any],
    rig_file: Path | None = None,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
) -> Rig:
    """``RIG_KINDS["labjack-t7-stream"]``: a LabJack T7 streaming over Modbus TCP."""
    from pmalab.rig.drivers.t7_stream import make_t7_stream_rig as make

    return make(section, rig_file, seed=seed, clock=clock)


def make_nidaq_rig(
    section: dict[str, Any],
    rig_file: Path | None = None,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
) -> Rig:
    """``RIG_KINDS["nidaqmx"]``: an NI-DAQmx device (imported only when such a rig is built)."""
    from pmalab.rig.drivers.nidaqmx_rig import make_nidaq_rig as make

    return make(section, rig_file, seed=seed, clock=clock)
