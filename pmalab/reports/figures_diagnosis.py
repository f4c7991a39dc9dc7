"""Figures of the model diagnosis: binned residuals, residual auto-/cross-correlation,
the effect ranking and the ladder (nrmse as effects are added one at a time).

Residuals are ``F − F_model`` (measured − model) in N, as written by diagnose; NRMSE = RMS error / std of the measured tension.
Inputs are the plain dicts of ``diagnosis.json``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.container import BarContainer
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from matplotlib.transforms import blended_transform_factory

from pmalab.reports import style

#: binned-residual variables in display order, with their axis names
BINNED_VARIABLES = {
    "position": "Contraction x",
    "velocity": "Velocity ẋ",
    "velocity_sign": "Direction sign(ẋ)",
    "acceleration": "Acceleration ẍ",
    "pressure_deviation": "Pressure p − p_nom",
    "time": "Time t",
    "branch": "Branch",
}
BRANCH_TICKS = {-1.0: "stretch\n(ẋ<0)", 0.0: "stretch\n(ẋ<0)", 1.0: "release\n(ẋ>0)"}
SIGN_TICKS = {-1.0: "ẋ < 0\n(stretch)", 1.0: "ẋ > 0\n(release)", 0.0: "ẋ = 0"}


def _ci(ci: Sequence[Any] | None, n: int) -> np.ndarray | None:
    """ci95 as a (2, n) yerr array: half-widths, or [lo, hi] offsets if given as pairs."""
    if ci is None:
        return None
    if n and isinstance(ci[0], list | tuple):
        arr = np.array([[np.nan if v is None else float(v) for v in pair] for pair in ci])
        return np.abs(arr.T)
    arr = np.array([np.nan if v is None else float(v) for v in ci])
    return np.vstack([arr, arr])


def plot_binned(ax: Axes, variable: str, binned: Mapping[str, Any]) -> None:
    """Mean residual (N) ± 95 % CI per bin of one variable; zero line for reference."""
    centers = list(binned["centers"])
    mean = np.array([np.nan if v is None else float(v) for v in binned["mean"]])
    yerr = _ci(binned.get("ci95"), len(centers))
    unit = str(binned.get("unit") or "")
    categorical = any(isinstance(c, str) for c in centers) or variable in (
        "velocity_sign",
        "branch",
    )
    if categorical:
        ticks = BRANCH_TICKS if variable == "branch" else SIGN_TICKS
        xs = np.arange(len(centers), dtype=float)
        labels = [c if isinstance(c, str) else ticks.get(float(c), f"{c:g}") for c in centers]
        ax.bar(xs, mean, yerr=yerr, color=style.MODEL, alpha=0.7, capsize=4, width=0.5)
        ax.set_xticks(xs, labels)
        ax.set_xlim(-0.7, len(centers) - 0.3)
        ax.set_xlabel(BINNED_VARIABLES.get(variable, variable))
    else:
        x = np.array([float(c) for c in centers])
        if unit == "MPa" and x.size and np.nanmax(np.abs(x)) < 0.05:
            # small pressure deviations read better in kPa
            x, unit = x * 1e3, "kPa"
        ax.errorbar(x, mean, yerr=yerr, fmt="o-", color=style.MODEL, ms=3.5, capsize=2.5, lw=0.9)
        name = BINNED_VARIABLES.get(variable, variable)
        ax.set_xlabel(f"{name} ({unit})" if unit and unit not in ("-", "–") else name)
        ax.xaxis.set_major_locator(MaxNLocator(5))  # 8 pt labels stay apart in a 4-column grid
    ax.axhline(0.0, color="0.3", lw=0.7)
    ax.set_ylabel("mean F − F_model (N)")
    ax.set_title(f"Residual vs {BINNED_VARIABLES.get(variable, variable).split(' ')[0].lower()}")


def plot_correlation(ax: Axes, corr: Mapping[str, Any], *, title: str) -> None:
    """Correlation values against lag (s) as stems, with the ±95 % white-noise bound."""
    lags = np.asarray(corr["lags_s"], dtype=float)
    vals = np.array([np.nan if v is None else float(v) for v in corr["values"]])
    if lags.size <= 50:
        ax.vlines(lags, 0.0, vals, color=style.MODEL, lw=1.0)
        ax.plot(lags, vals, "o", color=style.MODEL, ms=2.5)
    else:  # dense lag grids read better as a line
        ax.plot(lags, vals, "-", color=style.MODEL, lw=1.2)
    b = corr.get("bound95")
    if b is not None:
        # the bound named in the title, not in a legend: a legend inside the panel covered
        # the correlation near lag 0, where it matters most
        ax.axhspan(-b, b, color="0.85", alpha=0.7, zorder=0)
        outside = int(np.sum(np.abs(vals[lags != 0]) > b))
        title += f"\n{outside}/{int(np.sum(lags != 0))} lags outside ±{b:.3g}"
    ax.axhline(0.0, color="0.3", lw=0.7)
    ax.set_xlabel("Lag (s)")
    ax.set_ylabel("correlation (grey: 95 % bound)" if b is not None else "correlation")
    ax.set_title(title)


def _signed(v: float) -> str:
    """A mean residual (N) with its sign, short enough for a heatmap cell: two significant
    digits, whole newtons from 10 N on (``-117``, not ``-1.2e+02``, which overran the
    cell), powers of ten only from 10 kN."""
    return f"{v:+.0f}" if 10.0 <= abs(v) < 1.0e4 else f"{v:+.2g}"


def plot_regions(ax: Axes, regions: Sequence[Mapping[str, Any]]) -> None:
    """R.m.s. residual (N) in each (branch × part of the stroke) cell as a heatmap; the
    cell's mean residual is written under its r.m.s."""
    branches = list(dict.fromkeys(str(c["branch"]) for c in regions))
    parts = list(dict.fromkeys(str(c["position"]) for c in regions))
    rms = np.full((len(branches), len(parts)), np.nan)
    mean = np.full_like(rms, np.nan)
    for c in regions:
        i, j = branches.index(str(c["branch"])), parts.index(str(c["position"]))
        rms[i, j] = np.nan if c.get("rms") is None else float(c["rms"])
        mean[i, j] = np.nan if c.get("mean") is None else float(c["mean"])
    ax.imshow(
        rms,
        cmap=style.ERROR_CMAP,
        aspect="auto",
        vmin=0.0,
        vmax=max(float(np.nanmax(rms, initial=0.0)), 1e-12),
    )
    ax.grid(False)
    ax.set_xticks(range(len(parts)), [p.replace(" contraction", "") for p in parts])
    ax.set_xlabel("part of the stroke (contraction)")
    ax.set_yticks(
        range(len(branches)),
        [
            b.split(" (")[0].replace(" branch", "") + "\n(" + b.split(" (")[1] if " (" in b else b
            for b in branches
        ],
    )
    vmax = float(np.nanmax(rms, initial=0.0))
    for i in range(rms.shape[0]):
        for j in range(rms.shape[1]):
            if np.isfinite(rms[i, j]):
                txt = f"{rms[i, j]:.3g} N" + (
                    f"\nmean {_signed(mean[i, j])}" if np.isfinite(mean[i, j]) else ""
                )
                ax.text(
                    j,
                    i,
                    txt,
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="white" if rms[i, j] < 0.6 * vmax else "black",
                )
    # every cell carries its value, so no colour bar (it would widen one grid column)
    ax.set_title("R.m.s. residual by loop region (N)")


