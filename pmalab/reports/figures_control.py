"""Figures of a control experiment: responses, errors, pressures, gains, metrics table.

One experiment file (``pmalab control``) holds one run per controller; every figure
overlays them in the same colours.  Units: time s, position mm (contraction from the
manipulator's home), pressure MPa, force N, gains in their loop's units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from pmalab.reports import style

#: one colour per controller, the same on every page
CONTROLLER_COLOURS = {"pid": "0.35", "sn-pid": "#1f77b4", "rbf-pid": "#d62728"}
REFERENCE = "#2ca02c"
MAX_POINTS = 4000


@dataclass
class ControlRunData:
    """One recorded control run (datasets in their stored units)."""

    name: str
    attrs: dict[str, Any]
    status: str
    data: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def controller(self) -> str:
        return str(self.attrs.get("controller", self.name))

    @property
    def loop(self) -> str:
        return str(self.attrs.get("loop", "position"))

    @property
    def metrics(self) -> dict[str, Any]:
        m = self.attrs.get("metrics")
        return m if isinstance(m, dict) else {}


@dataclass
class ControlFileData:
    """One ``pmalab control`` output file (an experiment)."""

    path: str
    title: str
    attrs: dict[str, Any]
    runs: list[ControlRunData]


def _colour(c: str) -> str:
    return CONTROLLER_COLOURS.get(c, "#9467bd")


def _plot(ax, t: np.ndarray, y: np.ndarray, **kw) -> None:
    s = style.decimate(t.size, MAX_POINTS)
    ax.plot(t[s], y[s], **kw)


@style.styled
def response_figure(f: ControlFileData) -> Figure:
    """Response and reference, tracking error, muscle pressure (measured and p_d)."""
    runs = f.runs
    pos = runs[0].loop == "position"
    fig = style.new_figure(f"{f.title}: response, error and pressure")
    axes = fig.subplots(3, 1, sharex=True)
    yname, rname = (
        ("position", "position_reference")
        if pos
        else ("muscle_pressure", "muscle_pressure_reference")
    )
    unit = "mm" if pos else "MPa"
    ref_drawn = False
    for r in runs:
        d = r.data
        if "time" not in d or yname not in d or rname not in d:
            continue
        t = d["time"]
        if not ref_drawn:
            _plot(axes[0], t, d[rname], color=REFERENCE, lw=1.4, ls="--", label="reference")
            ref_drawn = True
        lbl = r.controller + ("" if r.status == "completed" else f" ({r.status})")
        _plot(axes[0], t, d[yname], color=_colour(r.controller), label=lbl)
        _plot(axes[1], t, d[rname] - d[yname], color=_colour(r.controller), label=r.controller)
        _plot(
            axes[2],
            t,
            d["muscle_pressure"],
            color=_colour(r.controller),
            label=f"{r.controller}: measured",
        )
        if pos and "muscle_pressure_reference" in d:
            _plot(
                axes[2],
                t,
                d["muscle_pressure_reference"],
                color=_colour(r.controller),
                ls=":",
                lw=0.8,
                label=f"{r.controller}: desired p_d",
            )
    axes[0].set_ylabel("Contraction x (mm)" if pos else style.PRESSURE)
    axes[1].set_ylabel(f"Error r − y ({unit})")
    axes[1].axhline(0.0, color="0.5", lw=0.6)
    axes[2].set_ylabel(style.PRESSURE)
    axes[2].set_xlabel(style.TIME)
    axes[0].legend(loc="upper right", ncols=2)
    axes[2].legend(loc="upper right", ncols=3, fontsize=8)
    return fig


GAIN_LABELS = {
    "outer_kp": "outer Kp (N/mm)",
    "outer_ki": "outer Ki (N/(mm·s))",
    "outer_kd": "outer Kd (N·s/mm)",
    "inner_kp": "inner Kp (MPa/MPa)",
    "inner_ki": "inner Ki (1/s)",
    "inner_kd": "inner Kd (s)",
}


@style.styled
def gains_figure(f: ControlFileData) -> Figure:
    """Every controller's gains over time (adaptive ones move, the classic is flat).

    A pressure-loop experiment shows the inner loop's three only (the outer loop does not
    run).  Each panel spans at least ±5 % of its gain, so round-off never looks like
    adaptation.
    """
    pressure = bool(f.runs) and f.runs[0].loop == "pressure"
    keys = [k for k in GAIN_LABELS if not (pressure and k.startswith("outer"))]
    title = f"{f.title}: controller gains over time"
    fig = style.new_figure(title + (" (pressure loop: inner gains only)" if pressure else ""))
    axes = style.panel_axes(fig, len(keys), 2 if len(keys) > 3 else 1, 3)
    for ax, key in zip(axes, keys):
        lo, hi = math.inf, -math.inf
        for r in f.runs:
            g = r.data.get(f"gains/{key}")
            if g is None or "time" not in r.data or g.size == 0:
                continue
            _plot(ax, r.data["time"], g, color=_colour(r.controller), label=r.controller)
            lo, hi = min(lo, float(np.nanmin(g))), max(hi, float(np.nanmax(g)))
        if math.isfinite(lo):
            mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
            half = max(half * 1.1, 0.05 * abs(mid), 1e-12)
            ax.set_ylim(mid - half, mid + half)
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        ax.set_title(GAIN_LABELS[key])
        ax.set_xlabel(style.TIME)
    if axes:
        axes[0].legend(loc="best")
    return fig


def _fmt(v: Any, spec: str = ".3g", unit: str = "") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    return format(v, spec) + (f" {unit}" if unit else "")


METRIC_COLUMNS = (
    "experiment",
    "controller",
    "status",
    "overshoot",
    "rise",
    "settling (2 %)",
    "steady-state error",
    "RMS error",
)


def metrics_rows(files: Sequence[ControlFileData]) -> list[list[str]]:
    rows = []
    for f in files:
        for r in f.runs:
            m = r.metrics
            u = str(m.get("unit", ""))
            settle = _fmt(m.get("settling_time_s"), ".2f", "s")
            if m.get("kind") == "square" and m.get("settled") is False:
                settle = "never settles"
            rows.append(
                [
                    f.title,
                    r.controller,
                    "ok" if r.status == "completed" else r.status[:40],
                    _fmt(m.get("overshoot_pct"), ".1f", "%"),
                    _fmt(m.get("rise_time_s"), ".2f", "s"),
                    settle,
                    _fmt(m.get("steady_state_error"), ".3g", u),
                    _fmt(m.get("rms_error"), ".3g", u),
                ]
            )
    return rows


#: unit suffixes of the papers' figure keys in the experiments file
_SEED_UNITS = {"_pct": " %", "_s": " s", "_mm": " mm", "_MPa": " MPa"}


def _seed_figure(key: str, value: float) -> str:
    """``classic_overshoot_pct = 31`` → ``"classic overshoot 31 %"``."""
    for suffix, unit in _SEED_UNITS.items():
        if key.endswith(suffix):
            return f"{key[: -len(suffix)].replace('_', ' ')} {value:g}{unit}"
    return f"{key.replace('_', ' ')} {value:g}"


def seed_rows(files: Sequence[ControlFileData]) -> list[str]:
    """The papers' figures stored with each experiment, as text lines."""
    lines = []
    for f in files:
        seeds = f.attrs.get("seeds")
        if not isinstance(seeds, dict):
            continue
        for paper, figs in seeds.items():
            if isinstance(figs, dict) and figs:
                txt = ", ".join(
                    _seed_figure(k, v) for k, v in figs.items() if isinstance(v, int | float)
                )
                lines.append(f"{f.title} — {paper}: {txt}")
    return lines


