"""Limit margins for the live view: how far each channel is from tripping the interlock.

The thresholds are those of :class:`pmalab.acquisition.safety.SafetyMonitor` (force: the
load cell's range, |F|; position: the travel, both ends; pressures: the limit plus the
monitor's margin for sensor noise).  A margin is ``threshold − reading`` in the channel's
unit (N, mm, MPa): 0 means the next such sample aborts the run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmalab.acquisition.safety import SafetyMonitor

#: SafetyMonitor's default: measured pressures trip this fraction above their limit
PRESSURE_MARGIN: float = SafetyMonitor.pressure_margin


@dataclass
class Margins:
    """Running margins of one run (reset per run)."""

    max_force_N: float
    min_position_mm: float
    max_position_mm: float
    muscle_trip_MPa: float
    cylinder_trip_MPa: float

    def __post_init__(self) -> None:
        self.reset()

    @classmethod
    def from_limits(
        cls, limits: dict[str, Any], pressure_margin: float = PRESSURE_MARGIN
    ) -> Margins | None:
        """From ``Limits.__dict__`` (the run file's ``limits`` attr); None when incomplete."""
        try:
            return cls(
                float(limits["max_force_N"]),
                float(limits["min_position_mm"]),
                float(limits["max_position_mm"]),
                float(limits["max_muscle_pressure_MPa"]) * (1 + pressure_margin),
                float(limits["max_cylinder_pressure_MPa"]) * (1 + pressure_margin),
            )
        except (KeyError, TypeError, ValueError):
            return None

    def reset(self) -> None:
        self.last: dict[str, float] = {}
        self.lowest: dict[str, float] = {}

    def update(self, x: np.ndarray, f: np.ndarray, pm: np.ndarray, pc: np.ndarray) -> None:
        """Fold in a batch of samples (every sample, not the decimated display points)."""
        if not len(x):
            return
        pos = np.minimum(self.max_position_mm - x, x - self.min_position_mm)
        now = {
            "force": self.max_force_N - np.abs(f),
            "position": pos,
            "muscle_pressure": self.muscle_trip_MPa - pm,
            "cylinder_pressure": self.cylinder_trip_MPa - pc,
        }
        for k, m in now.items():
            self.last[k] = float(m[-1])
            low = float(np.min(m))
            self.lowest[k] = min(self.lowest.get(k, math.inf), low)
        self._reading = {
            "force": float(f[-1]),
            "position": float(x[-1]),
            "muscle_pressure": float(pm[-1]),
            "cylinder_pressure": float(pc[-1]),
        }

    def rows(self) -> list[dict[str, Any]]:
        """One row per channel for the page: reading, threshold, margin now and lowest."""
        if not self.last:
            return []
        spec = {
            "force": ("N", f"|F| ≤ {self.max_force_N:g}", self.max_force_N),
            "position": (
                "mm",
                f"{self.min_position_mm:g} … {self.max_position_mm:g}",
                (self.max_position_mm - self.min_position_mm) / 2,
            ),
            "muscle_pressure": ("MPa", f"≤ {self.muscle_trip_MPa:.3g}", self.muscle_trip_MPa),
            "cylinder_pressure": ("MPa", f"≤ {self.cylinder_trip_MPa:.3g}", self.cylinder_trip_MPa),
        }
        out = []
        for k, (unit, trip, span) in spec.items():
            used = 1.0 - self.last[k] / span if span > 0 else 0.0
            out.append(
                {
                    "channel": k,
                    "unit": unit,
                    "trip": trip,
                    "reading": self._reading[k],
                    "margin": self.last[k],
                    "lowest": self.lowest[k],
                    "used": max(0.0, min(1.0, used)),
                }
            )
        return out
