"""The simulated device behind the fake: a muscle rig wired to analog channels.

A :class:`FakeDevice` holds pmalab's simulated rig physics and the wiring of its sensors
(value → volts, ``V = a·value + b``) and regulators (volts → MPa, ``MPa = a·V + b``).  A
stream samples the physics at ``t0 + k/rate`` on the device's own clock; a sample outside a
channel's range saturates like an ADC.  Faults are injected at a sample index:
``inject("overflow", at_sample=N)`` (the read that would pass sample N fails with −200279),
``inject("removed", at_sample=N)`` (from then on every call fails with −201003),
``inject("timeout", at_sample=N)`` (−200284).  ``install(device)`` makes it visible as
``device.name``.
"""

from __future__ import annotations

DEVICES: dict[str, FakeDevice] = {}


class FakeDevice:
    def __init__(self, name: str, physics, ai: dict[str, tuple[str, float, float]],
                 ao: dict[str, tuple[str, float, float]], max_rate: float = 250_000.0,
                 n_ai: int = 16, n_ao: int = 2, poll_dt: float = 0.01) -> None:
        self.name = name
        self.physics = physics
        self.ai = ai  # "ai0" -> (quantity, a, b): volts = a * value + b
        self.ao = ao  # "ao0" -> ("cylinder" | "muscle", a, b): MPa = a * volts + b
        self.max_rate = max_rate
        self.n_ai, self.n_ao = n_ai, n_ao
        self.t = 0.0  # the device's clock (s)
        self.poll_dt = poll_dt  # device time that passes per on-demand read
        self.faults: dict[str, int] = {}
        self.removed = False
        self.samples_streamed = 0
        self.ao_volts: dict[str, float] = {}
        self.calls: list[str] = []
        self._q = ("time", "position", "force", "muscle_pressure", "cylinder_pressure")

    def inject(self, kind: str, at_sample: int) -> None:
        assert kind in ("overflow", "removed", "timeout")
        self.faults[kind] = int(at_sample)

    def sample(self, t: float) -> dict[str, float]:
        out = self.physics.advance_and_sample(t)
        self.t = t
        return dict(zip(self._q, (float(v) for v in out[:5]), strict=True))

    def volts(self, chan: str, values: dict[str, float], lo: float, hi: float) -> float:
        q, a, b = self.ai[chan]
        return float(min(max(a * values[q] + b, lo), hi))

    def write_ao(self, chan: str, volts: float) -> None:
        target, a, b = self.ao[chan]
        self.ao_volts[chan] = volts
        mpa = max(a * volts + b, 0.0)
        self.physics.advance_to(self.t)
        if target == "cylinder":
            self.physics.set_cylinder_command(min(mpa, self.physics.cylinder_max_MPa))
        else:
            self.physics.set_muscle_supply(min(mpa, self.physics.muscle_max_MPa))


def install(device: FakeDevice) -> FakeDevice:
    DEVICES[device.name] = device
    return device


def uninstall() -> None:
    DEVICES.clear()
