"""An identification's messages: typed at the source, sorted by their type.

The fitting code collects one list of messages per campaign and per run; most explain what
was done (a default fix, the joint refinement, the pressure orders kept), a few say
something is wrong (a parameter at its bound, an anti-physical loop, an optimizer that
stopped early, a diverged or extrapolated validation).  The CLI prints the first kind as
``note:`` (the method's details only with ``-v``) and the second in full as ``warning:``.

Each message is a :class:`Message`: its ``kind`` (``note``, ``detail`` or ``warning``), a
stable ``code`` and its ``data`` travel with the text, so nothing downstream parses a
sentence back.  A :class:`Message` *is* its text (a ``str``), so lists of messages still
read, print and serialise as sentences; a plain string (a message nobody typed) counts as
a warning — an unknown message is shown, never hidden.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

KINDS = ("note", "detail", "warning")


class Message(str):
    """A message: ``kind`` (one of :data:`KINDS`), ``code`` (stable, for programs),
    ``data`` (the numbers and names in it) and the text itself (the ``str`` value)."""

    kind: str
    code: str
    data: dict[str, Any]

    def __new__(cls, kind: str, code: str, text: str, **data: Any) -> Message:
        if kind not in KINDS:
            raise ValueError(f"message kind must be one of {KINDS}, not {kind!r}")
        m = super().__new__(cls, text)
        m.kind, m.code, m.data = kind, code, dict(data)
        return m

    @property
    def text(self) -> str:
        return str.__str__(self)

    def __reduce__(self) -> tuple[Any, ...]:  # pickles across worker processes
        return (_rebuild, (self.kind, self.code, self.text, self.data))

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (``identification.json``'s ``messages``)."""
        return {"kind": self.kind, "code": self.code, "text": self.text, "data": dict(self.data)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Message:
        return cls(str(d["kind"]), str(d["code"]), str(d["text"]), **dict(d.get("data") or {}))

    def same(self, other: object) -> bool:
        """Equal kind, code, text and data (``==`` compares the text only, as for str)."""
        return isinstance(other, Message) and self.to_dict() == other.to_dict()


def _rebuild(kind: str, code: str, text: str, data: dict[str, Any]) -> Message:
    return Message(kind, code, text, **data)


def note(code: str, text: str, **data: Any) -> Message:
    """Information the user should read (printed as ``note:``)."""
    return Message("note", code, text, **data)


def detail(code: str, text: str, **data: Any) -> Message:
    """A detail of the method (printed with ``-v`` only)."""
    return Message("detail", code, text, **data)


def warn(code: str, text: str, **data: Any) -> Message:
    """Something the user must look at (printed as ``warning:``)."""
    return Message("warning", code, text, **data)


def as_message(message: str) -> Message:
    """``message`` typed: itself, or a plain string as a warning (code ``untyped``)."""
    return message if isinstance(message, Message) else warn("untyped", str(message))


def read_messages(items: Iterable[Mapping[str, Any]]) -> list[Message]:
    """Messages from their JSON form (:meth:`Message.to_dict`)."""
    return [Message.from_dict(d) for d in items]


def prefixed(prefix: str, message: str) -> str:
    """``prefix + message``, keeping the message's kind, code and data when it is typed."""
    if isinstance(message, Message):
        return Message(message.kind, message.code, prefix + message.text, **message.data)
    return prefix + message


def kind_of(message: str) -> str:
    """The message's kind; a plain string is a warning."""
    return message.kind if isinstance(message, Message) else "warning"


def is_note(message: str) -> bool:
    """True when ``message`` is information (a note or a detail), not a warning."""
    return kind_of(message) in ("note", "detail")


def is_detail(message: str) -> bool:
    """True when ``message`` is a detail of the method (shown with ``-v``)."""
    return kind_of(message) == "detail"


#: collinear pairs named in the campaign warning line (the rest with -v)
MAX_PAIRS = 6


@dataclass
class Messages:
    """An identification's messages, sorted: ``notes`` and ``warnings`` (full text); the
    method's details and the per-run collinear pairs go to ``details`` (``-v``)."""

    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    #: per-run details shown with ``-v`` (collinear pairs, per-run notes)
    details: list[str] = field(default_factory=list)


def sort_messages(
    campaign: Iterable[str], runs: Sequence[tuple[str, Sequence[str], Sequence[str]]]
) -> Messages:
    """Sort campaign messages and per-run ``(label, warnings, notes)`` by their kind.

    Per-run collinearity (code ``collinear``) is one warning line for the campaign naming
    each pair and on how many runs it occurs; the per-run pairs go to ``details``.
    """
    out = Messages()
    held = []
    for m in campaign:
        code = m.code if isinstance(m, Message) else ""
        if code == "held-out":
            held.append(str(m.data["run"]))  # type: ignore[union-attr]
        elif is_detail(m):
            out.details.append(str(m))
        else:
            (out.notes if is_note(m) else out.warnings).append(str(m))
    if held:
        out.notes.insert(
            0,
            f"{len(held)} run(s) with role 'validation' in the run file held "
            f"out for validation: {', '.join(held)}",
        )
    pairs: Counter[tuple[str, str]] = Counter()
    runs_with: set[str] = set()
    limit = ""
    for label, warns, notes in runs:
        mine = []
        for w in warns:
            if isinstance(w, Message) and w.code == "collinear":
                a, b = str(w.data["a"]), str(w.data["b"])
                pairs[(a, b)] += 1
                runs_with.add(label)
                limit = f"{w.data['limit']:g}"
                mine.append(f"{a}/{b} {w.data['rho']:+.3f}")
            elif is_note(w):
                out.details.append(f"{label}: {w}")
            else:
                out.warnings.append(f"{label}: {w}")
        if mine:
            out.details.append(f"{label}: |rho| > {limit}: {', '.join(mine)}")
        out.details += [f"{label}: {n}" for n in notes]
    if pairs:
        common = pairs.most_common()
        listed = ", ".join(
            f"{a}/{b}" + (f" ({k} runs)" if k > 1 else " (1 run)")
            for (a, b), k in common[:MAX_PAIRS]
        )
        if len(common) > MAX_PAIRS:
            listed += f" and {len(common) - MAX_PAIRS} more pair(s)"
        out.warnings.append(
            f"parameters trade off (|rho| > {limit}) on {len(runs_with)} of {len(runs)} runs: "
            f"{listed}; their per-run values are poorly determined (-v lists them per run)"
        )
    return out
