"""Channels declared as data: what a rig measures and commands, one :class:`Channel` each.

A rig declares its channels (name, kind, unit, safety limits, which muscle); the sample
loop, the safety monitor, the recorder and the run file iterate that declaration instead
of naming fixed fields, so a second muscle or a new kind of sensor is a change of the rig
file and of its declaration only.

Kinds and their canonical units (docs/explanation/physics.md):

* ``time`` — s, the sample's timestamp on the rig's clock;
* ``position`` — mm, a muscle's contraction (positive = shorter than nominal);
* ``force`` — N, a muscle's tension (load cell in series);
* ``pressure`` — MPa gauge, measured (a muscle's, or the cylinder's when ``muscle`` is "");
* ``angle`` — deg, a joint angle (positive = towards the first muscle of a pair);
* ``command`` — MPa gauge, a regulator's setpoint as sent.

``muscle`` names the muscle a channel belongs to ("" for rig-wide channels: time, the
cylinder, a joint angle).  A single-muscle rig's muscle is :data:`SINGLE_MUSCLE`.

Run files (format version 2) store the declaration as the run group's ``channels`` attr
(JSON list of ``{name, kind, unit, muscle}``) and each dataset's ``kind``/``muscle``
attrs; version-1 files carry none and are read with :data:`STANDARD_CHANNELS`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from pmalab.errors import ConfigError

#: channel kind → canonical unit
KINDS: dict[str, str] = {
    "time": "s",
    "position": "mm",
    "force": "N",
    "pressure": "MPa",
    "angle": "deg",
    "command": "MPa",
    # a test stand's state code (1 = pressurising, 2 = venting): a number without unit
    "state": "1",
}
#: the muscle of a single-muscle rig (version-1 files)
SINGLE_MUSCLE = "muscle"


@dataclass(frozen=True)
class Channel:
    """One declared channel.

    ``lo``/``hi``: the values the runner tolerates (trip outside; ±inf: unchecked), in
    ``unit``.  ``label``: how messages name it (default: the name with spaces).
    """

    name: str
    kind: str
    unit: str = ""
    muscle: str = ""
    lo: float = -math.inf
    hi: float = math.inf
    label: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ConfigError(
                f"channel '{self.name}': unknown kind '{self.kind}' (known: {', '.join(KINDS)})"
            )
        if not self.unit:
            object.__setattr__(self, "unit", KINDS[self.kind])
        if not self.label:
            object.__setattr__(self, "label", self.name.replace("_", " "))

    @property
    def checked(self) -> bool:
        """True when the runner holds this channel to limits."""
        return math.isfinite(self.lo) or math.isfinite(self.hi)

    def limited(self, lo: float = -math.inf, hi: float = math.inf) -> Channel:
        """A copy with limits ``lo``..``hi`` (in the channel's unit)."""
        return replace(self, lo=float(lo), hi=float(hi))

    def as_attr(self) -> dict[str, str]:
        """What a run file declares about it (name, kind, unit, muscle)."""
        return {"name": self.name, "kind": self.kind, "unit": self.unit, "muscle": self.muscle}


def _std(name: str, kind: str, muscle: str = "") -> Channel:
    return Channel(name, kind, KINDS[kind], muscle)


#: the single-muscle isobaric rig's channels (and every version-1 file's), in the order
#: a sampler delivers them; the last is the runner's command, not a sampler's
STANDARD_CHANNELS: tuple[Channel, ...] = (
    _std("time", "time"),
    _std("position", "position", SINGLE_MUSCLE),
    _std("force", "force", SINGLE_MUSCLE),
    _std("muscle_pressure", "pressure", SINGLE_MUSCLE),
    _std("cylinder_pressure", "pressure"),
    _std("cylinder_pressure_command", "command"),
)
#: a static test stand's state column, kept by the import (not a rig's recorded channel)
BRANCH_CHANNEL = _std("branch", "state", SINGLE_MUSCLE)


class Channels(tuple[Channel, ...]):
    """An ordered, name-unique declaration of channels (a tuple with look-ups)."""

    def __new__(cls, items: Iterable[Channel] = ()) -> Channels:
        items = tuple(items)
        seen: set[str] = set()
        for c in items:
            if c.name in seen:
                raise ConfigError(f"channel '{c.name}' declared twice")
            seen.add(c.name)
        return super().__new__(cls, items)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self)

    def __getitem__(self, key: Any) -> Any:  # name or index
        if isinstance(key, str):
            for c in self:
                if c.name == key:
                    return c
            raise KeyError(key)
        return super().__getitem__(key)

    def get(self, name: str) -> Channel | None:
        return next((c for c in self if c.name == name), None)

    @property
    def muscles(self) -> tuple[str, ...]:
        """The muscles the channels belong to, in declaration order."""
        out: list[str] = []
        for c in self:
            if c.muscle and c.muscle not in out:
                out.append(c.muscle)
        return tuple(out)

    def of_kind(self, kind: str, muscle: str | None = None) -> tuple[Channel, ...]:
        """Channels of ``kind`` (of ``muscle`` when given; "" = rig-wide)."""
        return tuple(c for c in self if c.kind == kind and (muscle is None or c.muscle == muscle))

    def units(self) -> dict[str, str]:
        return {c.name: c.unit for c in self}

    def as_attr(self) -> str:
        """The run file's ``channels`` attr (JSON)."""
        return json.dumps([c.as_attr() for c in self])

    @classmethod
    def from_attr(cls, text: Any, where: str = "") -> Channels:
        """Parse a run file's ``channels`` attr; one-line :class:`ConfigError` on bad text."""
        try:
            if isinstance(text, bytes):  # stored as fixed-length UTF-8 text
                text = text.decode("utf-8")
            doc = json.loads(text) if isinstance(text, str) else text
            return cls(
                Channel(str(d["name"]), str(d["kind"]), str(d["unit"]), str(d.get("muscle", "")))
                for d in doc
            )
        except (TypeError, KeyError, ValueError) as exc:
            raise ConfigError(
                f"{where}: attr 'channels': not a channel declaration ({exc})"
            ) from None

    def single_muscle_view(self, muscle: str) -> dict[str, str]:
        """How ``muscle``'s channels map onto the single-muscle names a version-1 reader
        knows: ``{single-muscle name: declared name}`` (time, position, force,
        muscle_pressure; the cylinder's when the rig has one)."""
        view: dict[str, str] = {}
        for single, kind, owner in (
            ("time", "time", ""),
            ("position", "position", muscle),
            ("force", "force", muscle),
            ("muscle_pressure", "pressure", muscle),
            ("cylinder_pressure", "pressure", ""),
            ("cylinder_pressure_command", "command", ""),
        ):
            found = self.of_kind(kind, owner)
            if len(found) == 1:
                view[single] = found[0].name
        return view


def standard(limits: Sequence[tuple[str, float, float]] = ()) -> Channels:
    """The single-muscle declaration, with ``(name, lo, hi)`` limits applied."""
    lim = {n: (lo, hi) for n, lo, hi in limits}
    return Channels(c.limited(*lim[c.name]) if c.name in lim else c for c in STANDARD_CHANNELS)


def muscle_channels(muscle: str, *, command: bool = True) -> tuple[Channel, ...]:
    """The channels one muscle of a multi-muscle rig brings: contraction, tension, pressure
    and (``command``) its regulator's setpoint, named ``<quantity>_<muscle>``."""
    out = [
        Channel(f"position_{muscle}", "position", muscle=muscle),
        Channel(f"force_{muscle}", "force", muscle=muscle),
        Channel(f"muscle_pressure_{muscle}", "pressure", muscle=muscle),
    ]
    if command:
        out.append(Channel(f"muscle_pressure_command_{muscle}", "command", muscle=muscle))
    return tuple(out)


__all__ = [
    "BRANCH_CHANNEL",
    "KINDS",
    "SINGLE_MUSCLE",
    "STANDARD_CHANNELS",
    "Channel",
    "Channels",
    "muscle_channels",
    "standard",
]
