"""Figures of identified parameters: values against muscle pressure with their quadratic
fits θ(p) = q0 + q1·p + q2·p², parameter and metric tables, correlation heatmaps.

Inputs are plain data (lists, dicts) as found in ``identification.json``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence, Set
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from pmalab.reports import style

#: units of the parameters of the base models (h in N, x in mm, ẋ in mm/s); a document's
#: own ``parameter_units`` mapping takes precedence.
KNOWN_UNITS = {
    "k": "N/mm",
    "c0": "N",
    "A": "N/mm",
    "alpha": "1/mm",
    "a": "N/mm",
    "b": "N/mm",
    "beta": "1/mm·N^(1−n)",
    "gamma": "1/mm·N^(1−n)",
    "n": "–",
    "h0": "N",
    # effects (pmalab.identify.effects)
    "visc_c": "N·s/mm",
    "asym_psi_v": "1/mm·N^(1−n)",
    "asym_psi_h": "1/mm·N^(1−n)",
    "asym_psi_x": "1/mm·N^(1−n)",
    "stiff_k2": "N/mm²",
    "stiff_k3": "N/mm³",
    "pv_g0": "N/MPa",
    "pv_g1": "N/(MPa·mm)",
    "delay_tau": "s",
    "inertia_m": "kg",
    "drift_d": "N/s",
}

CORR_WARN = 0.95  # |ρ| above which a pair is flagged as poorly identifiable


def unit_of(name: str, units: Mapping[str, str] | None = None) -> str:
    """The unit of a parameter ('' when unknown)."""
    if units and name in units:
        return units[name]
    return KNOWN_UNITS.get(name, "")


def _fmt(v: float | None, digits: int = 4) -> str:
    if v is None or not math.isfinite(v):
        return "—"
    return f"{v:.{digits}g}"


def quadratic(q: Sequence[float], p: np.ndarray) -> np.ndarray:
    """θ(p) = q0 + q1·p + q2·p² (p in MPa)."""
    q0, q1, q2 = ([*list(q), 0.0, 0.0, 0.0])[:3]
    return q0 + q1 * p + q2 * p * p


def law_text(stat: Mapping[str, Any] | None, *, state: bool = False) -> str:
    """What draws a parameter's pressure law, for a title or a table cell: ``joint law,
    order 2``, ``quadratic through the points, R² 0.983`` (an R² only where it can be read,
    0 ≤ R² ≤ 1), or ``per-run state (no law)``."""
    if state:
        return "per-run state (no law)"
    st = stat or {}
    deg = st.get("degree")
    order = f", order {int(deg)}" if isinstance(deg, int | float) and math.isfinite(deg) else ""
    if st.get("method") == "joint":
        return f"joint law{order}"
    r2 = st.get("r2")
    if isinstance(r2, int | float) and math.isfinite(r2) and 0.0 <= r2 <= 1.0:
        return f"quadratic through the points{order}, R² {r2:.3f}"
    return f"quadratic through the points{order}"


def plot_parameter_vs_pressure(
    ax: Axes,
    name: str,
    pressures: Sequence[float],
    values: Sequence[float],
    stderr: Sequence[float | None] | None = None,
    fit: Sequence[float] | None = None,
    *,
    stat: Mapping[str, Any] | None = None,
    unit: str = "",
    validation_pressures: Sequence[float] = (),
    state: bool = False,
    fixed: bool = False,
) -> None:
    """One parameter: each run's own fit ± stderr at its pressure (points) and the pressure
    law θ(p) = q0 + q1·p + q2·p² the predictions use (line).

    ``stat`` is the parameter's ``pressure_fit_stats`` entry: with ``method = "joint"`` the
    law was refined on all runs at once and need not pass through the per-run points (those
    trade off among collinear parameters run by run); the seeds' quadratic through the
    points is then drawn dashed for reference.  ``state``: a per-run start state (h0), for
    which no law is drawn (each prediction estimates its own); ``fixed``: held at a value on
    every run (not fitted).
    """
    p = np.asarray(pressures, dtype=float)
    v = np.asarray(values, dtype=float)
    se = None
    if stderr is not None:
        se = np.array([np.nan if s is None else float(s) for s in stderr])
        se = np.where(np.isfinite(se), se, 0.0)
    ax.errorbar(
        p,
        v,
        yerr=se,
        fmt="o",
        color=style.MEASURED,
        ms=4,
        capsize=3,
        label="each run fitted alone ± s.e.",
        zorder=3,
    )
    allp = np.concatenate([p, np.asarray(validation_pressures, dtype=float)])
    shown = list(v[np.isfinite(v)])
    st = stat or {}
    if allp.size:
        lo, hi = float(np.min(allp)), float(np.max(allp))
        pad = 0.05 * max(hi - lo, 0.05)
        pp = np.linspace(lo - pad, hi + pad, 100)
        joint = st.get("method") == "joint"
        if fit is not None and all(q is not None for q in fit) and not state:
            curve = quadratic(fit, pp)
            ax.plot(
                pp,
                curve,
                color=style.MODEL,
                lw=1.6,
                zorder=2,
                label="law used for prediction" + (" (joint fit)" if joint else ""),
            )
            shown += list(curve[np.isfinite(curve)])
        prq = st.get("per_run_quadratic")
        if joint and prq and all(q is not None for q in prq) and not state:
            curve = quadratic(prq, pp)
            ax.plot(
                pp,
                curve,
                color=style.MODEL,
                lw=0.9,
                ls="--",
                alpha=0.7,
                zorder=2,
                label="quadratic through the points",
            )
            shown += list(curve[np.isfinite(curve)])
    if shown and se is not None and np.any(se > 0):
        # y range from the values and the laws, not from huge error bars of a poorly
        # identified level (those bars are clipped and marked)
        lo, hi = min(shown), max(shown)
        span = max(hi - lo, 1e-9 * max(abs(lo), abs(hi), 1.0))
        ylo, yhi = lo - 0.15 * span, hi + 0.15 * span
        if np.any(v - se < ylo) or np.any(v + se > yhi):
            ax.set_ylim(ylo, yhi)
            ax.text(
                0.99,
                0.02,
                "some error bars clipped",
                transform=ax.transAxes,
                ha="right",
                va="bottom",
                fontsize=8,
                color="0.35",
            )
    for i, vp in enumerate(validation_pressures):
        ax.axvline(
            vp, color=style.VALIDATION, ls=":", lw=0.8, label="validation p" if i == 0 else None
        )
    title = f"{name} ({unit})" if unit and unit not in ("–", "-") else name
    law = f"fixed at {_fmt(v[0])} (not fitted)" if fixed and v.size else law_text(st, state=state)
    ax.set_title(f"{title}\n{law}", fontsize=9)
    ax.set_xlabel(style.PRESSURE)
    ax.set_ylabel(f"{name} ({unit})" if unit and unit not in ("–", "-") else name)
    ax.yaxis.set_major_locator(MaxNLocator(6))


@style.styled
def parameters_vs_pressure_figure(
    parameter_names: Sequence[str],
    pressures: Sequence[float],
    values: Mapping[str, Sequence[float]],
    stderr: Mapping[str, Sequence[float | None]] | None = None,
    pressure_fits: Mapping[str, Sequence[float]] | None = None,
    stats: Mapping[str, Mapping[str, Any] | None] | None = None,
    *,
    units: Mapping[str, str] | None = None,
    validation_pressures: Sequence[float] = (),
    state_parameters: Sequence[str] = ("h0",),
    fixed: Sequence[str] = (),
    title: str = "Parameters against muscle pressure: per-run fits and the pressure laws",
) -> Figure:
    """Up to nine parameters (3 × 3 grid), one panel each (:func:`plot_parameter_vs_pressure`);
    ``stats``: ``pressure_fit_stats`` of identification.json (method, degree, r2, ...)."""
    fig = style.new_figure(title)
    n = len(parameter_names)
    ncols = min(3, max(n, 1))
    nrows = max(1, math.ceil(n / ncols))
    axes = style.panel_axes(fig, n, nrows, ncols)
    for i, ax in enumerate(axes):
        name = parameter_names[i]
        plot_parameter_vs_pressure(
            ax,
            name,
            pressures,
            values[name],
            None if stderr is None else stderr.get(name),
            None if pressure_fits is None else pressure_fits.get(name),
            stat=None if stats is None else stats.get(name),
            unit=unit_of(name, units),
            validation_pressures=validation_pressures,
            state=name in state_parameters,
            fixed=name in fixed,
        )
    if axes:
        handles: dict[str, Any] = {}
        for ax in axes:
            for h, lab in zip(*ax.get_legend_handles_labels()):
                handles.setdefault(lab, h)
        joint = any(((stats or {}).get(n) or {}).get("method") == "joint" for n in parameter_names)
        caption = (
            "The joint law is refined on the free-run error of all runs at once, so "
            "it need not pass through the per-run points (collinear parameters trade "
            "off run by run)."
            if joint
            else ""
        )
        spare = [ax for ax in fig.axes if not ax.get_visible()]
        if spare:  # an empty grid cell holds the legend and the caption
            box = spare[0]
            box.set_visible(True)
            box.axis("off")
            leg = box.legend(
                handles.values(),
                handles.keys(),
                loc="center",
                frameon=False,
                title="\n".join(style.wrap(caption, 52)) or None,
                title_fontsize=8.5,
                fontsize=8.5,
            )
            leg.get_title().set_color("0.3")
        else:
            axes[0].legend(handles.values(), handles.keys(), loc="best")
    return fig


def coef_text(q: Sequence[float | None]) -> list[str]:
    """q0, q1, q2 as table text: round-off residue (|q| < 1e-9 of the largest) and −0
    print as ``0``."""
    vals = [None if x is None or not math.isfinite(float(x)) else float(x) for x in q]
    big = max([abs(x) for x in vals if x is not None] + [0.0])
    out = []
    for x in vals:
        if x is not None and abs(x) <= 1e-9 * big:
            x = 0.0
        out.append("0" if x == 0.0 else _fmt(x))
    return out


def _table(
    ax: Axes,
    cells: list[list[str]],
    col_labels: list[str],
    *,
    col_widths: Sequence[float] | None = None,
    highlight: Set[tuple[int, int]] = frozenset(),
    fontsize: float = 8.5,
    row_height: float = 1.35,
):
    ax.axis("off")
    tab = ax.table(
        cellText=cells,
        colLabels=col_labels,
        loc="upper center",
        cellLoc="center",
        colWidths=col_widths,
    )
    tab.auto_set_font_size(False)
    tab.set_fontsize(fontsize)
    tab.scale(1.0, row_height)
    two_line = any("\n" in h for h in col_labels)
    for (r, c), cell in tab.get_celld().items():
        cell.set_linewidth(0.4)
        if r == 0 and two_line:
            cell.set_height(cell.get_height() * 1.7)
        if r == 0:
            cell.set_facecolor("#e8eef6")
            cell.set_text_props(fontweight="bold")
        elif (r - 1, c) in highlight:
            cell.set_facecolor("#fde0dc")
    return tab


def bullet_lines(lines: Sequence[str], width: int = 150) -> list[str]:
    """Lines as wrapped bullet points."""
    out: list[str] = []
    for ln in lines:
        out.extend(style.wrap(ln, width, initial_indent="• ", subsequent_indent="  "))
    return out


#: how the parameter table page splits its height: tables by rows, warnings by a fixed share
_TEXT_SHARE = 7.0


def table_page_warning_capacity(n_params: int, has_fits: bool) -> int:
    """How many warning lines (8.5 pt) fit under the tables of :func:`parameter_table_figure`."""
    r1 = max(n_params, 1) + 1.5
    r2 = (n_params + 1.5) if has_fits else 0.01
    height_pt = 8.27 * 0.86 * 72 * _TEXT_SHARE / (r1 + r2 + _TEXT_SHARE)
    return max(int(height_pt / (8.5 * 1.35)) - 2, 2)


def _text_block(
    ax: Axes,
    heading: str,
    lines: Sequence[str],
    *,
    width: int = 150,
    max_lines: int = 14,
    more: str = "more lines",
) -> None:
    ax.axis("off")
    wrapped = bullet_lines(lines, width)
    if len(wrapped) > max_lines:
        extra = len(wrapped) - max_lines + 1
        wrapped = [*wrapped[: max_lines - 1], f"  … ({extra} {more})"]
    ax.text(0.0, 1.0, heading, fontweight="bold", va="top", transform=ax.transAxes)
    ax.annotate(
        "\n".join(wrapped) if wrapped else "none",
        (0.0, 1.0),
        xycoords="axes fraction",
        xytext=(0, -17),
        textcoords="offset points",
        va="top",
        fontsize=8.5,
        linespacing=1.35,
    )


@style.styled
def parameter_table_figure(
    parameter_names: Sequence[str],
    runs: Sequence[Mapping[str, Any]],
    pressure_fits: Mapping[str, Sequence[float]] | None = None,
    stats: Mapping[str, Mapping[str, Any] | None] | None = None,
    *,
    units: Mapping[str, str] | None = None,
    warnings: Sequence[str] = (),
    state_parameters: Sequence[str] = ("h0",),
    fixed_all: Sequence[str] = (),
    title: str = "Identified parameters (value ± standard error) and identifiability",
) -> Figure:
    """Table of parameter values ± standard errors per run (≤ 7 runs per page), the
    pressure laws' coefficients and how each law was made (:func:`law_text`), and the
    identifiability warnings.

    ``runs``: dicts with ``muscle_pressure_MPa``, ``parameters``, optional ``stderr``,
    ``fixed`` and ``run``.  Cells whose relative standard error exceeds 50 % are shaded
    (the caption under the table says so).
    """
    fig = style.new_figure(title)
    has_fits = bool(pressure_fits)
    ratios = [
        max(len(parameter_names), 1) + 1.5,
        (len(parameter_names) + 1.5) if has_fits else 0.01,
        _TEXT_SHARE,
    ]
    axes = fig.subplots(3, 1, gridspec_kw={"height_ratios": ratios})
    head = ["parameter", "unit"] + [
        f"p = {r['muscle_pressure_MPa']:.3f} MPa\n{r.get('run', '')}" for r in runs
    ]
    cells, hi = [], set()
    for i, name in enumerate(parameter_names):
        row = [name, unit_of(name, units)]
        for j, r in enumerate(runs):
            v = (r.get("parameters") or {}).get(name)
            se = (r.get("stderr") or {}).get(name)
            fixed = name in (r.get("fixed") or [])
            txt = _fmt(v)
            if fixed:
                txt += " (fixed)"
            elif se is not None and math.isfinite(se):
                txt += f" ± {_fmt(se, 2)}"
                if v not in (None, 0) and abs(se / v) > 0.5:
                    hi.add((i, j + 2))
            row.append(txt)
        cells.append(row)
    n = len(runs)
    widths = [0.1, 0.08] + [min(0.82 / max(n, 1), 0.2)] * n
    _table(axes[0], cells, head, col_widths=widths, highlight=hi)
    axes[0].set_title(
        "Each run fitted alone; shaded: relative standard error > 50 % "
        "(poorly determined on that run)",
        loc="left",
        fontsize=8.5,
        color="0.3",
    )
    if has_fits:
        head2 = [
            "parameter",
            "unit",
            "q0",
            "q1 (per MPa)",
            "q2 (per MPa²)",
            "θ(p) = q0 + q1·p + q2·p²",
        ]
        cells2 = []
        for name in parameter_names:
            q = list((pressure_fits or {}).get(name) or [])
            q = ([*q, None, None, None])[:3]
            st = None if stats is None else stats.get(name)
            if name in state_parameters:
                law, q = law_text(st, state=True), [None, None, None]
            elif name in fixed_all:
                law = "fixed (not fitted)"
            else:
                law = law_text(st)
            cells2.append([name, unit_of(name, units), *coef_text(q), law])
        _table(axes[1], cells2, head2, col_widths=[0.1, 0.08, 0.14, 0.14, 0.14, 0.3])
    else:
        axes[1].axis("off")
    _text_block(
        axes[2],
        "Warnings and notes of the identification",
        list(warnings),
        max_lines=table_page_warning_capacity(len(parameter_names), has_fits),
        more="more lines: all warnings are on the next page",
    )
    return fig


@style.styled
def correlation_figure(
    entries: Sequence[Mapping[str, Any]],
    *,
    title: str = "Parameter correlation (identifiability); |ρ| > 0.95 is outlined",
) -> Figure:
    """Up to six correlation heatmaps (2 × 3). ``entries``: dicts with ``title``,
    ``names`` and ``matrix`` (ρ in [−1, 1])."""
    fig = style.new_figure(title)
    n = len(entries)
    axes = style.panel_axes(fig, n, *style.grid_shape(n))
    im = None
    for i, ax in enumerate(axes):
        e = entries[i]
        names = list(e["names"])
        m = np.array([[np.nan if v is None else float(v) for v in row] for row in e["matrix"]])
        im = ax.imshow(m, vmin=-1.0, vmax=1.0, cmap="RdBu_r")
        ax.grid(False)
        ax.set_xticks(range(len(names)), names, rotation=45, ha="right")
        ax.set_yticks(range(len(names)), names)
        ax.set_title(str(e.get("title", "")))
        fs = 8.5 if len(names) <= 8 else 8.0
        # write ρ into the cells only while they are wide enough for "-0.99" at 8 pt
        if len(names) <= (12 if len(axes) <= 4 else 8):
            for r in range(len(names)):
                for c in range(len(names)):
                    v = m[r, c]
                    if not np.isfinite(v):
                        continue
                    strong = abs(v) > CORR_WARN and r != c
                    ax.text(
                        c,
                        r,
                        f"{v:.2f}",
                        ha="center",
                        va="center",
                        fontsize=fs,
                        color="white" if abs(v) > 0.6 else "black",
                        fontweight="bold" if strong else "normal",
                    )
                    if strong:
                        ax.add_patch(_outline(c, r))
    if im is not None:
        fig.colorbar(im, ax=list(axes[:n]), label="correlation ρ", shrink=0.8)
    return fig


def _outline(c: int, r: int):
    from matplotlib.patches import Rectangle

    return Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, ec="black", lw=1.5)


METRIC_COLUMNS = [
    ("rmse", "RMSE\n(N)", ".3g"),
    ("nrmse", "NRMSE", ".3g"),
    ("fit_percent", "fit\n(%)", ".1f"),
    ("max_error", "max\n|error| (N)", ".3g"),
    ("energy_error_percent", "loop energy\nerror (%)", "+.1f"),
]


@style.styled
def metrics_table_figure(
    rows: Sequence[Mapping[str, Any]],
    *,
    title: str = "Fit quality: identification runs and validation (free-run prediction)",
    notes: Sequence[str] = (),
) -> Figure:
    """One table row per run: role, run, p, f, waveform, RMSE, NRMSE, fit %, max error,
    loop energy error, RMSE on the stretch/release branches; below it, fit % per run as
    bars.  ``rows`` are the run dicts of ``identification.json`` with a ``role`` key."""
    fig = style.new_figure(title)
    nrow = len(rows)
    axes = fig.subplots(3, 1, gridspec_kw={"height_ratios": [nrow + 1.2, 5.0, 1.6]})
    head = (
        ["role", "run", "p\n(MPa)", "f\n(Hz)", "waveform"]
        + [h for _, h, _ in METRIC_COLUMNS]
        + ["RMSE\nstretch (N)", "RMSE\nrelease (N)"]
    )
    cells, hi = [], set()
    for i, r in enumerate(rows):
        f = r.get("frequency_Hz")
        row = [
            str(r.get("role", "")),
            f"{Path(str(r.get('file', ''))).name}:{r.get('run', '')}",
            f"{r['muscle_pressure_MPa']:.4g}",
            _fmt(f, 3),
            str(r.get("waveform") or "—"),
        ]
        for k, _, spec in METRIC_COLUMNS:
            v = r.get(k)
            row.append("—" if v is None or not math.isfinite(v) else format(v, spec))
        br = r.get("branch_rmse") or {}
        row += [_fmt(br.get("stretch"), 3), _fmt(br.get("release"), 3)]
        cells.append(row)
        if r.get("role") == "validation":
            hi.add((i, 0))
    widths = [0.085, 0.22, 0.05, 0.04, 0.06, 0.065, 0.065, 0.05, 0.075, 0.085, 0.08, 0.08]
    _table(axes[0], cells, head, col_widths=widths, highlight=hi, row_height=1.6)
    ax = axes[1]
    fits = [
        float(r["fit_percent"])
        if r.get("fit_percent") is not None
        else 100.0 * (1.0 - float(r["nrmse"]))
        for r in rows
    ]
    colours = [style.VALIDATION if r.get("role") == "validation" else style.MODEL for r in rows]
    xs = np.arange(nrow)
    ax.bar(xs, fits, color=colours, width=0.6)
    for x, v in zip(xs, fits):
        ax.text(x, v, f"{v:.1f}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(xs, [f"{r.get('run', '')}\n{r['muscle_pressure_MPa']:.3f} MPa" for r in rows])
    lo = min([*fits, 100.0])
    bottom = max(0.0, lo - 0.25 * (100.0 - lo) - 2.0)
    ax.set_ylim(bottom, 100.0 + 0.08 * (100.0 - bottom))  # headroom for the labels
    ax.set_ylabel("fit (%)")
    ax.set_title("Fit per run (blue: identification, red: validation)")
    ax.grid(axis="x", visible=False)
    _text_block(
        axes[2],
        "Notes",
        [
            "NRMSE = RMS error / standard deviation of the measured tension; fit % = 100·(1 − NRMSE).",
            "Validation rows: the pressure-quadratic model's free-run prediction of runs not used "
            "for identification (shaded).",
            "Stretch branch: x decreasing (muscle lengthening, higher tension); release: x increasing.",
            *notes,
        ],
        max_lines=8,
    )
    return fig


WARNINGS_LINES_PER_COLUMN = 46


@style.styled
def warnings_figure(
    warnings: Sequence[str],
    *,
    title: str = "Identifiability and fit warnings (all)",
) -> Figure:
    """Every warning as a bullet list in two columns (≤ 2 × 46 lines; callers split longer
    lists over pages with :func:`bullet_lines`)."""
    fig = style.new_figure(title)
    axes = fig.subplots(1, 2)
    lines = bullet_lines(warnings, 95)
    for j, ax in enumerate(axes):
        ax.axis("off")
        chunk = lines[j * WARNINGS_LINES_PER_COLUMN : (j + 1) * WARNINGS_LINES_PER_COLUMN]
        ax.text(
            0.0,
            1.0,
            "\n".join(chunk),
            va="top",
            fontsize=8.5,
            linespacing=1.35,
            transform=ax.transAxes,
        )
    return fig
