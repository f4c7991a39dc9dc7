"""A proportional regulator simulated inside a physics object (rig or manipulator).

Commands land at the physics' current time (it is advanced to the clock first); a vent is
the command 0 MPa, confirmed because nothing between the software and the simulated valve
can lose it — unless setting the command itself fails, which is then reported as FAILED.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from pmalab.rig.base import Clock, PressureRegulator, VentResult


class _Advances(Protocol):
    def advance_to(self, t: float) -> None: ...


class SimulatedRegulator(PressureRegulator):
    """An ITV-class regulator whose output is a physics model's command (MPa gauge)."""

    def __init__(
        self,
        physics: _Advances,
        clock: Clock,
        max_pressure_MPa: float,
        command: Callable[[float], None],
    ) -> None:
        self.physics = physics
        self.clock = clock
        self.max_pressure_MPa = max_pressure_MPa
        self._command = command

    def set_pressure(self, mpa: float) -> None:
        self.physics.advance_to(self.clock.now())
        self._command(mpa)

    def vent(self) -> VentResult:
        try:
            self.physics.advance_to(self.clock.now())
        except Exception:  # a diverged integration must not stop the vent
            pass
        try:
            self._command(0.0)
        except Exception as exc:  # vent must never raise
            return VentResult.failed(f"simulated regulator: {exc}")
        return VentResult.confirmed("simulated regulator commanded to 0 MPa")
