"""The report of a static characterization (``identify --static``): the parameters with their
meaning, force–pressure loops per held length (measured and model, inflating and venting
branches told apart), the static map as a family of curves with the data it was fitted to,
and each run's error against its own noise floor.

Isobaric and free runs of the same identification are drawn as force–contraction loops on
the loops page (the drive that moved them).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import matplotlib as mpl
import numpy as np
from matplotlib.figure import Figure

from pmalab.identify.schema import PredictionRun, read_predictions
from pmalab.reports import style
from pmalab.reports.errors import ReportError
from pmalab.reports.pdf import PageSpec, ReportPlan, write_plan

#: the PDF Subject of a static characterization report
STATIC_SUBJECT = "pneumatic muscle static characterization"

#: branch colours: inflating (pressure rising) and venting
INFLATING = "#1f77b4"
VENTING = "#d62728"


def is_static_dir(path: str | Path) -> bool:
    """True for an ``identify --static`` output directory."""
    j = Path(path) / "identification.json"
    if not j.is_file():
        return False
    try:
        return json.loads(j.read_text()).get("kind") == "static"
    except (OSError, ValueError, AttributeError):
        return False


def _load(path: Path) -> tuple[dict[str, Any], list[PredictionRun]]:
    try:
        doc = json.loads((path / "identification.json").read_text())
    except (OSError, ValueError) as exc:
        raise ReportError(f"{path / 'identification.json'}: unreadable ({exc})") from None
    pred = path / "predictions.h5"
    if not pred.is_file():
        raise ReportError(f"{pred}: missing (the identify output is incomplete)")
    return doc, read_predictions(pred, error=ReportError).runs


def _row(doc: dict[str, Any], pr: PredictionRun) -> dict[str, Any]:
    """The identification.json row of a prediction group."""
    for r in [*doc.get("runs", []), *doc.get("validation", [])]:
        if r["run"] == pr.attrs.get("run") and (r.get("file") or "") == (
            pr.attrs.get("file") or ""
        ):
            return r
    return {}


def _held(row: dict[str, Any], pr: PredictionRun) -> str:
    if "held_position_mm" in row:
        return f"x = {row['held_position_mm']:.3g} mm"
    if row.get("test_type") == "isobaric":
        return f"p = {row.get('muscle_pressure_MPa', float(np.median(pr.arrays['muscle_pressure']))):.3g} MPa"
    return row.get("test_type", "")


@style.styled
def summary_figure(doc: dict[str, Any]) -> Figure:
    """Page 1: what was fitted, its parameters (value ± standard error, unit, meaning), the
    loop widths and every run's fit against its noise floor."""
    fig = style.new_figure(f"Static characterization: {doc.get('model_full', '')}", layout=False)
    sm = doc["static_map"]
    lines = [
        f"static map: {sm['title']}  (geometry: "
        + ", ".join(f"{k} = {v:g}" for k, v in sm["geometry"].items() if v is not None)
        + ")"
    ]
    rows: list[tuple[str, str, str, str]] = []
    for n, p in sm["parameters"].items():
        se = "" if p.get("stderr") is None else f" ± {p['stderr']:.2g}"
        rows.append((n, f"{p['value']:.5g}{se}", p.get("unit") or "", p.get("doc") or ""))
    for n, p in sm.get("derived", {}).items():
        rows.append((n, f"{p['value']:.5g}", p.get("unit") or "", p.get("doc") or ""))
    h = doc.get("hysteresis")
    if h:
        lines.append(f"hysteresis: {h['law']} driven by the {h['drive']}")
        for n, p in h["parameters"].items():
            se = "" if p.get("stderr") is None else f" ± {p['stderr']:.2g}"
            rows.append((n, f"{p['value']:.5g}{se}", p.get("unit") or "", p.get("doc") or ""))
        for k, v in h.get("loop_half_width_N", {}).items():
            rows.append(
                (f"loop half-width ({k})", f"{v:.3g}", "N", h.get("loop_half_width_doc", ""))
            )
    else:
        lines.append("hysteresis: none (the static map alone)")
    y = 0.90
    for ln in lines:
        fig.text(0.03, y, ln, fontsize=10)
        y -= 0.035
    y -= 0.01
    for name, val, unit, what in rows:
        fig.text(0.03, y, name, fontsize=9, family="monospace")
        fig.text(0.25, y, val, fontsize=9, family="monospace")
        fig.text(0.40, y, unit, fontsize=9)
        fig.text(0.48, y, what[:95], fontsize=8, color="0.3")
        y -= 0.028
    y -= 0.02
    fig.text(
        0.03,
        y,
        "runs (nrmse = RMS error / SD of the measured force; floor: the force noise alone)",
        fontsize=10,
    )
    y -= 0.032
    for r in [*doc.get("runs", []), *doc.get("validation", [])]:
        held = (
            f"x = {r['held_position_mm']:.3g} mm"
            if "held_position_mm" in r
            else f"p = {r['muscle_pressure_MPa']:.3g} MPa"
        )
        ratio = r["nrmse"] / max(r.get("noise_floor_nrmse", 0.0), 1e-12)
        fig.text(
            0.03,
            y,
            f"{r.get('role', ''):<15}{r['run'][:28]:<29}{r['test_type']:<10}{held:<15}"
            f"rmse {r['rmse']:7.3g} N  nrmse {r['nrmse']:.4f}  {ratio:5.2f}× floor",
            fontsize=8.5,
            family="monospace",
            color=style.VALIDATION if r.get("role") == "validation" else "0.1",
        )
        y -= 0.026
        if y < 0.04:
            break
    return fig


