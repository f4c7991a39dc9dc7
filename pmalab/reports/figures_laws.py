"""Figures of several hysteresis laws identified on the same runs (``pmalab identify --model
a,b,c``): the ranking table with each law's held-out error per run on one scale (multiples of
the noise floor), and each held-out run's loops, one column per law, coloured on one shared
error scale with the residuals on one shared axis — so a law that looks better is better.

Units: x contraction in mm (positive = shorter), F tension in N, residuals F − F_model in N;
nrmse = rms(F − F_model) / std(F).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from pmalab.identify.noise import noise_floor_nrmse
from pmalab.reports import style
from pmalab.reports.data import LawEntry, Trace
from pmalab.reports.figures_parameters import _table
from pmalab.reports.figures_signals import ERROR_PERCENTILE, TIME_MAX_POINTS, error_loop

#: laws drawn side by side on one loops page
LAWS_PER_PAGE = 4
#: bars labelled with their value at most (4 laws × 6 runs)
MAX_BAR_LABELS = 24


def law_colour(i: int) -> str:
    """The colour of the i-th law (ranking order) on every laws page."""
    return f"C{i % 10}"


def run_key(t: Trace) -> tuple[str, str]:
    return (Path(t.file).name, t.run)


def run_floor(t: Trace) -> float | None:
    """The run's own noise floor (nrmse): the lowest any model can reach on it (the same
    estimate ``identify`` ranks the laws against)."""
    try:
        v = noise_floor_nrmse(t.force, t.time)
    except ValueError:
        return None
    return v if math.isfinite(v) and v > 0 else None


def _num(v: object, fmt: str) -> str:
    return format(float(v), fmt) if isinstance(v, int | float) and math.isfinite(v) else "-"


@style.styled
def laws_figure(
    entries: Sequence[LawEntry],
    floor: float | None,
    *,
    title: str = "Hysteresis laws compared on the held-out runs",
) -> Figure:
    """The laws ranked (best first, as ``laws.json``): a table of held-out nrmse, its
    multiple of the noise floor, the identification runs' fit and the parameter count, and a
    bar chart of every held-out run's nrmse per law in multiples of that run's own noise
    floor (the dashed line: a model there leaves only noise)."""
    fig = style.new_figure(title)
    gs = fig.add_gridspec(2, 1, height_ratios=[0.12 + 0.045 * len(entries), 1.0])
    tab_ax = fig.add_subplot(gs[0])
    cells = [
        [
            str(i + 1),
            e.law,
            _num(e.row.get("validation_nrmse"), ".4f"),
            _num(e.row.get("x_floor"), ".2f"),
            _num(e.row.get("identification_nrmse"), ".4f"),
            str(e.row.get("parameters_per_run", "-")),
        ]
        for i, e in enumerate(entries)
    ]
    _table(
        tab_ax,
        cells,
        [
            "rank",
            "law",
            "held-out nrmse\n(mean)",
            "× noise floor" + (f"\n(floor {floor:.4f})" if floor else ""),
            "identification nrmse\n(mean per run)",
            "parameters\n(per run)",
        ],
        col_widths=[0.06, 0.2, 0.15, 0.12, 0.2, 0.12],
        fontsize=9,
    )
    ax = fig.add_subplot(gs[1])
    # held-out runs in the best law's order; each law's nrmse of that run from its own file
    runs: list[tuple[str, str]] = []
    for e in entries:
        for t in e.validation():
            if run_key(t) not in runs:
                runs.append(run_key(t))
    if not runs:
        ax.axis("off")
        ax.text(0.5, 0.5, "no held-out run: the laws were not validated", ha="center")
        return fig
    floors = {}
    for e in entries:
        for t in e.validation():
            floors.setdefault(run_key(t), run_floor(t))
    scaled = all(floors[k] for k in runs)
    xs = np.arange(len(runs), dtype=float)
    w = 0.8 / len(entries)
    top = 0.0
    for i, e in enumerate(entries):
        by = {run_key(t): t for t in e.validation()}
        vals = [
            by[k].nrmse / (float(floors[k] or 1.0) if scaled else 1.0) if k in by else math.nan
            for k in runs
        ]
        top = max([top, *(v for v in vals if math.isfinite(v))])
        xi = xs + (i - (len(entries) - 1) / 2) * w
        ax.bar(xi, vals, w, color=law_colour(i), label=e.law)
        if len(entries) * len(runs) <= MAX_BAR_LABELS:  # more would crowd into each other
            for x, v in zip(xi, vals):
                if math.isfinite(v):
                    ax.text(x, v, f"{v:.2f}", ha="center", va="bottom", fontsize=8)
    if scaled:
        ax.axhline(1.0, color="0.2", ls="--", lw=1.0, label="noise floor")
    if len(runs) <= 6:
        ax.set_xticks(xs, [f"{run}\n({file})" for file, run in runs])
    else:  # slanted, so that long run names do not run into each other
        ax.set_xticks(xs, [run for _, run in runs], rotation=30, ha="right", rotation_mode="anchor")
    # headroom for the value labels and the legend above the tallest bars
    ax.set_ylim(0.0, max(top, 1.0) * 1.35)
    ax.set_ylabel("held-out nrmse (× the run's noise floor)" if scaled else "held-out nrmse")
    ax.set_title("Every held-out run, every law, one scale")
    ax.legend(loc="upper left", ncols=min(len(entries) + 1, 5), fontsize=8.5)
    ax.grid(axis="x", visible=False)
    return fig


@style.styled
def laws_loops_figure(
    entries: Sequence[LawEntry],
    key: tuple[str, str],
    *,
    colour_offset: int = 0,
    title: str,
) -> Figure:
    """One held-out run ``key`` (file name, run): a column per law with the measured loop
    and the law's loop coloured by |F − F_model| on ONE colour scale for all columns (0 to
    the 98th percentile of every law's error), and under it F − F_model against time on ONE
    shared axis."""
    fig = style.new_figure(title)
    traces = []
    for e in entries:
        t = next((t for t in e.validation() if run_key(t) == key), None)
        traces.append(t)
    # the measured force is the same in every law's trace: its noise floor once
    fl = next((run_floor(t) for t in traces if t is not None), None)
    errs = np.concatenate([np.abs(t.error) for t in traces if t is not None] or [np.zeros(1)])
    top = float(np.percentile(errs, ERROR_PERCENTILE)) if errs.size else 1.0
    norm = Normalize(vmin=0.0, vmax=max(top, 1e-12))
    lim = max(float(np.max(errs)), 1e-9) * 1.05
    n = len(entries)
    axes = fig.subplots(2, n, squeeze=False, height_ratios=[1.5, 1.0])
    lc = None
    for j, (e, t) in enumerate(zip(entries, traces)):
        ax_l, ax_e = axes[0, j], axes[1, j]
        if t is None:
            ax_l.axis("off")
            ax_e.axis("off")
            ax_l.set_title(f"{e.law}: run not predicted", fontsize=9)
            continue
        lc = error_loop(ax_l, t.position, t.force, t.force_model, norm=norm)
        x_floor = f", {t.nrmse / fl:.2f}× floor" if fl else ""
        ax_l.set_title(f"{e.law}\nnrmse {t.nrmse:.4f}{x_floor}", fontsize=9.5)
        if j:
            ax_l.set_ylabel("")
        if j == 0:
            ax_l.legend(loc="upper right", fontsize=8)
        s = style.decimate(t.time.shape[0], TIME_MAX_POINTS)
        ax_e.plot(t.time[s], t.error[s], color=law_colour(j + colour_offset), lw=0.8)
        ax_e.axhline(0.0, color="0.3", lw=0.6)
        ax_e.set_ylim(-lim, lim)
        ax_e.set_xlabel(style.TIME)
        ax_e.set_ylabel(style.RESIDUAL if j == 0 else "")
    if lc is not None:
        fig.colorbar(
            lc, ax=list(axes[0, :]), label=style.ABS_ERROR + ", one scale", shrink=0.9, pad=0.01
        )
    return fig


def held_out_keys(entries: Sequence[LawEntry], most: int) -> list[tuple[str, str]]:
    """The held-out runs that separate the laws most (largest spread of nrmse between the
    laws), at most ``most``, in the best law's order."""
    keys: list[tuple[str, str]] = []
    for e in entries:
        for t in e.validation():
            if run_key(t) not in keys:
                keys.append(run_key(t))

    def spread(k: tuple[str, str]) -> float:
        v = [t.nrmse for e in entries for t in e.validation() if run_key(t) == k]
        return (max(v) - min(v)) if v else 0.0

    chosen = set(sorted(keys, key=spread, reverse=True)[:most])
    return [k for k in keys if k in chosen]
