"""Safety interlocks: refuse unsafe protocols before anything moves; check every sample.

Limits come from the rig (:class:`pmalab.rig.base.Limits`, read from the rig file):
muscle pressure ≤ 0.6 MPa (DMSP-20 rating), cylinder pressure ≤ the regulator's maximum,
|force| ≤ the load cell's range, position (contraction, mm) within the travel.

The runner calls :meth:`SafetyMonitor.check` on every sample; on a trip it vents the
cylinder regulator in the same sample period (before the next deadline), closes the run as
``aborted: <reason>`` and raises :class:`~pmalab.errors.SafetyAbort`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from pmalab.acquisition.protocol import Protocol
from pmalab.channels import Channel
from pmalab.errors import ConfigError
from pmalab.rig.base import SINGLE_MUSCLE_CHANNELS, Limits, Rig, sampled


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
    muscles = rig.channels.muscles
    for r in protocol.runs:
        if r.static:
            if getattr(rig, "muscle_regulator", None) is None:
                name = rig.info.get("rig_file") or rig.info.get("kind") or "this rig"
                raise ProtocolRefused(
                    f"{where}: run '{r.name}': refused: an {r.test_type} run commands the "
                    f"muscle pressure, but rig '{name}' has no commanded muscle regulator "
                    "(channel 'muscle_pressure_command')"
                )
            if r.max_command_MPa > lim.max_muscle_pressure_MPa + 1e-9:
                raise ProtocolRefused(
                    f"{where}: run '{r.name}': refused: muscle pressure command peaks at "
                    f"{r.max_command_MPa:g} MPa (offset + amplitude), above the rig's muscle "
                    f"limit {lim.max_muscle_pressure_MPa:g} MPa"
                )
            continue
        if not getattr(rig, "has_cylinder", True):
            name = rig.info.get("rig_file") or rig.info.get("kind") or "this rig"
            raise ProtocolRefused(
                f"{where}: run '{r.name}': refused: an isobaric run drives a cylinder, but "
                f"rig '{name}' has none (channel 'cylinder_pressure_command'); give the run "
                'test_type = "isometric" or "isotonic"'
            )
        if len(muscles) > 1 and r.muscle not in muscles:
            raise ProtocolRefused(
                f"{where}: run '{r.name}': refused: field 'muscle' = {r.muscle!r}: the rig "
                f"has {len(muscles)} muscles, name the one held ({', '.join(muscles)})"
            )
        if len(muscles) <= 1 and r.muscle and r.muscle not in muscles:
            raise ProtocolRefused(
                f"{where}: run '{r.name}': refused: field 'muscle' = {r.muscle!r}, but the "
                "rig has one muscle (leave 'muscle' out)"
            )
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


def channel_limits(channel: Channel, limits: Limits) -> tuple[float, float]:
    """The (lo, hi) a channel is held to: its own declared limits where it has them, else
    the rig's :class:`~pmalab.rig.base.Limits` for its kind (force: the load cell's range
    both ways; position: the travel; a muscle's pressure: the muscle limit; a rig-wide
    pressure: the cylinder limit); (−inf, inf) for a kind the limits do not cover."""
    if channel.checked:
        return channel.lo, channel.hi
    kind = channel.kind
    if kind == "force":
        return -limits.max_force_N, limits.max_force_N
    if kind == "position":
        return limits.min_position_mm, limits.max_position_mm
    if kind == "pressure":
        hi = limits.max_muscle_pressure_MPa if channel.muscle else limits.max_cylinder_pressure_MPa
        return -math.inf, hi
    return -math.inf, math.inf


#: kinds in the order a sample is checked (the first trip names the reason)
_CHECK_ORDER = ("force", "position", "angle", "pressure")


def _pressure_role(c: Channel) -> str:
    """How a pressure channel is named in a trip reason."""
    if not c.muscle:
        return "cylinder pressure" if c.name == "cylinder_pressure" else c.label
    return "muscle pressure" if c.name == "muscle_pressure" else f"muscle pressure ({c.muscle})"


def _rule(c: Channel, i: int, lo: float, hi: float, margin: float) -> Callable[[float], str | None]:
    """A check of sample value ``v[i]`` against ``lo``..``hi``, worded for its kind."""
    if c.kind == "force":
        who = "force" if c.name == "force" else f"force ({c.muscle or c.label})"
        lim = max(abs(lo), abs(hi))
        return lambda f: (
            f"{who} {f:.1f} N beyond the load cell's range ±{lim:g} N" if abs(f) > lim else None
        )
    if c.kind == "pressure":
        trip = hi * (1 + margin)  # measured pressures get the margin for noise/overshoot
        who = _pressure_role(c)
        return lambda p: f"{who} {p:.3f} MPa above the limit {hi:g} MPa" if p > trip else None
    if c.kind == "position":
        who = "position" if c.name == "position" else f"position ({c.muscle or c.label})"
        return lambda x: (
            f"{who} {x:.2f} mm outside the travel [{lo:g}, {hi:g}] mm" if x > hi or x < lo else None
        )
    if not math.isfinite(lo):
        return lambda v: (
            f"{c.label} {v:.6g} {c.unit} above the limit {hi:g} {c.unit}" if v > hi else None
        )
    if not math.isfinite(hi):
        return lambda v: (
            f"{c.label} {v:.6g} {c.unit} below the limit {lo:g} {c.unit}" if v < lo else None
        )
    return lambda v: (
        f"{c.label} {v:.6g} {c.unit} outside [{lo:g}, {hi:g}] {c.unit}"
        if v > hi or v < lo
        else None
    )


@dataclass
class SafetyMonitor:
    """Per-sample limit check over the rig's declared sampled channels (plain float
    comparisons: it runs 500 times a second).

    ``channels``: the channels a sample holds, in order (default: the single-muscle
    rig's); each is held to :func:`channel_limits`.
    """

    limits: Limits
    #: measured pressures trip this fraction above their limit: a run at the rated
    #: 0.6 MPa reads 0.6 ± sensor noise, and a regulator overshoots a little when it
    #: settles; the protocol's *nominal* pressures are held to the limit exactly (preflight)
    pressure_margin: float = 0.05
    channels: Sequence[Channel] = field(
        default_factory=lambda: tuple(
            SINGLE_MUSCLE_CHANNELS[n] for n in sampled(SINGLE_MUSCLE_CHANNELS)
        )
    )

    def __post_init__(self) -> None:
        self._muscle_trip = self.limits.max_muscle_pressure_MPa * (1 + self.pressure_margin)
        self._cyl_trip = self.limits.max_cylinder_pressure_MPa * (1 + self.pressure_margin)
        rules = []
        for i, c in enumerate(self.channels):
            lo, hi = channel_limits(c, self.limits)
            if math.isfinite(lo) or math.isfinite(hi):
                order = _CHECK_ORDER.index(c.kind) if c.kind in _CHECK_ORDER else len(_CHECK_ORDER)
                rules.append((order, i, i, _rule(c, i, lo, hi, self.pressure_margin)))
        rules.sort(key=lambda r: (r[0], r[1]))
        self._rules = [(i, fn) for _, _, i, fn in rules]

        standard = tuple((c.name, c.lo, c.hi) for c in self.channels) == tuple(
            (n, -math.inf, math.inf) for n in sampled(SINGLE_MUSCLE_CHANNELS)
        )
        if standard:  # the single-muscle rig: the same checks, inline (500 times a second)
            self.check = self._check_single  # type: ignore[method-assign]

    def _check_single(self, values: Sequence[float]) -> str | None:
        """:meth:`check` for the single-muscle declaration (same reasons, no loop)."""
        position, force, muscle, cylinder = values
        lim = self.limits
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

    def check(self, values: Sequence[float]) -> str | None:
        """Return the trip reason, or None when every channel is within its limit."""
        # NaN compares false everywhere; a sensor returning NaN is a fault, so test for it
        for v in values:
            if v != v:
                return "sensor returned NaN (sample not stored)"
        for i, rule in self._rules:
            reason = rule(values[i])
            if reason is not None:
                return reason
        return None
