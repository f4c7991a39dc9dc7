"""One registration mechanism for everything a user picks by name: hysteresis laws, effects,
controllers and rig kinds.

Each item declares its own id, title and order where it is defined (a class attribute, or
the one ``register`` line of a rig backend); the registry keeps them in that order and
answers an unknown id with one line listing the valid ones.  A :class:`Registry` is a
read-only mapping id → item, so ``"bouc-wen" in LAWS``, ``LAWS["duhem"]`` and
``", ".join(LAWS)`` work as with a dict.  The conformance tests iterate every registry, so
a new law, effect, controller or rig kind is tested the moment its file exists.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

from pmalab.errors import PmalabError

T = TypeVar("T")


@dataclass(frozen=True)
class Entry(Generic[T]):
    id: str
    item: T
    title: str
    order: float
    seq: int


class Registry(Mapping[str, T]):
    """Items by id, in their declared order (then registration order)."""

    def __init__(self, kind: str, error: type[PmalabError] = PmalabError) -> None:
        #: what the items are, for messages ("law", "effect", "controller", "rig kind")
        self.kind = kind
        self.error = error
        self._entries: dict[str, Entry[T]] = {}
        self._seq = 0

    def register(
        self, id: str, item: T, *, title: str = "", order: float = 100.0, replace: bool = False
    ) -> T:
        """Add ``item`` under ``id``; a second item with the same id is refused unless
        ``replace`` (a user's file must not silently shadow a built-in)."""
        if not isinstance(id, str) or not id:
            raise self.error(f"{self.kind}: an id must be a non-empty text, got {id!r}")
        if id in self._entries and not replace and self._entries[id].item is not item:
            raise self.error(
                f"{self.kind} '{id}' is already registered ({self._entries[id].item!r})"
            )
        self._seq += 1
        self._entries[id] = Entry(id, item, title, float(order), self._seq)
        return item

    def unregister(self, id: str) -> None:
        """Remove ``id`` (tests that register a throwaway item clean up with this)."""
        self._entries.pop(id, None)

    def pop(self, id: str, default: T | None = None) -> T | None:
        e = self._entries.pop(id, None)
        return default if e is None else e.item

    def title(self, id: str) -> str:
        return self._entries[id].title

    def lookup(self, id: str) -> T:
        """The item, or one line naming the valid ids."""
        try:
            return self._entries[id].item
        except KeyError:
            raise self.error(
                f"unknown {self.kind} '{id}' (choose from {', '.join(self)})"
            ) from None

    # Mapping
    def __getitem__(self, id: str) -> T:
        return self._entries[id].item

    def __iter__(self) -> Iterator[str]:
        return iter(e.id for e in sorted(self._entries.values(), key=lambda e: (e.order, e.seq)))

    def __len__(self) -> int:
        return len(self._entries)

    def __setitem__(self, id: str, item: T) -> None:  # RIG_KINDS["x"] = factory
        self.register(id, item)

    def __repr__(self) -> str:
        return f"Registry({self.kind}: {', '.join(self)})"


def declared_ids(folder: Path, key: str = "name") -> list[str]:
    """The ids the classes in ``folder``'s modules declare (``key = "..."`` beside an
    ``order = N`` in a class body), in their declared order — what the registry filled from
    those modules will hold, read from the source without importing it, so a help text
    can name them without loading the numerical libraries the modules need."""
    found: list[tuple[float, str]] = []
    for path in sorted(folder.glob("*.py")):
        try:
            tree = ast.parse(path.read_text(encoding="utf-8"))
        except (OSError, SyntaxError, UnicodeDecodeError):
            continue
        for node in ast.walk(tree):
            if not isinstance(node, ast.ClassDef):
                continue
            values: dict[str, object] = {}
            for st in node.body:
                if (
                    isinstance(st, ast.Assign)
                    and len(st.targets) == 1
                    and isinstance(st.targets[0], ast.Name)
                    and isinstance(st.value, ast.Constant)
                ):
                    values[st.targets[0].id] = st.value.value
            ident, order = values.get(key), values.get("order")
            if isinstance(ident, str) and isinstance(order, int | float):
                found.append((float(order), ident))
    return list(dict.fromkeys(i for _, i in sorted(found)))
