"""Figures of measured vs modelled signals: time histories, error-coloured loops and
validation overlays.

Sign convention (docs/explanation/physics.md): x is the contraction in mm (positive = shorter), F the
tension in N; in an F–x loop the tension is higher while the muscle is being stretched
(x decreasing) than while it contracts.  Residuals are ``F − F_model`` (measured − model) in N.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from pmalab.reports import style
from pmalab.reports.data import Trace

#: samples drawn per loop: each is a separately coloured PDF path, so this sets the page
#: weight (600 keeps ~200 per cycle on a 3-cycle run, smooth at print size)
LOOP_MAX_POINTS = 600
ERROR_PERCENTILE = 98.0
TIME_MAX_POINTS = 2000
#: line widths (pt) of a loop: the measurement wide underneath, the model thinner on top
MEASURED_LW = 2.2
MODEL_LW = 1.0


def error_loop(
    ax: Axes,
    position: np.ndarray,
    force: np.ndarray,
    force_model: np.ndarray,
    *,
    norm: Normalize | None = None,
    max_points: int = LOOP_MAX_POINTS,
    measured_label: str = "measured",
    measured_lw: float = MEASURED_LW,
    model_lw: float = MODEL_LW,
) -> LineCollection:
    """Draw a measured F–x loop (a wide grey band, visible under the model) and the model
    loop over it, thinner, as segments coloured by the absolute error |F − F_model| (N) at
    each segment (mean of its two end samples); the colour scale runs from 0 to the 98th
    percentile of those errors unless ``norm`` is given.

    At most ``max_points`` samples are drawn (uniform stride), so a loop of n ≤ max_points
    samples has exactly n − 1 coloured segments.  Returns the LineCollection (its array
    holds the per-segment |error| in N).
    """
    x = np.asarray(position, dtype=float)
    f = np.asarray(force, dtype=float)
    fm = np.asarray(force_model, dtype=float)
    s = style.decimate(x.shape[0], max_points)
    x, f, fm = x[s], f[s], fm[s]
    err = np.abs(fm - f)
    pts = np.column_stack([x, fm])
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    seg_err = 0.5 * (err[:-1] + err[1:])
    if norm is None:
        # the 98th percentile, not the maximum, tops the scale: one spike at a reversal
        # would otherwise paint the rest of the loop in the lowest colour
        top = float(np.percentile(seg_err, ERROR_PERCENTILE)) if seg_err.size else 0.0
        norm = Normalize(vmin=0.0, vmax=max(top, 1e-12))
    ax.plot(
        x,
        f,
        color=style.MEASURED_BAND,
        lw=measured_lw,
        label=measured_label,
        zorder=1,
        solid_capstyle="round",
    )
    lc = LineCollection(list(segs), cmap=style.ERROR_CMAP, norm=norm, linewidths=model_lw, zorder=2)
    lc.set_array(seg_err)
    ax.add_collection(lc)
    ax.autoscale_view()
    # legend proxy: a LineCollection's own handle would show its unused default colour
    ax.add_line(
        Line2D([], [], color=style.ERROR_CMAP(0.55), lw=model_lw, label="model (colour = |error|)")
    )
    ax.set_xlabel(style.POSITION)
    ax.set_ylabel(style.FORCE)
    return lc


def _fit_text(t: Trace, fit_percent: float | None) -> str:
    fp = t.fit_percent if fit_percent is None else fit_percent
    return f"fit {fp:.1f} %"


def _colorbar(fig: Figure, lc: LineCollection, ax: Axes) -> None:
    arr = np.asarray(lc.get_array(), dtype=float)
    vmax = lc.norm.vmax
    over = bool(arr.size) and isinstance(vmax, float | int) and float(arr.max()) > float(vmax)
    fig.colorbar(
        lc,
        ax=ax,
        label=style.ABS_ERROR,
        shrink=0.85,
        pad=0.01,
        aspect=30,
        extend="max" if over else "neither",
    )


@style.styled
def loops_figure(
    traces: Sequence[Trace],
    *,
    title: str = "Measured vs model loops",
    fit_percent: Sequence[float | None] | None = None,
) -> Figure:
    """Up to six F–x loops (2 × 3 grid), one per run/pressure level, each with its own
    |error| colour scale (a failing run must not wash out the others).

    ``fit_percent`` (same order as ``traces``) overrides the fit % computed from the trace.
    """
    fig = style.new_figure(title)
    n = len(traces)
    axes = style.panel_axes(fig, n, *style.grid_shape(n))
    for i, ax in enumerate(axes):
        t = traces[i]
        lc = error_loop(ax, t.position, t.force, t.force_model)
        _colorbar(fig, lc, ax)
        fp = None if fit_percent is None else fit_percent[i]
        ax.set_title(f"{t.describe()} — {_fit_text(t, fp)}\n{t.label}")
    if axes:
        # one legend for the page, under the panels: inside a panel no place is free of
        # data on every loop ("best" put it across a branch of the loop)
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncols=len(labels))
    return fig


@style.styled
def time_history_figure(traces: Sequence[Trace], *, title: str = "Time histories") -> Figure:
    """For each of up to three runs (columns): contraction, tension (measured vs model),
    error, and muscle pressure against time."""
    fig = style.new_figure(title)
    n = len(traces)
    axes = fig.subplots(
        4, n, squeeze=False, sharex="col", gridspec_kw={"height_ratios": [1, 1.6, 0.9, 0.9]}
    )
    for j, t in enumerate(traces):
        s = style.decimate(t.time.shape[0], TIME_MAX_POINTS)
        tt = t.time[s]
        a0, a1, a2, a3 = axes[:, j]
        a0.plot(tt, t.position[s], color=style.MEASURED)
        a0.set_ylabel(style.POSITION)
        a0.set_title(f"{t.label}\n{t.describe()}")
        a1.plot(tt, t.force[s], color=style.MEASURED, label="measured")
        a1.plot(tt, t.force_model[s], color=style.MODEL, lw=1.0, alpha=0.9, label="model")
        a1.set_ylabel(style.FORCE)
        # above the panel: a legend inside would cover the periodic curves
        a1.legend(
            loc="lower right", bbox_to_anchor=(1.0, 1.0), ncols=2, frameon=False, borderaxespad=0.1
        )
        a2.plot(tt, t.error[s], color=style.VALIDATION, lw=0.5)
        a2.axhline(0.0, color="0.4", lw=0.6)
        a2.set_ylabel(style.RESIDUAL)
        rms = float(np.sqrt(np.mean(t.error**2)))
        a2.set_title(
            f"residual: RMSE {rms:.3g} N, fit {t.fit_percent:.1f} %", loc="left", fontsize=8.5
        )
        a3.plot(tt, t.muscle_pressure[s], color="#8c564b", lw=0.5)
        a3.set_ylabel("p (MPa)")
        a3.set_xlabel(style.TIME)
    return fig


@style.styled
def validation_figure(
    traces: Sequence[Trace],
    *,
    fit_percent: Sequence[float | None] | None = None,
    title: str = "Validation: pressure-quadratic model, free-run prediction",
) -> Figure:
    """For each of up to two validation runs (columns): the error-coloured F–x loop, the
    tension against time (measured vs predicted) and the error; fit % in the titles."""
    fig = style.new_figure(title)
    n = len(traces)
    axes = fig.subplots(3, n, squeeze=False, gridspec_kw={"height_ratios": [2.2, 1.1, 0.8]})
    for j, t in enumerate(traces):
        fp = None if fit_percent is None else fit_percent[j]
        a0, a1, a2 = axes[:, j]
        lc = error_loop(a0, t.position, t.force, t.force_model)
        _colorbar(fig, lc, a0)
        a0.set_title(f"{t.label}\n{t.describe()} — {_fit_text(t, fp)}")
        a0.legend(loc="best")
        s = style.decimate(t.time.shape[0], TIME_MAX_POINTS)
        a1.plot(t.time[s], t.force[s], color=style.MEASURED, label="measured")
        a1.plot(t.time[s], t.force_model[s], color=style.VALIDATION, alpha=0.9, label="predicted")
        a1.set_ylabel(style.FORCE)
        # above the panel: a legend inside would cover the periodic curves
        a1.legend(
            loc="lower right", bbox_to_anchor=(1.0, 1.0), ncols=2, frameon=False, borderaxespad=0.1
        )
        a2.plot(t.time[s], t.error[s], color=style.VALIDATION, lw=0.5)
        a2.axhline(0.0, color="0.4", lw=0.6)
        a2.set_ylabel(style.RESIDUAL)
        a2.set_xlabel(style.TIME)
        a1.sharex(a2)
    return fig


@style.styled
def position_validation_figure(
    traces: Sequence[Trace],
    *,
    title: str = "Validation: simulated position (output error), free run from the measured force",
) -> Figure:
    """For each of up to two validation runs of a model fitted on position (columns): the
    measured and simulated position against time, their difference (same unit), and a
    zoom on the one-second window where the difference is largest."""
    fig = style.new_figure(title)
    n = len(traces)
    axes = fig.subplots(3, n, squeeze=False, gridspec_kw={"height_ratios": [1.5, 0.9, 1.5]})
    for j, t in enumerate(traces):
        a0, a1, a2 = axes[:, j]
        xm = t.position_model if t.position_model is not None else np.full_like(t.time, np.nan)
        e = t.position - xm
        rmse = float(np.sqrt(np.mean(e * e)))
        s = style.decimate(t.time.shape[0], TIME_MAX_POINTS)
        a0.plot(t.time[s], t.position[s], color=style.MEASURED, lw=1.4, label="measured")
        a0.plot(t.time[s], xm[s], color=style.VALIDATION, alpha=0.9, lw=0.7, label="simulated")
        a0.set_ylabel("Contraction x (mm)")
        a0.set_title(
            f"{t.label}\n{t.describe()}\nrms error {rmse * 1e-3:.3g} m "
            f"(nrmse {rmse / max(float(np.std(t.position)), 1e-12):.4f})",
            fontsize=10,
        )
        a1.plot(t.time[s], e[s], color=style.VALIDATION, lw=0.5)
        a1.axhline(0.0, color="0.4", lw=0.6)
        a1.set_ylabel("x − x_model (mm)")
        a1.sharex(a0)
        # the worst second, every sample drawn
        dt = float(np.median(np.diff(t.time)))
        w = max(2, min(t.time.shape[0], int(round(1.0 / dt))))
        k = int(np.nanargmax(np.abs(e))) if np.any(np.isfinite(e)) else 0
        lo = max(0, min(k - w // 2, t.time.shape[0] - w))
        z = slice(lo, lo + w)
        a2.plot(t.time[z], t.position[z], color=style.MEASURED, lw=1.6, label="measured")
        a2.plot(t.time[z], xm[z], color=style.VALIDATION, lw=0.9, label="simulated")
        a2.set_ylabel("x (mm), largest-error second")
        a2.set_xlabel(style.TIME)
        a2.legend(loc="upper right", ncols=2, fontsize=8)
    return fig


@style.styled
def before_after_figure(
    pairs: Sequence[tuple[Trace, Trace]],
    *,
    base_name: str = "base model",
    final_name: str = "final model",
    title: str = "The error falling: base model vs final model",
) -> Figure:
    """For up to three runs (columns): the error-coloured loop of the base model (top) and
    of the final model (bottom) on the same |error| scale, so the fall is visible."""
    fig = style.new_figure(title)
    n = len(pairs)
    axes = fig.subplots(2, n, squeeze=False)
    for j, (base, final) in enumerate(pairs):
        e = np.abs(base.error)
        top = float(np.percentile(0.5 * (e[:-1] + e[1:]), ERROR_PERCENTILE)) if e.size > 1 else 1.0
        norm = Normalize(vmin=0.0, vmax=max(top, 1e-12))
        for i, (t, name) in enumerate(((base, base_name), (final, final_name))):
            ax = axes[i, j]
            lc = error_loop(ax, t.position, t.force, t.force_model, norm=norm)
            # the run heads its column; each panel names its model and fit (titles no wider
            # than the panel, so they stay clear of the next column's colour bar)
            head = f"{t.run or t.label}\n{t.describe()}\n" if i == 0 else ""
            label = "\n".join(style.wrap(name, 36, break_on_hyphens=False))
            ax.set_title(f"{head}{label}\nfit {t.fit_percent:.1f} %", fontsize=9)
            if i == 0 and j == 0:
                ax.legend(loc="best")
        fig.colorbar(
            lc,
            ax=list(axes[:, j]),
            label=style.ABS_ERROR,
            shrink=0.85,
            pad=0.01,
            aspect=40,
            extend="max" if float(np.max(e)) > float(norm.vmax or 0.0) else "neither",
        )
        axes[1, j].sharex(axes[0, j])
        axes[1, j].sharey(axes[0, j])
    return fig
