"""The parameter trajectory of a long record (identification.json ``trajectory``): each
parameter against the cycle count with its windows' standard errors and the trend line,
and the same as a table."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from pmalab.reports import style
from pmalab.reports.figures_parameters import _fmt, _table, unit_of

#: error bars: ± this many standard errors (≈ 95 % for a normal estimate)
ERR_K = 2.0


def _plotted(tr: Mapping[str, Any], fixed: Sequence[str] = ()) -> list[str]:
    """The parameters with a value in some window, the fixed ones left out."""
    ok = [w for w in tr.get("windows", []) if w.get("status") == "ok"]
    names = [n for n in tr.get("parameters", []) if n not in fixed]
    return [n for n in names if any(n in (w.get("parameters") or {}) for w in ok)]


@style.styled
def trajectory_figure(
    tr: Mapping[str, Any],
    *,
    units: Mapping[str, str] | None = None,
    fixed: Sequence[str] = (),
    title: str = "Parameter trajectory along the record",
) -> Figure:
    """One panel per parameter: the window fits (± 2 standard errors) against the cycle
    count at each window's middle, the weighted trend line, its drift in the panel title;
    a top axis in hours of the record."""
    fig = style.new_figure(title)
    # a strip at the bottom for the note under the panels
    engine = fig.get_layout_engine()
    if engine is not None:
        engine.set(rect=(0.0, 0.06, 1.0, 0.94))  # type: ignore[call-arg]
    names = _plotted(tr, fixed)[:6]
    ok = [w for w in tr.get("windows", []) if w.get("status") == "ok"]
    failed = len(tr.get("windows", [])) - len(ok)
    nrows, ncols = style.grid_shape(len(names))
    axes = style.panel_axes(fig, len(names), nrows, ncols)
    cyc = np.array([0.5 * (w["cycle_start"] + w["cycle_end"]) for w in ok], dtype=float)
    hours = np.array([w["time_s"] for w in ok], dtype=float) / 3600.0
    f = float(tr.get("frequency_Hz") or 0.0)
    for ax, n in zip(axes, names):
        y = np.array([(w["parameters"] or {}).get(n, np.nan) for w in ok], dtype=float)
        se = np.array(
            [np.nan if (w.get("stderr") or {}).get(n) is None else w["stderr"][n] for w in ok],
            dtype=float,
        )
        ax.errorbar(
            cyc,
            y,
            yerr=np.where(np.isfinite(se), ERR_K * se, 0.0),
            fmt="o",
            ms=3.5,
            color=style.MODEL,
            ecolor="0.55",
            elinewidth=0.8,
            capsize=2,
            label=f"window fit ± {ERR_K:g} s.e.",
        )
        t = (tr.get("trend") or {}).get(n) or {}
        unit = unit_of(n, units)
        head = n
        if t.get("start") is not None and t.get("per_hour") is not None and hours.size:
            line = t["start"] + t["per_hour"] * hours
            ax.plot(cyc, line, "-", color=style.VALIDATION, lw=1.2, label="trend (weighted line)")
            pct = t.get("percent_per_hour")
            se_h = t.get("per_hour_stderr")
            head += (
                f": {t['per_hour']:+.3g} ± {se_h:.2g} {unit}/h".replace(" /h", "/h")
                if se_h is not None
                else f": {t['per_hour']:+.3g} {unit}/h"
            )
            if pct is not None:
                head += f" ({pct:+.1f} %/h)" if abs(pct) >= 0.95 else f" ({pct:+.2g} %/h)"
        ax.set_title(head, fontsize=9)
        ax.set_xlabel("Cycle count")
        ax.set_ylabel(f"{n} ({unit})" if unit else n)
        ax.margins(x=0.03)
        if f > 0 and cyc.size:
            per_h = 3600.0 * f  # cycles per hour of record

            def to_h(c: Any, k: float = per_h) -> Any:
                return np.asarray(c, dtype=float) / k

            def to_c(h: Any, k: float = per_h) -> Any:
                return np.asarray(h, dtype=float) * k

            top = ax.secondary_xaxis("top", functions=(to_h, to_c))
            top.set_xlabel("Record time (h)", fontsize=8)
            top.tick_params(labelsize=8)
    if axes:
        axes[0].legend(loc="best", fontsize=8)
    note = (
        f"{tr.get('file', '')}: run '{tr.get('run', '')}', {len(ok)} windows of "
        f"{tr.get('cycles_per_window')} cycles"
        + (f" ({failed} window fit(s) failed: not drawn)" if failed else "")
        + f"; error bars ± {ERR_K:g} standard errors of each window's fit; the line is "
        "the weighted least-squares trend"
    )
    fig.text(0.01, 0.03, note, fontsize=8, color="0.3")
    return fig


@style.styled
def trajectory_table_figure(
    tr: Mapping[str, Any],
    *,
    units: Mapping[str, str] | None = None,
    fixed: Sequence[str] = (),
    title: str = "Parameter trajectory: windows and trends",
) -> Figure:
    """The windows (cycles, hours, each parameter ± its standard error, nrmse) and one
    row of trends per parameter (start, drift per hour ± s.e., % per hour)."""
    fig = style.new_figure(title)
    names = _plotted(tr, fixed)[:7]
    wins = list(tr.get("windows", []))
    gs = fig.add_gridspec(2, 1, height_ratios=[max(4, len(wins) + 1), len(names) + 2])
    ax = fig.add_subplot(gs[0])
    cells = []
    for w in wins:
        row = [f"{w['cycle_start']}–{w['cycle_end']}", f"{w['time_s'] / 3600.0:.3g}"]
        if w.get("status") != "ok":
            row += [str(w.get("reason", "failed"))[:40]] + [""] * (len(names))
            cells.append(row[: 2 + len(names) + 1])
            continue
        p, s = w.get("parameters") or {}, w.get("stderr") or {}
        for n in names:
            se = s.get(n)
            row.append(f"{_fmt(p.get(n))} ± {_fmt(se, 2)}" if se is not None else _fmt(p.get(n)))
        row.append(f"{w.get('nrmse', math.nan):.4f}")
        cells.append(row)
    labels = (
        ["cycles", "time (h)"]
        + [f"{n}\n({unit_of(n, units)})" if unit_of(n, units) else n for n in names]
        + ["nrmse"]
    )
    _table(ax, cells, labels, fontsize=8.0, row_height=1.0 if len(wins) > 16 else 1.2)
    ax2 = fig.add_subplot(gs[1])
    trend_cells = []
    for n in names:
        t = (tr.get("trend") or {}).get(n) or {}
        trend_cells.append(
            [
                n,
                _fmt(t.get("start")),
                _fmt(t.get("per_hour")),
                _fmt(t.get("per_hour_stderr"), 2),
                _fmt(t.get("percent_per_hour"), 3),
            ]
        )
    _table(
        ax2,
        trend_cells,
        ["parameter", "start", "drift per hour", "s.e. of drift", "% of start per hour"],
        fontsize=8.0,
    )
    return fig
