"""The simulated rig behind the emulators, advanced to real time on every request.

The emulated devices (Modbus server, ITV, load-cell indicator) run on their own threads and
share one :class:`EmulatedPlant`; a lock serialises them.  Time is the wall clock since the
plant was created (``time.perf_counter``), so the physics sees exactly the timing the real
link produces — late requests, jitter and all.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from pmalab.rig.sim.physics import RigPhysics
from pmalab.rig.sim.truth import Truth


class EmulatedPlant:
    """Thread-safe :class:`RigPhysics` on wall-clock time (s since start)."""

    def __init__(self, truth: Truth | str | Path | None = None, seed: int = 0) -> None:
        self.physics = RigPhysics(truth, seed=seed)
        self.lock = threading.Lock()
        # compile/warm the physics kernels now, not on the first (timed) request
        self.physics.advance_and_sample(1e-4)
        self.physics.truth_state()
        self._t0 = time.perf_counter()
        self.requests = 0

    def now(self) -> float:
        return time.perf_counter() - self._t0

    def sample(self) -> dict[str, float]:
        """Advance to now and return the sensors' readings (s, mm, N, MPa, MPa)."""
        with self.lock:
            self.requests += 1
            out = self.physics.advance_and_sample(self.now())
            return {
                "time": float(out[0]),
                "position": float(out[1]),
                "force": float(out[2]),
                "muscle_pressure": float(out[3]),
                "cylinder_pressure": float(out[4]),
            }

    def command_cylinder(self, mpa: float) -> None:
        """The cylinder regulator's setpoint changed (MPa), effective now."""
        with self.lock:
            self.physics.advance_to(self.now())
            self.physics.set_cylinder_command(min(max(mpa, 0.0), self.physics.cylinder_max_MPa))

    def command_muscle(self, mpa: float) -> None:
        """The muscle regulator's setpoint changed (MPa), effective now."""
        with self.lock:
            self.physics.advance_to(self.now())
            self.physics.set_muscle_supply(min(max(mpa, 0.0), self.physics.muscle_max_MPa))

    def cylinder_pressure_true(self) -> float:
        """The regulator's actual output pressure (MPa), for the ITV's ``MON`` read-back."""
        with self.lock:
            self.physics.advance_to(self.now())
            return float(self.physics.truth_state()["cylinder_pressure"])