@style.styled
def loops_figure(doc: dict[str, Any], runs: Sequence[PredictionRun], title: str) -> Figure:
    """Force–pressure loops (isometric, isotonic) or force–contraction loops (isobaric,
    free) of up to six runs: measured (inflating / venting branches) and model."""
    fig = style.new_figure(title)
    nrows, ncols = style.grid_shape(len(runs))
    for ax, pr in zip(style.panel_axes(fig, len(runs), nrows, ncols), runs, strict=True):
        a = pr.arrays
        row = _row(doc, pr)
        kind = row.get("test_type", "isobaric")
        u = a["position"] if kind in ("isobaric", "free") else a["muscle_pressure"]
        sl = style.decimate(len(u), 2500)
        rising = np.gradient(u) >= 0
        for mask, col, lab in ((rising, INFLATING, "rising"), (~rising, VENTING, "falling")):
            m = mask[sl]
            ax.plot(
                u[sl][m],
                a["force"][sl][m],
                ".",
                ms=2.2,
                color=col,
                alpha=0.5,
                label=f"measured, {'pressure' if kind not in ('isobaric', 'free') else 'x'} {lab}",
            )
        ax.plot(u[sl], a["force_model"][sl], "-", lw=0.6, color="0.05", label="model")
        ax.set_xlabel(style.POSITION if kind in ("isobaric", "free") else style.PRESSURE)
        ax.set_ylabel(style.FORCE)
        role = "held out" if pr.role == "validation" else "identification"
        ratio = row.get("nrmse", np.nan) / max(row.get("noise_floor_nrmse", 0.0) or 1e-12, 1e-12)
        ax.set_title(
            f"{pr.attrs.get('run', pr.key)} ({role}): {_held(row, pr)}\n"
            f"rmse {row.get('rmse', np.nan):.3g} N, {ratio:.2f}× noise floor",
            fontsize=9,
        )
        ax.grid(True, alpha=0.3)
    if runs:
        fig.axes[0].legend(loc="best", fontsize=7, markerscale=6)
    return fig


@style.styled
def family_figure(doc: dict[str, Any], runs: Sequence[PredictionRun]) -> Figure:
    """The static map as families of curves: F_s against pressure at each held length
    (with the measured force, thinned), and F_s against contraction at five pressures."""
    # the static maps load the identification's compiled laws: imported where a static
    # report draws them, not by every `pmalab report` that asks whether its input is static
    from pmalab.identify.static.maps import Geometry, get_static_map

    sm = doc["static_map"]
    geo = Geometry(
        length_mm=sm["geometry"].get("length_mm"), diameter_mm=sm["geometry"].get("diameter_mm")
    )
    smap = get_static_map(sm["id"], geo)
    theta = {n: p["value"] for n, p in sm["parameters"].items()}
    fig = style.new_figure("Static map F_s(x, p): families of curves")
    ax1, ax2 = style.panel_axes(fig, 2, 1, 2)
    held = []
    for pr in runs:
        row = _row(doc, pr)
        if "held_position_mm" in row:
            held.append((row["held_position_mm"], pr))
    pmax = max(float(np.max(pr.arrays["muscle_pressure"])) for pr in runs)
    xmax = max(float(np.max(pr.arrays["position"])) for pr in runs)
    pg = np.linspace(0.0, pmax, 100)
    cm = mpl.colormaps["viridis"]
    xs = sorted({round(x, 6) for x, _ in held}) or list(np.linspace(0, max(xmax, 1.0), 4))
    for i, x in enumerate(xs):
        col = cm(i / max(len(xs) - 1, 1))
        for hx, pr in held:
            if round(hx, 6) == x:
                a = pr.arrays
                sl = style.decimate(len(a["force"]), 800)
                ax1.plot(
                    a["muscle_pressure"][sl], a["force"][sl], ".", ms=1.0, color=col, alpha=0.3
                )
        ax1.plot(
            pg,
            smap.force(np.full_like(pg, x), pg, theta),
            "-",
            color=col,
            lw=1.4,
            label=f"x = {x:.3g} mm",
        )
    ax1.set_xlabel(style.PRESSURE)
    ax1.set_ylabel("Static force F_s (N)")
    ax1.set_title("F_s against pressure per held length (dots: measured)", fontsize=9)
    ax1.legend(fontsize=7)
    ax1.grid(True, alpha=0.3)
    xg = np.linspace(min(0.0, min(xs)), max(xmax, max(xs)) * 1.15 + 1e-9, 100)
    for i, p in enumerate(np.linspace(0.2, 1.0, 5) * pmax):
        col = cm(i / 4)
        ax2.plot(
            xg,
            smap.force(xg, np.full_like(xg, p), theta),
            "-",
            color=col,
            lw=1.4,
            label=f"p = {p:.2f} MPa",
        )
    ax2.axhline(0.0, color="0.5", lw=0.6)
    ax2.set_xlabel(style.POSITION)
    ax2.set_ylabel("Static force F_s (N)")
    ax2.set_title("F_s against contraction at five pressures", fontsize=9)
    ax2.legend(fontsize=7)
    ax2.grid(True, alpha=0.3)
    return fig