@style.styled
def metrics_table_figure(files: Sequence[ControlFileData], title: str) -> Figure:
    """The step/tracking metrics of every run (python-control step_info definitions) and
    the seeds' reported figures."""
    fig = style.new_figure(title, layout=False)
    rows = metrics_rows(files)
    ax = fig.add_axes((0.03, 0.30, 0.94, 0.62))
    ax.axis("off")
    if rows:
        tab = ax.table(
            cellText=rows, colLabels=list(METRIC_COLUMNS), loc="upper center", cellLoc="center"
        )
        tab.auto_set_font_size(False)
        tab.set_fontsize(8)
        tab.scale(1.0, 1.25)
    notes = [
        "Metrics as python-control's step_info, per step of the square (y0 = value before "
        "the step): rise 10→90 %, settling within 2 % of the final value (mean of the "
        "step's last 0.1 s), overshoot relative to it (largest over the steps); "
        "steady-state error |r − y_final| (largest); RMS error over the run.",
        "Papers' figures (measured on their rig; not the same manipulator):",
    ]
    notes += seed_rows(files) or ["(none stored with these experiments)"]
    # wrapped as every page's text (a number kept with its unit), to the page's width
    lines = [w for note in notes for w in style.wrap(note, 185)]
    fig.text(0.03, 0.27, "\n".join(lines), va="top", fontsize=8)
    return fig


