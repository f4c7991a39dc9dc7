"""Safety interlocks: refuse unsafe protocols before anything moves; check every sample.

Limits come from the rig (:class:`pmalab.rig.base.Limits`, read from the rig file):
muscle pressure ≤ 0.6 MPa (DMSP-20 rating), cylinder pressure ≤ the regulator's maximum,
|force| ≤ the load cell's range, position (contraction, mm) within the travel.

The runner calls :meth:`SafetyMonitor.check` on every sample; on a trip it vents the
cylinder regulator in the same sample period (before the next deadline), closes the run as
``aborted: <reason>`` and raises :class:`~pmalab.errors.SafetyAbort`.
"""

from __future__ import annotations

from dataclasses import dataclass

from pmalab.acquisition.protocol import Protocol
from pmalab.errors import ConfigError
from pmalab.rig.base import Limits, Rig


class ProtocolRefused(ConfigError):
    """A protocol would exceed a rig limit; it is refused before anything moves."""


def effective_limits(rig: Rig) -> Limits:
    """The rig's limits, with the cylinder limit capped at the regulator's own maximum."""
    lim = rig.limits
    reg_max = float(
        getattr(rig.cylinder_regulator, "max_pressure_MPa", lim.max_cylinder_pressure_MPa)
    )
    return Limits(
        max_muscle_pressure_MPa=float(lim.max_muscle_pressure_MPa),
        max_cylinder_pressure_MPa=min(float(lim.max_cylinder_pressure_MPa), reg_max),
        max_force_N=float(lim.max_force_N),
        min_position_mm=float(lim.min_position_mm),
        max_position_mm=float(lim.max_position_mm),
    )


def preflight(protocol: Protocol, rig: Rig) -> None:
    """Refuse (``ProtocolRefused``, one line) any run whose commands exceed a limit.

    Checked before the output file is created or any device is commanded.  The muscle's
    pressure and the cylinder command's peak (offset + amplitude) are known exactly from
    the protocol; force and position are only known once measured, so those are checked
    per sample.
    """
    lim = effective_limits(rig)
    where = protocol.path or protocol.name
    sampler = rig.sampler
    lo_hi = getattr(sampler, "rate_range_Hz", None)  # a sampler that programs its clock
    if lo_hi is not None and not lo_hi[0] <= protocol.sample_rate_Hz <= lo_hi[1]:
        raise ProtocolRefused(
            f"{where}: refused: field 'sample_rate_Hz' = {protocol.sample_rate_Hz:g} Hz is "
            f"outside the rig's {lo_hi[0]:g}–{lo_hi[1]:g} Hz"
        )
    if (
        lo_hi is None
        and sampler.hardware_timed
        and abs(sampler.sample_rate_Hz - protocol.sample_rate_Hz) > 1e-9
    ):
        raise ProtocolRefused(
            f"{where}: refused: field 'sample_rate_Hz' = {protocol.sample_rate_Hz:g} Hz but the "
            f"rig's hardware-timed sampler runs at {sampler.sample_rate_Hz:g} Hz"
        )
    for r in protocol.runs:
        if r.muscle_pressure_MPa > lim.max_muscle_pressure_MPa + 1e-9:
            raise ProtocolRefused(
                f"{where}: run '{r.name}': refused: field 'muscle_pressure_MPa' = "
                f"{r.muscle_pressure_MPa:g} MPa exceeds the rig's muscle limit "
                f"{lim.max_muscle_pressure_MPa:g} MPa"
            )
        if r.max_command_MPa > lim.max_cylinder_pressure_MPa + 1e-9:
            raise ProtocolRefused(
                f"{where}: run '{r.name}': refused: cylinder command peaks at "
                f"{r.max_command_MPa:g} MPa (offset + amplitude), above the limit "
                f"{lim.max_cylinder_pressure_MPa:g} MPa"
            )
        if r.min_command_MPa < -1e-9:
            raise ProtocolRefused(
                f"{where}: run '{r.name}': refused: cylinder command goes down to "
                f"{r.min_command_MPa:g} MPa (offset < amplitude)"
            )


@dataclass
class SafetyMonitor:
    """Per-sample limit check (plain float comparisons: it runs 500 times a second)."""

    limits: Limits
    #: measured pressures trip this fraction above their limit: a run at the rated
    #: 0.6 MPa reads 0.6 ± sensor noise, and a regulator overshoots a little when it
    #: settles; the protocol's *nominal* pressures are held to the limit exactly (preflight)
    pressure_margin: float = 0.05

    def __post_init__(self) -> None:
        self._muscle_trip = self.limits.max_muscle_pressure_MPa * (1 + self.pressure_margin)
        self._cyl_trip = self.limits.max_cylinder_pressure_MPa * (1 + self.pressure_margin)

    def check(self, position: float, force: float, muscle: float, cylinder: float) -> str | None:
        """Return the trip reason, or None when every channel is within its limit."""
        lim = self.limits
        # NaN compares false everywhere; a sensor returning NaN is a fault, so test for it
        if not (
            force == force and position == position and muscle == muscle and cylinder == cylinder
        ):
            return "sensor returned NaN (sample not stored)"
        if abs(force) > lim.max_force_N:
            return f"force {force:.1f} N beyond the load cell's range ±{lim.max_force_N:g} N"
        if position > lim.max_position_mm or position < lim.min_position_mm:
            return (
                f"position {position:.2f} mm outside the travel "
                f"[{lim.min_position_mm:g}, {lim.max_position_mm:g}] mm"
            )
        if muscle > self._muscle_trip:
            return (
                f"muscle pressure {muscle:.3f} MPa above the limit "
                f"{lim.max_muscle_pressure_MPa:g} MPa"
            )
        if cylinder > self._cyl_trip:
            return (
                f"cylinder pressure {cylinder:.3f} MPa above the limit "
                f"{lim.max_cylinder_pressure_MPa:g} MPa"
            )
        return None
