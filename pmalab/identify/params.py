"""Model parameters with bounds, units and (after a fit) standard errors.

Modelled on lmfit's ``Parameter``: a fit varies ``value`` inside ``[lo, hi]`` unless
``vary`` is False; ``stderr`` is filled in from the Jacobian at the optimum.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace


@dataclass
class Param:
    """One scalar parameter of a force law."""

    name: str
    value: float
    lo: float = -float("inf")
    hi: float = float("inf")
    unit: str = ""
    vary: bool = True
    doc: str = ""
    stderr: float | None = None

    def clipped(self, value: float | None = None) -> Param:
        """A copy with ``value`` (default: own value) clipped into the bounds."""
        v = self.value if value is None else value
        return replace(self, value=min(max(float(v), self.lo), self.hi))


class Params:
    """An ordered set of :class:`Param`, addressable by name."""

    def __init__(self, params: Iterable[Param] = ()) -> None:
        self._p: dict[str, Param] = {}
        for p in params:
            self.add(p)

    def add(self, p: Param) -> None:
        if p.name in self._p:
            raise ValueError(f"duplicate parameter name {p.name!r}")
        self._p[p.name] = p

    def __getitem__(self, name: str) -> Param:
        return self._p[name]

    def __contains__(self, name: object) -> bool:
        return name in self._p

    def __iter__(self) -> Iterator[Param]:
        return iter(self._p.values())

    def __len__(self) -> int:
        return len(self._p)

    def names(self) -> list[str]:
        return list(self._p)

    def values(self) -> dict[str, float]:
        """``{name: value}`` — what a force law's ``theta`` is."""
        return {n: p.value for n, p in self._p.items()}

    def free(self) -> list[Param]:
        return [p for p in self._p.values() if p.vary]

    def copy(self) -> Params:
        return Params(replace(p) for p in self._p.values())

    def __repr__(self) -> str:
        inner = ", ".join(f"{p.name}={p.value:.4g}" for p in self._p.values())
        return f"Params({inner})"
