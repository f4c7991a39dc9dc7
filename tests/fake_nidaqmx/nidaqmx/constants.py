"""nidaqmx.constants (the members pmalab uses, with NI's values)."""

from enum import Enum

READ_ALL_AVAILABLE = -1


class TerminalConfiguration(Enum):
    DEFAULT = -1
    RSE = 10083
    NRSE = 10078
    DIFF = 10106
    PSEUDO_DIFF = 12529


class AcquisitionType(Enum):
    FINITE = 10178
    CONTINUOUS = 10123
    HW_TIMED_SINGLE_POINT = 12522


class Edge(Enum):
    RISING = 10280
    FALLING = 10171


class VoltageUnits(Enum):
    VOLTS = 10348
    FROM_CUSTOM_SCALE = 10065