def plot_phase(ax: Axes, phase: Mapping[str, Any]) -> None:
    """Mean and r.m.s. residual against loop phase (deg; 0° = maximum contraction)."""
    c = np.asarray(phase["centers_deg"], dtype=float)
    for key, colour, mk in (("rms", style.VALIDATION, "s-"), ("mean", style.MODEL, "o-")):
        if phase.get(key) is not None:
            v = np.array([np.nan if x is None else float(x) for x in phase[key]])
            ax.plot(c, v, mk, color=colour, ms=3.5, label=key)
    ax.axvspan(90.0, 270.0, color="0.9", zorder=0)
    ax.text(
        180.0,
        0.02,
        "stretch (x falling)",
        transform=ax.get_xaxis_transform(),
        ha="center",
        va="bottom",
        fontsize=8,
        color="0.35",
    )
    ax.axhline(0.0, color="0.3", lw=0.7)
    ax.set_xlim(0.0, 360.0)
    ax.set_xticks([0, 90, 180, 270, 360])
    ax.set_xlabel("Loop phase (deg, 0 = max contraction)")
    ax.set_ylabel("F − F_model (N)")
    ax.set_title("Residual by loop phase")
    lo, hi = ax.get_ylim()
    # headroom: the legend on top, the shaded band's label at the bottom
    ax.set_ylim(lo - 0.15 * (hi - lo), hi + 0.35 * (hi - lo))
    ax.legend(loc="upper right", ncols=2, fontsize=8)


