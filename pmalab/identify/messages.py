"""Sorting an identification's messages into information (``note:``) and real warnings.

The fitting code collects one list of messages per campaign and per run; most campaign
messages explain what was done (a default fix, the joint refinement, the pressure orders
kept), a few say something is wrong (a parameter at its bound, an anti-physical loop, an
optimizer that stopped early, a diverged or extrapolated validation).  The CLI prints the
first kind as ``note:`` and the second in full as ``warning:``.

:data:`NOTE_PATTERNS` is the registry of information messages; anything it does not match
is a warning (an unknown message is shown, never hidden).  :func:`cli_text` rewrites the
Python spelling of a hint (``free=['n']``) into the CLI flag (``--free n``).
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

#: messages that describe what was done (information), matched anywhere in the message;
#: ``True``: a detail of the method, printed with ``-v`` only
NOTE_PATTERNS: tuple[tuple[re.Pattern[str], bool], ...] = tuple(
    (re.compile(p), detail) for p, detail in (
        (r"^\w+ fixed at \S+ \(default\)", False),                # the law's default fixes
        (r"^pressure laws refined jointly", False),                # joint refinement done
        (r"^force tared on each predicted run", False),            # drifting-zero effect
        (r"role 'validation' in the run file, held out", False),   # held-out runs
        (r"^joint fit: (kept|pressure order)", True),              # order pruning decisions
        (r"^\w+: pressure order \d", True),                        # order chosen by BIC
        (r"^\w+: poorly determined per run", True),                # joint fit from the median
        (r"only because c0 is extrapolated to x = 0", True),       # parametrisation artefact
        (r"not identifiable on this run; fixed \w+ = ", True),     # an automatic, safe fix
        (r"fixed at \S+ on every run for consistent", True),       # consistency refit
        (r"^\w+ fixed at \S+ on all runs: collinear", False),      # ... and its campaign line
    ))

HELD_OUT = re.compile(r"^(.*): role 'validation' in the run file, held out for validation$")

#: a per-run collinearity message: ``rho(a,b)=+0.998: |rho| > 0.95; these parameters trade off``
COLLINEAR = re.compile(r"^rho\((\w+),(\w+)\)=([+-]?[\d.]+): \|rho\| > ([\d.]+); "
                       r"these parameters trade off$")

#: collinear pairs named in the campaign warning line (the rest with -v)
MAX_PAIRS = 6

_PY_FREE = re.compile(r"free=\[([^\]]*)\]")


def is_note(message: str) -> bool:
    """True when ``message`` is information, not a warning (see :data:`NOTE_PATTERNS`)."""
    return any(p.search(message) for p, _ in NOTE_PATTERNS)


def is_detail(message: str) -> bool:
    """True when ``message`` is information on the method's details (shown with ``-v``)."""
    return any(detail and p.search(message) for p, detail in NOTE_PATTERNS)


def cli_text(message: str) -> str:
    """The message as a CLI user reads it: ``free=['n']`` → ``--free n``."""
    def flag(m: re.Match[str]) -> str:
        names = [s.strip().strip("'\"") for s in m.group(1).split(",") if s.strip()]
        return " ".join(f"--free {n}" for n in names)

    return _PY_FREE.sub(flag, message)


@dataclass
class Messages:
    """An identification's messages, sorted: ``notes`` and ``warnings`` (full text); the
    method's details and the per-run collinear pairs go to ``details`` (``-v``)."""

    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    #: per-run details shown with ``-v`` (collinear pairs, per-run notes)
    details: list[str] = field(default_factory=list)


def sort_messages(campaign: Iterable[str], runs: Sequence[tuple[str, Sequence[str],
                                                                 Sequence[str]]]) -> Messages:
    """Sort campaign messages and per-run ``(label, warnings, notes)`` into notes/warnings.

    Per-run collinearity (|ρ| above the limit) is one warning line for the campaign naming
    each pair and on how many runs it occurs; the per-run pairs go to ``details``.
    """
    out = Messages()
    held = []
    for m in campaign:
        h = HELD_OUT.match(m)
        if h:
            held.append(h.group(1))
        elif is_detail(m):
            out.details.append(cli_text(m))
        else:
            (out.notes if is_note(m) else out.warnings).append(cli_text(m))
    if held:
        out.notes.insert(0, f"{len(held)} run(s) with role 'validation' in the run file held "
                            f"out for validation: {', '.join(held)}")
    pairs: Counter[tuple[str, str]] = Counter()
    runs_with: set[str] = set()
    limit = ""
    for label, warns, notes in runs:
        mine = []
        for w in warns:
            c = COLLINEAR.match(w)
            if c:
                pairs[(c.group(1), c.group(2))] += 1
                runs_with.add(label)
                limit = c.group(4)
                mine.append(f"{c.group(1)}/{c.group(2)} {c.group(3)}")
            elif is_note(w):
                out.details.append(f"{label}: {cli_text(w)}")
            else:
                out.warnings.append(f"{label}: {cli_text(w)}")
        if mine:
            out.details.append(f"{label}: |rho| > {limit}: {', '.join(mine)}")
        out.details += [f"{label}: {cli_text(n)}" for n in notes]
    if pairs:
        common = pairs.most_common()
        listed = ", ".join(f"{a}/{b}" + (f" ({k} runs)" if k > 1 else " (1 run)")
                           for (a, b), k in common[:MAX_PAIRS])
        if len(common) > MAX_PAIRS:
            listed += f" and {len(common) - MAX_PAIRS} more pair(s)"
        out.warnings.append(
            f"parameters trade off (|rho| > {limit}) on {len(runs_with)} of {len(runs)} runs: "
            f"{listed}; their per-run values are poorly determined (-v lists them per run)")
    return out
