"""Figures that put a base identification and an improved one (``identify --add``) side by
side: the validation error per run before/after with the one error-fall figure, the
parameter changes, and the hysteretic component of seed 1's Figure 6 (measured
F − (k·x + c0) against x with each model's over it).

Units: x contraction in mm (positive = shorter), F tension in N, residuals F − F_model in N.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from pmalab.reports import style
from pmalab.reports.data import Trace
from pmalab.reports.figures_parameters import _fmt, _table, unit_of
from pmalab.reports.figures_signals import ERROR_PERCENTILE, error_loop


def _nrmse(row: Mapping[str, Any]) -> float:
    v = row.get("nrmse")
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else math.nan


def _bars(
    ax,
    labels: Sequence[str],
    before: Sequence[float],
    after: Sequence[float],
    *,
    base_name: str,
    improved_name: str,
    title: str,
) -> None:
    xs = np.arange(len(labels), dtype=float)
    w = 0.38
    ax.bar(xs - w / 2, before, w, color=style.NOT_SIGNIFICANT, label=f"base: {base_name}")
    ax.bar(xs + w / 2, after, w, color=style.SIGNIFICANT, label=f"improved: {improved_name}")
    top = max([v for v in [*before, *after] if math.isfinite(v)] + [1e-9])
    for x, b, a in zip(xs, before, after):
        for dx, v in ((-w / 2, b), (w / 2, a)):
            if math.isfinite(v):
                ax.text(x + dx, v + 0.01 * top, f"{v:.4f}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(xs, labels)
    ax.set_ylim(0.0, top * 1.12)  # headroom for the value labels
    ax.set_ylabel("NRMSE")
    ax.set_title(title)
    ax.grid(axis="x", visible=False)


def _run_label(row: Mapping[str, Any]) -> str:
    return f"{row.get('run', '')}\n{float(row['muscle_pressure_MPa']):.3f} MPa"


@style.styled
def compare_figure(
    base: Mapping[str, Any],
    improved: Mapping[str, Any],
    headline: str,
    *,
    base_name: str,
    improved_name: str,
    title: str = "Base vs improved identification: the validation error per run",
) -> Figure:
    """Validation NRMSE per run (and their mean) of both models, the identification runs
    predicted through each model's pressure laws, and the parameters both models share,
    base → improved, per identification run.  ``headline`` is the error-fall sentence
    (:func:`pmalab.identify.headline.error_fall`), printed under the title."""
    fig = style.new_figure(title)
    names = [
        n for n in base.get("parameter_names") or [] if n in (improved.get("parameter_names") or [])
    ]
    runs_b = sorted(base.get("runs") or [], key=lambda r: r["muscle_pressure_MPa"])
    by_run = {(r.get("file"), r.get("run")): r for r in improved.get("runs") or []}
    pairs = [
        (r, by_run[(r.get("file"), r.get("run"))])
        for r in runs_b
        if (r.get("file"), r.get("run")) in by_run
    ]
    gs = fig.add_gridspec(3, 2, height_ratios=[0.3, 1.0, 0.95 if pairs and names else 0.01])
    head = fig.add_subplot(gs[0, :])
    head.axis("off")
    head.text(
        0.5,
        1.0,
        "\n".join(style.wrap(headline[:1].upper() + headline[1:], 125)),
        ha="center",
        va="top",
        fontsize=10.5,
        fontweight="bold",
        transform=head.transAxes,
    )
    head.legend(
        handles=[
            Patch(color=style.NOT_SIGNIFICANT, label=f"base: {base_name}"),
            Patch(color=style.SIGNIFICANT, label=f"improved: {improved_name}"),
        ],
        loc="lower center",
        ncols=2,
        frameon=False,
        fontsize=9,
    )
    val_b = list(base.get("validation") or [])
    val_i = {(v.get("file"), v.get("run")): v for v in improved.get("validation") or []}
    vpairs = [
        (v, val_i[(v.get("file"), v.get("run"))])
        for v in val_b
        if (v.get("file"), v.get("run")) in val_i
    ]
    ax = fig.add_subplot(gs[1, 0])
    if vpairs:
        before = [_nrmse(b) for b, _ in vpairs]
        after = [_nrmse(a) for _, a in vpairs]
        labels = [_run_label(b) for b, _ in vpairs]
        ok = [i for i in range(len(vpairs)) if math.isfinite(before[i]) and math.isfinite(after[i])]
        if ok:
            labels.append("mean")
            before.append(float(np.mean([before[i] for i in ok])))
            after.append(float(np.mean([after[i] for i in ok])))
        _bars(
            ax,
            labels,
            before,
            after,
            base_name=base_name,
            improved_name=improved_name,
            title="Validation runs: free-run prediction through the pressure laws",
        )
    else:
        ax.axis("off")
        ax.text(0.5, 0.5, "no validation run predicted by both models", ha="center")
    ax2 = fig.add_subplot(gs[1, 1])
    quad = [
        (r, i)
        for r, i in pairs
        if (r.get("quadratic_model") or {}).get("nrmse") is not None
        and (i.get("quadratic_model") or {}).get("nrmse") is not None
    ]
    if quad:
        _bars(
            ax2,
            [f"{float(r['muscle_pressure_MPa']):.2f}" for r, _ in quad],
            [float(r["quadratic_model"]["nrmse"]) for r, _ in quad],
            [float(i["quadratic_model"]["nrmse"]) for _, i in quad],
            base_name=base_name,
            improved_name=improved_name,
            title="Identification runs predicted through the pressure laws",
        )
        ax2.set_xlabel("muscle pressure of the identification run (MPa)")
        for t in ax2.texts:  # too many bars for value labels
            t.set_visible(False)
    else:
        ax2.axis("off")
    if pairs and names:
        tab = fig.add_subplot(gs[2, :])
        shown = pairs[:7]
        cells = []
        for n in names:
            row = [n, unit_of(n, base.get("parameter_units"))]
            for r, i in shown:
                row.append(
                    f"{_fmt((r.get('parameters') or {}).get(n))} → "
                    f"{_fmt((i.get('parameters') or {}).get(n))}"
                )
            cells.append(row)
        headr = ["parameter", "unit"] + [
            f"p = {float(r['muscle_pressure_MPa']):.3f} MPa" for r, _ in shown
        ]
        k = len(shown)
        _table(
            tab,
            cells,
            headr,
            col_widths=[0.09, 0.12] + [min(0.78 / max(k, 1), 0.2)] * k,
            fontsize=8.0,
            row_height=1.2,
        )
        tab.set_title(
            "Shared parameters per identification run: base → improved (each run fitted alone)",
            fontsize=9.5,
        )
    return fig


def linear_component(doc: Mapping[str, Any], trace: Trace) -> tuple[float, float] | None:
    """(k N/mm, c0 N) of an identification for one trace: the run's own fit for an
    identification run, else the pressure laws at the run's nominal pressure."""
    for r in doc.get("runs") or []:
        if r.get("run") == trace.run and trace.role.endswith("identification"):
            p = r.get("parameters") or {}
            if "k" in p and "c0" in p:
                return float(p["k"]), float(p["c0"])
    fits = doc.get("pressure_fits") or {}
    if "k" not in fits or "c0" not in fits:
        return None
    pn = trace.muscle_pressure_MPa
    ev = [sum(float(q or 0.0) * pn**j for j, q in enumerate(fits[n][:3])) for n in ("k", "c0")]
    return ev[0], ev[1]