@style.styled
def residual_diagnostics_figure(label: str, diag: Mapping[str, Any]) -> Figure:
    """All residual diagnostics of one run on one page (3 × 3): binned residuals against
    each variable, the residual autocorrelation and its cross-correlation with the input."""
    title = f"Residual diagnostics — {label}"
    fig = style.new_figure(title)
    panels: list[tuple[str, Any]] = []
    binned = diag.get("binned") or {}
    order = [v for v in BINNED_VARIABLES if v in binned] + [
        v for v in binned if v not in BINNED_VARIABLES
    ]
    if "branch" in binned and "velocity_sign" in binned:
        # the same split of the samples (ẋ < 0 is the stretch branch): one panel, not two
        order.remove("velocity_sign")
    panels += [("binned", v) for v in order]
    if diag.get("acf"):
        panels.append(("acf", None))
    if diag.get("ccf_input"):
        panels.append(("ccf", None))
    if diag.get("regions"):
        panels.append(("regions", None))
    if diag.get("loop_phase"):
        panels.append(("phase", None))
    n = len(panels)
    # at least 2 × 3 cells, so a run with few diagnostics keeps readable panel sizes
    ncols = 4 if n > 9 else 3
    nrows = max(2, math.ceil(n / ncols))
    axes = style.panel_axes(fig, n, nrows, ncols)
    for i, ax in enumerate(axes):
        kind, var = panels[i]
        if kind == "binned":
            plot_binned(ax, var, binned[var])
        elif kind == "regions":
            plot_regions(ax, diag["regions"])
        elif kind == "phase":
            plot_phase(ax, diag["loop_phase"])
        elif kind == "acf":
            plot_correlation(ax, diag["acf"], title="Residual autocorrelation")
        else:
            what = str(diag["ccf_input"].get("input") or "input")
            what = "contraction x" if what == "position" else what
            plot_correlation(ax, diag["ccf_input"], title=f"Correlation with {what}")
    worst = diag.get("worst_region")
    if worst:
        wrapped = "\n".join(style.wrap(f"worst region: {worst}", 115))
        fig.suptitle(f"{title}\n{wrapped}", fontweight="bold", fontsize=11)
    return fig


def plot_ranking(
    ax: Axes, ranking: Sequence[Mapping[str, Any]], ambiguous: Sequence[str] = ()
) -> tuple[BarContainer, BarContainer]:
    """Horizontal bars, best effect on top: NRMSE before (grey outline) and after adding
    each effect (green if significant, grey otherwise). Returns (before, after) bars."""
    n = len(ranking)
    y = np.arange(n)[::-1].astype(float)
    # null: no held-out run left to judge on (no bar)
    before = [float(r["nrmse_before"] or 0.0) for r in ranking]
    # a failed fit has no after-value worth a bar (its number is not a fall): none drawn
    after = [
        0.0 if r.get("status") == "failed" else float(r["nrmse_after"] or 0.0) for r in ranking
    ]
    colours = [style.SIGNIFICANT if r["significant"] else style.NOT_SIGNIFICANT for r in ranking]
    h = 0.38
    b0 = ax.barh(y + h / 2, before, height=h, color="white", edgecolor="0.3", label="before")
    b1 = ax.barh(y - h / 2, after, height=h, color=colours, label="after adding the effect")
    labels = []
    for r in ranking:
        s = str(r["effect"])
        if r["effect"] in ambiguous:
            s += " (ambiguous)"
        labels.append(s)
    ax.set_yticks(y, labels)
    xmax = max([*before, *after, 1e-9])
    for yi, r, a in zip(y, ranking, after):
        txt = "significant" if r["significant"] else "not significant"
        if r.get("status") == "failed":
            txt = "fit failed"
        if r.get("gain_x_floor") is not None:  # the rule's measure: held-out fall / floor
            txt += f", {float(r['gain_x_floor']):.2g}× floor"
        if r.get("n_params") is not None:
            txt += f", +{int(r['n_params'])} par."
        ax.text(
            a + 0.01 * xmax,
            yi - h / 2,
            txt,
            va="center",
            fontsize=8,
            fontweight="bold" if r["significant"] else "normal",
        )
    ax.set_xlim(0, xmax * 1.55)
    ax.set_xlabel("validation NRMSE")
    ax.set_title("Effect ranking (best first)")
    ax.legend(
        handles=[
            b0,
            Line2D([], [], color=style.SIGNIFICANT, lw=6, label="after: significant"),
            Line2D([], [], color=style.NOT_SIGNIFICANT, lw=6, label="after: not significant"),
        ],
        loc="upper center",
        bbox_to_anchor=(0.5, -0.12),
        ncols=3,
        frameon=False,
    )
    ax.grid(axis="y", visible=False)
    return b0, b1