@style.styled
def residual_figure(doc: dict[str, Any], runs: Sequence[PredictionRun]) -> Figure:
    """Each run's error against pressure, with ±2 noise SDs (the force noise alone)."""
    fig = style.new_figure("Model error per run against pressure (band: ± 2 × the noise floor)")
    n = min(len(runs), 6)
    nrows, ncols = style.grid_shape(n)
    for ax, pr in zip(style.panel_axes(fig, n, nrows, ncols), runs[:n], strict=True):
        a = pr.arrays
        row = _row(doc, pr)
        e = a["force"] - a["force_model"]
        sl = style.decimate(len(e), 2500)
        ax.plot(a["muscle_pressure"][sl], e[sl], ".", ms=1.0, color=style.MEASURED, alpha=0.4)
        sd_noise = row.get("noise_floor_nrmse", 0.0) * float(np.std(a["force"]))
        ax.axhspan(-2 * sd_noise, 2 * sd_noise, color=style.MEASURED_BAND, alpha=0.4, lw=0)
        ax.axhline(0.0, color="0.3", lw=0.6)
        ax.set_xlabel(style.PRESSURE)
        ax.set_ylabel(style.RESIDUAL)
        ax.set_title(f"{pr.attrs.get('run', pr.key)}: {_held(row, pr)}", fontsize=9)
        ax.grid(True, alpha=0.3)
    return fig


def static_plan(path: str) -> ReportPlan:
    """The static report's pages (summary, loops of the identification and held-out runs,
    the static map, the errors) and footer for one ``identify --static`` directory."""
    p = Path(path)
    doc, runs = _load(p)
    pages: list[tuple[str, Callable[[], Figure]]] = [("summary", lambda: summary_figure(doc))]
    ident = [r for r in runs if r.role != "validation"]
    held_out = [r for r in runs if r.role == "validation"]
    for k in range(0, len(ident), 6):
        chunk = ident[k : k + 6]
        pages.append(
            (
                f"loops-{k // 6 + 1}",
                lambda c=chunk: loops_figure(doc, c, "Loops: identification runs"),
            )
        )
    for k in range(0, len(held_out), 6):
        chunk = held_out[k : k + 6]
        pages.append(
            (
                f"held-out-{k // 6 + 1}",
                lambda c=chunk: loops_figure(doc, c, "Loops: held-out runs (predicted)"),
            )
        )
    pages.append(("static-map", lambda: family_figure(doc, runs)))
    pages.append(("errors", lambda: residual_figure(doc, [*held_out, *ident])))
    specs = [PageSpec(slug, slug, lambda i, n, make=make: make()) for slug, make in pages]

    def footer(fig: Figure, i: int, n: int) -> None:
        fig.text(
            0.99,
            0.005,
            f"pmalab static report · {p.name} · page {i}/{n}",
            ha="right",
            va="bottom",
            fontsize=8,
            color="0.4",
        )

    return ReportPlan(specs, f"pmalab static report: {doc.get('model_full', '')}", footer)


def build_static_report(
    path: str | Path,
    out: str | Path,
    force: bool = False,
    *,
    png_dir: str | Path | None = None,
    svg_dir: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    bar: bool = False,
    jobs: int | None = None,
    start_method: str | None = None,
) -> Path:
    """Render the report of one ``identify --static`` directory into the PDF ``out``.

    ``jobs`` worker processes render the pages (default: the CPUs this process may use;
    1 renders in this process); the PDF's pages are the same either way.
    """
    return write_plan(
        static_plan,
        (str(Path(path)),),
        out,
        force,
        subject=STATIC_SUBJECT,
        png_dir=png_dir,
        svg_dir=svg_dir,
        progress=progress,
        bar=bar,
        jobs=jobs,
        start_method=start_method,
    )