@style.styled
def hysteresis_component_figure(
    base: Trace,
    improved: Trace,
    linear: tuple[float, float],
    *,
    base_name: str,
    improved_name: str,
    title: str = "Hysteretic component",
) -> Figure:
    """Seed 1's Figure 6 for one run, base and improved side by side: the measured
    F − (k·x + c0) against x (black) with each model's F_model − (k·x + c0) over it
    (thinner, coloured by |F − F_model| on the base model's scale), and below it the
    residual F − F_model against x on a shared axis.  ``linear`` = (k, c0) of the base
    model, subtracted from the measurement and both models alike (the residual does not
    depend on it)."""
    k, c0 = linear
    fig = style.new_figure(title)
    gs = fig.add_gridspec(3, 2, height_ratios=[2.2, 1.0, 0.16])
    axes = np.empty((2, 2), dtype=object)
    for i in range(2):
        for j in range(2):
            axes[i, j] = fig.add_subplot(gs[i, j], sharex=None if i == j == 0 else axes[0, 0])
    e = np.abs(base.error)
    top = float(np.percentile(0.5 * (e[:-1] + e[1:]), ERROR_PERCENTILE)) if e.size > 1 else 1.0
    norm = Normalize(vmin=0.0, vmax=max(top, 1e-12))
    lc = None
    for j, (t, name) in enumerate(
        ((base, f"base: {base_name}"), (improved, f"improved: {improved_name}"))
    ):
        lin = k * t.position + c0
        a0, a1 = axes[0, j], axes[1, j]
        lc = error_loop(
            a0,
            t.position,
            t.force - lin,
            t.force_model - lin,
            norm=norm,
            measured_lw=1.6,
            model_lw=0.9,
        )
        a0.set_ylabel("F − (k·x + c0) (N)")
        a0.set_xlabel("")
        rms = float(np.sqrt(np.mean(t.error**2)))
        a0.set_title(f"{name}\nfit {t.fit_percent:.2f} %, r.m.s. residual {rms:.3g} N")
        a0.legend(loc="upper right", fontsize=8)
        s = style.decimate(t.position.shape[0], 4000)
        a1.plot(t.position[s], t.error[s], color=style.VALIDATION, lw=0.5)
        a1.axhline(0.0, color="0.3", lw=0.7)
        a1.set_ylabel(style.RESIDUAL)
        a1.set_xlabel(style.POSITION)
    axes[0, 1].sharey(axes[0, 0])
    axes[1, 1].sharey(axes[1, 0])
    if lc is not None:
        fig.colorbar(
            lc,
            ax=list(axes[0, :]),
            label=style.ABS_ERROR,
            shrink=0.9,
            pad=0.01,
            aspect=30,
            extend="max" if float(np.max(e, initial=0.0)) > top else "neither",
        )
    cap = fig.add_subplot(gs[2, :])
    cap.axis("off")
    cap.text(
        0.0,
        0.5,
        "\n".join(
            style.wrap(
                f"{base.label}: {base.describe()}.  k·x + c0 with k = {k:.4g} N/mm, c0 = {c0:.4g} N "
                "(the base model's linear component) is removed from the measured tension and from both "
                "models, leaving the hysteretic part the laws must reproduce; the loop is thin in the "
                "F–x plane, so this is where a model's failure shows.",
                160,
            )
        ),
        fontsize=8,
        va="center",
        color="0.25",
        transform=cap.transAxes,
    )
    return fig