def plot_ladder(ax: Axes, ladder: Sequence[Mapping[str, Any]]) -> Line2D:
    """NRMSE after each step of adding effects (step 0 = base model); the fit % is written
    at each point. Returns the NRMSE line (its y data are the ladder's nrmse values)."""
    steps = [int(s["step"]) for s in ladder]
    nr = [float(s["nrmse"]) for s in ladder]
    (line,) = ax.plot(steps, nr, "o-", color=style.MODEL, lw=1.8, ms=6)
    labels = []
    for s in ladder:
        added, law = s.get("added"), s.get("switched_law")
        labels.append(f"+ {added}" if added else (f"law {law}" if law else "base model"))
    ax.set_xticks(steps, labels, rotation=20, ha="right")
    for st, v, s in zip(steps, nr, ladder):
        fp = s.get("fit_percent")
        txt = f"{v:.3f}" + (f"\n({float(fp):.1f} %)" if fp is not None else "")
        ax.annotate(txt, (st, v), textcoords="offset points", xytext=(6, 6), fontsize=8)
    ax.set_ylim(0, max([*nr, 1e-9]) * 1.25)
    ax.set_xlim(min(steps) - 0.3, max(steps) + 0.6)
    ax.set_ylabel("validation NRMSE")
    ax.set_title("Ladder: NRMSE as effects are added")
    return line


@style.styled
def ranking_figure(ranking: Sequence[Mapping[str, Any]], ambiguous: Sequence[str] = ()) -> Figure:
    """The effect ranking alone (for export)."""
    fig = style.new_figure("Effect ranking", figsize=(8.0, 4.5))
    plot_ranking(fig.subplots(), ranking, ambiguous)
    return fig


@style.styled
def ladder_figure(ladder: Sequence[Mapping[str, Any]]) -> Figure:
    """The ladder plot alone (for export)."""
    fig = style.new_figure("Effect ladder", figsize=(7.0, 4.5))
    plot_ladder(fig.subplots(), ladder)
    return fig


@style.styled
def effects_figure(
    ranking: Sequence[Mapping[str, Any]],
    ladder: Sequence[Mapping[str, Any]] = (),
    *,
    ambiguous: Sequence[str] = (),
    suggested_experiment: str | None = None,
    summary: str | None = None,
    model: str = "",
) -> Figure:
    """The diagnosis page: ranking and ladder side by side, then the summary, ambiguity
    and the explanation of each effect."""
    fig = style.new_figure(f"Which effect is missing? — base model {model}".rstrip())
    gs = fig.add_gridspec(2, 2 if ladder else 1, height_ratios=[3.0, 1.6])
    if ranking:
        plot_ranking(fig.add_subplot(gs[0, 0]), ranking, ambiguous)
    if ladder:
        plot_ladder(fig.add_subplot(gs[0, 1] if ranking else gs[0, :]), ladder)
    tx = fig.add_subplot(gs[1, :])
    tx.axis("off")
    width = 150
    lines: list[str] = []
    if summary:
        lines += style.wrap("Summary: " + summary, width)
    if ambiguous:
        lines += style.wrap(
            "Ambiguous (explain the residual about equally well): " + ", ".join(ambiguous), width
        )
        if suggested_experiment:
            lines += style.wrap("Suggested experiment: " + suggested_experiment, width)
    for r in ranking[:4]:
        if r.get("explanation"):
            lines += style.wrap(
                f"{r['effect']}: {_first_sentence(str(r['explanation']))}",
                width,
                subsequent_indent="    ",
            )
    if len(lines) > 12:
        lines = [*lines[:11], "… (more in diagnosis.json)"]
    # x from the page's left margin (figure coordinates), y from the text panel: long
    # lines stay on the page whatever width the ranking's labels take
    tx.text(
        0.03,
        1.0,
        "\n".join(lines),
        va="top",
        fontsize=9,
        linespacing=1.4,
        transform=blended_transform_factory(fig.transFigure, tx.transAxes),
    )
    return fig