# --------------------------------------------------------------------------- sim-to-real
def _reference_text(r: ControlRunData) -> str:
    p = r.attrs.get("protocol")
    return str(p.get("reference", "")) if isinstance(p, dict) else ""


def sim_to_real_pairs(
    files: Sequence[ControlFileData],
) -> list[tuple[ControlRunData, ControlRunData, str]]:
    """(rig run, model-in-the-loop run, reference) for every controller and reference
    recorded both on a rig and with the identified model as plant (root attr ``plant``)."""
    plant = [(r, f) for f in files if f.attrs.get("plant") for r in f.runs]
    rig = [(r, f) for f in files if not f.attrs.get("plant") for r in f.runs]
    out = []
    for rp, _ in plant:
        for rr, _ in rig:
            if rr.controller == rp.controller and _reference_text(rr) == _reference_text(rp):
                out.append((rr, rp, _reference_text(rr)))
                break
    return out


def _m(r: ControlRunData, key: str, spec: str, unit: str) -> str:
    return _fmt(r.metrics.get(key), spec, unit)


@style.styled
def sim_to_real_figure(pairs: Sequence[tuple[ControlRunData, ControlRunData, str]]) -> Figure:
    """Model in the loop against the rig, per controller: responses overlaid (rig solid,
    model dashed, same colour), tracking errors, and the metrics side by side."""
    fig = style.new_figure("Sim-to-real: the identified model as plant vs the rig")
    n = len(pairs)
    gs = fig.add_gridspec(n + 1, 2, height_ratios=[*([1.0] * n), 0.32 + 0.12 * n])
    for i, (rr, rp, ref) in enumerate(pairs):
        ax = fig.add_subplot(gs[i, 0])
        ae = fig.add_subplot(gs[i, 1], sharex=ax)
        col = _colour(rr.controller)
        pos = rr.loop == "position"
        yname, rname = (
            ("position", "position_reference")
            if pos
            else ("muscle_pressure", "muscle_pressure_reference")
        )
        unit = "mm" if pos else "MPa"
        d = rr.data
        if "time" in d and rname in d:
            _plot(ax, d["time"], d[rname], color=REFERENCE, lw=1.2, ls="--", label="reference")
        for r, ls, what in ((rr, "-", "rig"), (rp, (0, (4, 2)), "model in the loop")):
            dd = r.data
            if "time" not in dd or yname not in dd or rname not in dd:
                continue
            _plot(ax, dd["time"], dd[yname], color=col, ls=ls, lw=1.1, label=what)
            _plot(ae, dd["time"], dd[rname] - dd[yname], color=col, ls=ls, lw=1.0, label=what)
        ax.set_ylabel(f"{rr.controller}\n{'x' if pos else 'p'} ({unit})")
        ae.set_ylabel(f"error r − y ({unit})")
        ae.axhline(0.0, color="0.5", lw=0.6)
        ax.set_title(ref, fontsize=9, loc="left")
        ax.legend(loc="upper right", fontsize=7, ncols=3)
        if i == n - 1:
            ax.set_xlabel(style.TIME)
            ae.set_xlabel(style.TIME)
    at = fig.add_subplot(gs[n, :])
    at.axis("off")
    rows = []
    for rr, rp, ref in pairs:
        u = str(rr.metrics.get("unit", ""))
        for r, what in ((rr, "rig"), (rp, "model in the loop")):
            rows.append(
                [
                    rr.controller,
                    ref,
                    what,
                    _m(r, "overshoot_pct", ".1f", "%"),
                    _m(r, "settling_time_s", ".2f", "s"),
                    _m(r, "rms_error", ".3g", u),
                    _m(r, "max_error", ".3g", u),
                ]
            )
    tab = at.table(
        cellText=rows,
        colLabels=[
            "controller",
            "reference",
            "plant",
            "overshoot",
            "settling",
            "RMS error",
            "max error",
        ],
        loc="center",
        cellLoc="center",
    )
    tab.auto_set_font_size(False)
    tab.set_fontsize(8)
    return fig
