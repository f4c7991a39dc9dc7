"""Which runs diagnosis holds out — the same held-out data ``pmalab identify`` validates on.

In order of preference:

1. runs given with ``--validate`` and runs whose ``role`` attr is ``"validation"`` (exactly
   what ``pmalab identify`` holds out);
2. otherwise whole runs held out automatically at *interior* pressure levels (so the
   pressure laws interpolate, never extrapolate): at every interior level with two or more
   runs one run (alternating through the levels), else every other interior level —
   keeping at least three identification levels where the campaign has them.  The user
   reproduces the numbers with ``pmalab identify ... --hold-out RUN,...``;
3. a campaign too small for that (fewer than three pressure levels and one run per level):
   the last third of every run is held out (``RUN[held-out]``), the first two thirds fit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from pmalab.runfile import Run

#: fraction of each run fitted when runs are split in time
FIT_FRACTION = 2.0 / 3.0


@dataclass
class HeldOut:
    train: list[Run]
    held: list[Run]
    #: how the held-out runs were chosen (said in the JSON and the summary)
    scheme: str
    #: the identify option that reproduces this split (empty when none is needed)
    identify_hint: str = ""


def _levels(runs: Sequence[Run]) -> list[float]:
    return sorted({round(float(r.nominal_pressure), 3) for r in runs})


def choose(runs: Sequence[Run], validate: Sequence[Run] = ()) -> HeldOut:
    """Split ``runs`` (+ ``validate``) into identification and held-out runs (module doc)."""
    tagged = [r for r in runs if r.attrs.get("role") == "validation"]
    train = [r for r in runs if r.attrs.get("role") != "validation"]
    if tagged or validate:
        return HeldOut(
            train,
            [*tagged, *validate],
            "validation runs (--validate and runs with role 'validation')",
        )
    levels = _levels(train)
    by_level = {
        lv: [r for r in train if round(float(r.nominal_pressure), 3) == lv] for lv in levels
    }
    held: list[Run] = []
    if len(levels) >= 3:
        interior = levels[1:-1]
        multi = [lv for lv in interior if len(by_level[lv]) >= 2]
        if multi:
            for i, lv in enumerate(multi):
                group = sorted(by_level[lv], key=lambda r: (r.frequency or 0.0, r.label))
                held.append(group[i % len(group)])
        else:
            keep_levels = len(levels)
            for lv in interior[::2]:
                if keep_levels - 1 < 3:
                    break
                held += by_level[lv]
                keep_levels -= 1
    if held:
        ids = {id(r) for r in held}
        names = ",".join(r.name for r in held)
        return HeldOut(
            [r for r in train if id(r) not in ids],
            held,
            "whole runs held out at interior pressures",
            f"--hold-out {names}",
        )
    # too small a campaign: split every run in time
    fit, val = [], []
    for r in train:
        t0, t1 = float(r.time[0]), float(r.time[-1])
        cut = t0 + FIT_FRACTION * (t1 - t0)
        a = replace(r.window(0.0, cut - t0), name=f"{r.name}[fit]")
        b = replace(r.window(cut - t0, t1 - t0), name=f"{r.name}[held-out]")
        fit.append(a)
        val.append(b)
    return HeldOut(
        fit, val, "last third of every run held out (too few runs to hold out whole runs)"
    )
