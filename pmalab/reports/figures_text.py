"""Text pages: the title page (what was measured and fitted, timing statistics) and the
datasets/provenance page."""

from __future__ import annotations

import json
import textwrap
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from pmalab.reports import style
from pmalab.reports.figures_parameters import _table


def timing_stats(time: np.ndarray) -> dict[str, float]:
    """Sampling statistics of one time vector (s): duration (s), samples, mean rate (Hz),
    interval jitter (std, ms) and the largest interval (ms)."""
    t = np.asarray(time, dtype=float)
    dt = np.diff(t)
    return {
        "duration_s": float(t[-1] - t[0]),
        "samples": float(t.shape[0]),
        "rate_Hz": float(1.0 / np.mean(dt)) if dt.size else float("nan"),
        "jitter_ms": float(np.std(dt) * 1e3) if dt.size else float("nan"),
        "max_dt_ms": float(np.max(dt) * 1e3) if dt.size else float("nan"),
    }


def flatten(d: Mapping[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    """Nested provenance as ``(dotted.key, short value)`` pairs."""
    out: list[tuple[str, str]] = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out += flatten(v, key + ".")
        else:
            s = v if isinstance(v, str) else json.dumps(v, default=str)
            out.append((key, s if len(s) <= 70 else s[:67] + "…"))
    return out


@style.styled
def title_page_figure(
    *,
    model: str,
    effects: Sequence[str] = (),
    directory: str = "",
    created: str = "",
    version: str = "",
    inputs: Sequence[Mapping[str, Any]] = (),
    datasets: Sequence[Mapping[str, Any]] = (),
    summary: str | None = None,
    contents: Sequence[str] = (),
) -> Figure:
    """Title page: model and effects, source files, a table of the runs with their timing
    statistics (duration, rate, jitter, largest interval), the diagnosis summary and the
    report's contents.

    ``datasets``: dicts with role, label, p, f, waveform and the :func:`timing_stats` keys.
    """
    fig = style.new_figure(None, layout=False)
    fig.text(0.5, 0.96, "Pneumatic muscle identification report", ha="center", va="top",
             fontsize=20, fontweight="bold")
    sub = f"model: {model}" + (f"  +  {', '.join(effects)}" if effects else "  (base model)")
    fig.text(0.5, 0.905, sub, ha="center", va="top", fontsize=13)
    meta = [f"results: {directory}"]
    if created:
        meta.append(f"created: {created}")
    if version:
        meta.append(f"pmalab {version}")
    fig.text(0.5, 0.865, "    ".join(meta), ha="center", va="top", fontsize=9, color="0.3")
    y = 0.82
    if inputs:
        lines = []
        for inp in inputs:
            runs = inp.get("runs") or []
            lines.append(f"{inp.get('file', '?')}: {len(runs)} run(s) "
                         f"{', '.join(map(str, runs[:8]))}{' …' if len(runs) > 8 else ''}")
        if len(lines) > 6:
            lines = [*lines[:5], f"… and {len(lines) - 5} more files"]
        fig.text(0.05, y, "Data files", fontweight="bold", va="top", fontsize=10)
        fig.text(0.05, y - 0.03, "\n".join(lines), va="top", fontsize=9, linespacing=1.4)
        y -= 0.05 + 0.028 * len(lines)
    if datasets:
        rows = list(datasets)[:14]
        h = 0.027 * (len(rows) + 1)
        fig.text(0.05, y, "Runs and sampling", fontweight="bold", va="top", fontsize=10)
        ax = fig.add_axes((0.05, y - 0.02 - h, 0.9, h))
        head = ["role", "run", "p (MPa)", "f (Hz)", "waveform", "duration (s)", "samples",
                "rate (Hz)", "jitter σ(Δt) (ms)", "max Δt (ms)"]
        cells = []
        for r in rows:
            f = r.get("f")
            cells.append([r.get("role", ""), r.get("label", ""), f"{r['p']:.4g}",
                          "—" if f is None else f"{f:g}", r.get("waveform") or "—",
                          f"{r['duration_s']:.2f}", f"{int(r['samples'])}",
                          f"{r['rate_Hz']:.1f}", f"{r['jitter_ms']:.3f}",
                          f"{r['max_dt_ms']:.2f}"])
        _table(ax, cells, head, col_widths=[0.1, 0.2, 0.07, 0.06, 0.08, 0.09, 0.08, 0.08,
                                            0.12, 0.09], row_height=1.3)
        extra = len(datasets) - len(rows)
        y -= 0.07 + h
        if extra > 0:
            fig.text(0.05, y + 0.02, f"… {extra} more runs", fontsize=8.5)
    if summary:
        fig.text(0.05, y, "Diagnosis", fontweight="bold", va="top", fontsize=10)
        wrapped = textwrap.wrap(summary, 150)[:4]
        fig.text(0.05, y - 0.03, "\n".join(wrapped), va="top", fontsize=9, linespacing=1.4)
        y -= 0.06 + 0.028 * len(wrapped)
    if contents:
        fig.text(0.05, max(y, 0.2), "Contents", fontweight="bold", va="top", fontsize=10)
        items = [f"{i + 2:>2}. {c}" for i, c in enumerate(contents)]
        half = (len(items) + 1) // 2
        for col, chunk in enumerate((items[:half], items[half:])):
            fig.text(0.05 + 0.45 * col, max(y, 0.2) - 0.03, "\n".join(chunk), va="top",
                     fontsize=8.5, linespacing=1.35)
    fig.text(0.5, 0.035, "Sign convention: x = contraction in mm (positive = shorter than "
             "nominal), F = tension in N, p = gauge pressure in MPa; residuals are F − F_model.",
             ha="center", fontsize=8, color="0.3")
    return fig


@style.styled
def provenance_figure(inputs: Sequence[Mapping[str, Any]],
                      *, title: str = "Datasets and provenance") -> Figure:
    """The provenance attributes (rig, protocol, timing) of each input file, as text."""
    fig = style.new_figure(title)
    ax = fig.add_subplot()
    ax.axis("off")
    lines: list[str] = []
    for inp in inputs:
        lines.append(f"{inp.get('file', '?')}   runs: {', '.join(map(str, inp.get('runs') or []))}")
        prov = flatten(inp.get("provenance") or {})
        if not prov:
            lines.append("    (no provenance recorded)")
        width = max((len(k) for k, _ in prov), default=0)
        lines += [f"    {k:<{width}}  {v}" for k, v in prov]
        lines.append("")
    max_lines = 56
    col = [lines[i:i + max_lines] for i in range(0, min(len(lines), 2 * max_lines), max_lines)]
    for j, chunk in enumerate(col):
        ax.text(0.0 + 0.5 * j, 1.0, "\n".join(chunk), va="top", family="monospace",
                fontsize=8, transform=ax.transAxes, linespacing=1.25)
    if len(lines) > 2 * max_lines:
        ax.text(0.0, -0.02, f"… {len(lines) - 2 * max_lines} more lines (see the JSON file)",
                fontsize=8, transform=ax.transAxes)
    return fig