def _first_sentence(s: str, limit: int = 240) -> str:
    """The first sentence of an explanation (at most ``limit`` characters)."""
    cut = s.find(". ")
    out = s if cut < 0 else s[: cut + 1]
    return out if len(out) <= limit else out[: limit - 1] + "…"


CAMPAIGN_VARIABLES = {"pressure_level": "Muscle pressure level", "frequency": "Frequency"}


@style.styled
def campaign_figure(
    per_run: Sequence[Mapping[str, Any]],
    campaign: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    final_model: str | None = None,
    title: str = "Where the base model fails across the campaign",
) -> Figure:
    """Per-run NRMSE of the base model (and of the final model when given), then the r.m.s.
    residual (N) by pressure level and by frequency.

    ``per_run``: dicts with ``label``, ``nrmse`` and optional ``nrmse_final``, ``worst``;
    ``campaign``: the ``campaign_diagnostics`` of diagnosis.json (``centers``, ``rms``,
    optional ``ci95_rms``, ``unit``).
    """
    fig = style.new_figure(title)
    camp = [(k, v) for k, v in (campaign or {}).items() if v.get("rms") is not None]
    gs = fig.add_gridspec(2, max(len(camp), 1), height_ratios=[1.25, 1.0])
    ax = fig.add_subplot(gs[0, :])
    rows = sorted(per_run, key=lambda r: -(r.get("nrmse") or 0.0))
    xs = np.arange(len(rows))
    base = [np.nan if r.get("nrmse") is None else float(r["nrmse"]) for r in rows]
    has_final = final_model is not None and any(r.get("nrmse_final") is not None for r in rows)
    w = 0.38 if has_final else 0.6
    ax.bar(
        xs - (w / 2 if has_final else 0.0),
        base,
        width=w,
        color=style.NOT_SIGNIFICANT,
        label="base model",
    )
    if has_final:
        fin = [np.nan if r.get("nrmse_final") is None else float(r["nrmse_final"]) for r in rows]
        ax.bar(xs + w / 2, fin, width=w, color=style.SIGNIFICANT, label=f"final: {final_model}")
    ax.set_xticks(xs, [str(r["label"]) for r in rows], rotation=20, ha="right")
    ax.set_ylabel("NRMSE")
    ax.set_title("NRMSE per diagnosed run (its held-out prediction), highest first")
    ax.grid(axis="x", visible=False)
    top = np.nanmax([*base, *(fin if has_final else []), 1e-9])
    ax.set_ylim(0.0, 1.3 * top)  # headroom: the legend sits above the bars
    ax.legend(loc="upper center", ncols=2)
    for j, (var, c) in enumerate(camp):
        a = fig.add_subplot(gs[1, j])
        centers = np.asarray(c["centers"], dtype=float)
        rms = np.array([np.nan if v is None else float(v) for v in c["rms"]])
        ci = c.get("ci95_rms")
        yerr = None if ci is None else np.array([0.0 if v is None else float(v) for v in ci])
        a.errorbar(centers, rms, yerr=yerr, fmt="o-", color=style.VALIDATION, ms=4, capsize=3)
        unit = str(c.get("unit") or "")
        name = CAMPAIGN_VARIABLES.get(var, var.replace("_", " "))
        a.set_xlabel(f"{name} ({unit})" if unit else name)
        a.set_ylabel("r.m.s. residual (N)")
        a.set_title(f"Residual by {name.lower()}")
        a.set_ylim(bottom=0.0)
    return fig
