"""Text pages: the title page (what was measured and fitted, timing statistics) and the
datasets/provenance page."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from pmalab.reports import style
from pmalab.reports.figures_parameters import _table
from pmalab.runfile import decode_attr


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


#: vertical space of one text line, as a fraction of the A4-landscape page height
_LINE = {8.5: 8.5 * 1.35 / 72 / 8.27, 9.0: 9.0 * 1.4 / 72 / 8.27}
#: the runs table shows at least this many rows (more when the page has room)
TITLE_MIN_RUNS = 4
#: height of one runs-table row (figure fraction: 8.5 pt text with a little padding)
TITLE_ROW = 0.0215
TITLE_MAX_SUMMARY_LINES = 3


#: how the title page names a run's role
ROLE_NAMES = {"identification": "identification", "validation": "held out"}


def runs_by_role(inp: Mapping[str, Any]) -> str:
    """``identification (2): a, b; held out (1): c`` for one input file (its ``runs`` and
    their ``roles``; a run without a role counts as identification), each run once."""
    roles = inp.get("roles") or {}
    groups: dict[str, list[str]] = {}
    for r in dict.fromkeys(str(r) for r in inp.get("runs") or []):
        role = str(roles.get(r, "identification"))
        groups.setdefault(ROLE_NAMES.get(role, role), []).append(r)
    return "; ".join(f"{name} ({len(rs)}): {', '.join(rs)}" for name, rs in groups.items())


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
    improved_model: str | None = None,
    headline: str | None = None,
) -> Figure:
    """Title page: model and effects, source files, a table of the runs with their timing
    statistics (duration, rate, jitter, largest interval), the diagnosis summary, the
    error fall from the base to the improved model (``headline``) and the report's
    contents.  The runs table takes the room the other blocks leave; longer lists are cut
    (with a note) so nothing overlaps.

    ``datasets``: dicts with role, label, p, f, waveform and the :func:`timing_stats` keys.
    """
    fig = style.new_figure(None, layout=False)
    fig.text(
        0.5,
        0.96,
        "Pneumatic muscle identification report",
        ha="center",
        va="top",
        fontsize=20,
        fontweight="bold",
    )
    sub = f"model: {model}" + (f"  +  {', '.join(effects)}" if effects else "  (base model)")
    if improved_model:
        sub += f"   →   improved: {improved_model}"
    fig.text(0.5, 0.905, sub, ha="center", va="top", fontsize=13)
    meta = [f"results: {directory}"]
    if created:
        meta.append(f"created: {created}")
    if version:
        meta.append(f"pmalab {version}")
    fig.text(0.5, 0.865, "    ".join(meta), ha="center", va="top", fontsize=9, color="0.3")
    y = 0.82

    def heading(text: str) -> None:
        nonlocal y
        fig.text(0.05, y, text, fontweight="bold", va="top", fontsize=10)
        y -= 0.032

    def block(lines: Sequence[str], size: float = 9.0, gap: float = 0.022) -> None:
        nonlocal y
        fig.text(
            0.05,
            y,
            "\n".join(lines),
            va="top",
            fontsize=size,
            linespacing=1.4 if size == 9.0 else 1.35,
        )
        y -= _LINE[size] * len(lines) + gap

    if inputs:
        lines = []
        for inp in inputs:
            line = f"{inp.get('file', '?')}: {runs_by_role(inp)}"
            lines.append(line if len(line) <= 150 else line[:149] + "…")
        if len(lines) > 3:
            lines = [*lines[:2], f"… and {len(lines) - 2} more files"]
        heading("Data files")
        block(lines)
    # room the blocks under the runs table need (figure fraction), so the table can grow
    sum_lines = min(len(style.wrap(summary, 150)), TITLE_MAX_SUMMARY_LINES) if summary else 0
    head_lines = len(style.wrap(headline, 150)) if headline else 0
    below = 0.07
    for n_lines in (sum_lines, head_lines):
        if n_lines:
            below += 0.032 + _LINE[9.0] * n_lines + 0.022
    entries = contents_entries(contents)
    if entries:
        below += 0.032 + _LINE[8.5] * math.ceil(len(entries) / 2)
    if datasets:
        # the table's own margins: heading and the gaps after it (and, when not every run
        # fits, the "more runs" line)
        below += 0.012 + 0.02
        fit = int((y - 0.032 - below) / TITLE_ROW) - 1  # rows under a header row
        if fit < len(datasets):
            fit = int((y - 0.032 - below - _LINE[8.5]) / TITLE_ROW) - 1
        rows = list(datasets)[: max(fit, TITLE_MIN_RUNS)]
        h = TITLE_ROW * (len(rows) + 1)
        heading("Runs and sampling (from the prediction files)")
        ax = fig.add_axes((0.05, y - h, 0.9, h))
        head = [
            "role",
            "run",
            "p (MPa)",
            "f (Hz)",
            "waveform",
            "duration (s)",
            "samples",
            "rate (Hz)",
            "jitter σ(Δt) (ms)",
            "max Δt (ms)",
        ]
        cells = []
        for r in rows:
            f = r.get("f")
            cells.append(
                [
                    r.get("role", ""),
                    r.get("label", ""),
                    f"{r['p']:.4g}",
                    "—" if f is None else f"{f:g}",
                    r.get("waveform") or "—",
                    f"{r['duration_s']:.2f}",
                    f"{int(r['samples'])}",
                    f"{r['rate_Hz']:.1f}",
                    f"{r['jitter_ms']:.3f}",
                    f"{r['max_dt_ms']:.2f}",
                ]
            )
        _table(
            ax,
            cells,
            head,
            col_widths=[0.1, 0.2, 0.07, 0.06, 0.08, 0.09, 0.08, 0.08, 0.12, 0.09],
            row_height=1.05,
        )
        y -= h + 0.012
        extra = len(datasets) - len(rows)
        if extra > 0:
            fig.text(
                0.05,
                y,
                f"… {extra} more run(s) (all in the fit quality table)",
                fontsize=8.5,
                va="top",
            )
            y -= _LINE[8.5]
        y -= 0.02
    if headline:
        heading("Base vs improved model")
        block(style.wrap(headline[:1].upper() + headline[1:], 150))
    if summary:
        heading("Diagnosis")
        wrapped = style.wrap(summary, 150)
        if len(wrapped) > TITLE_MAX_SUMMARY_LINES:
            wrapped = wrapped[:TITLE_MAX_SUMMARY_LINES]
            # cut between words, a number kept with its unit (as the lines were wrapped)
            wrapped[-1] = style.wrap(wrapped[-1], 146)[0] + " …"
        block(wrapped)
    if entries:
        heading("Contents")
        room = max(int((y - 0.07) / _LINE[8.5]), 3)  # lines left above the footer notes
        cols = 2 if len(entries) <= 2 * room else 3
        # a column's width less a gap, in points: an entry is cut (at a word, with "…")
        # only when its drawn text is wider, not by a worst-case count of characters
        width_pt = (0.9 / cols - 0.015) * fig.get_figwidth() * 72
        items = [_fit_text(f"{pages:>5}. {c}", width_pt, 8.5) for pages, c in entries]
        per = -(-len(items) // cols)
        if per > room:
            per = room
            items = [*items[: per * cols - 1], f"… {len(items) - per * cols + 1} more pages"]
        for col in range(cols):
            chunk = items[col * per : (col + 1) * per]
            if chunk:
                fig.text(
                    0.05 + (0.9 / cols) * col,
                    y,
                    "\n".join(chunk),
                    va="top",
                    fontsize=8.5,
                    linespacing=1.35,
                )
    fig.text(
        0.5,
        0.035,
        "Sign convention: x = contraction in mm (positive = shorter than "
        "nominal), F = tension in N, p = gauge pressure in MPa; residuals are F − F_model.",
        ha="center",
        fontsize=8,
        color="0.3",
    )
    return fig


def _text_width_pt(text: str, size: float) -> float:
    """Drawn width of ``text`` (points) in the report's font at ``size`` pt."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    w, _, _ = TextToPath().get_text_width_height_descent(
        text, FontProperties(size=size), ismath=False
    )
    return float(w)


def _fit_text(text: str, width_pt: float, size: float) -> str:
    """``text`` as it is when it fits ``width_pt``, else cut at a word and ended by "…"."""
    if _text_width_pt(text, size) <= width_pt:
        return text
    words = text.split(" ")
    while len(words) > 1:
        words.pop()
        cut = " ".join(words).rstrip(" ,;:—-") + "…"
        if _text_width_pt(cut, size) <= width_pt:
            return cut
    return text


_PART = re.compile(r" \(\d+/\d+\)$")


def contents_entries(titles: Sequence[str], first_page: int = 2) -> list[tuple[str, str]]:
    """The contents as ``(pages, title)``: consecutive pages of one kind are one entry
    (``"4–6"``, ``"Time histories — identification, bouc-wen"``); pages that differ only
    after `` — `` (one per run) are listed as ``"Residual diagnostics (4 runs)"``."""
    out: list[tuple[str, str]] = []
    i = 0
    while i < len(titles):
        full = _PART.sub("", titles[i])
        head = full.split(" — ")[0]
        j = i + 1
        while j < len(titles) and _PART.sub("", titles[j]).split(" — ")[0] == head:
            j += 1
        fulls = {_PART.sub("", t) for t in titles[i:j]}
        pages = str(first_page + i) if j == i + 1 else f"{first_page + i}–{first_page + j - 1}"
        text = full if len(fulls) == 1 else f"{head} ({j - i} runs)"
        out.append((pages, text))
        i = j
    return out


FILE_KEYS = (
    ("created_utc", "recorded"),
    ("protocol_name", "protocol"),
    ("protocol_file", "protocol file"),
    ("rig_spec", "rig spec"),
    ("clock", "clock"),
    ("scheduling", "scheduling"),
    ("sample_rate_Hz", "sample rate (Hz)"),
    ("software", "software"),
    ("software_version", "version"),
    ("seed", "seed"),
    ("command_line", "command"),
)


def _short(v: Any, n: int = 110) -> str:
    s = v if isinstance(v, str) else json.dumps(v, default=str)
    return s if len(s) <= n else s[: n - 1] + "…"


def summarize_provenance(
    inputs: Sequence[Mapping[str, Any]],
) -> tuple[list[tuple[str, list[str]]], list[dict[str, Any]]]:
    """Condense each input file's provenance into a few lines, and one row per run with its
    recorded status and timing (duration, samples, late/missed deadlines, lateness).

    Understands the layout ``{"sha256", "size_bytes", "file_attrs": {...}, "runs": {run:
    {..., "timing": {...}}}}``; any other mapping is shown as its first key/value pairs.
    """
    blocks: list[tuple[str, list[str]]] = []
    rows: list[dict[str, Any]] = []
    for inp in inputs:
        prov = inp.get("provenance") or {}
        if not isinstance(prov, Mapping):
            continue
        file = str(inp.get("file", "?"))
        lines: list[str] = []
        structured = "file_attrs" in prov or "runs" in prov
        if prov.get("sha256"):
            size = prov.get("size_bytes")
            lines.append(
                f"sha256 {str(prov['sha256'])[:16]}…"
                + (f", {float(size) / 1e6:.1f} MB" if size is not None else "")
            )
        fa = prov.get("file_attrs") if structured else prov
        fa = fa if isinstance(fa, Mapping) else {}
        for key, label in FILE_KEYS:
            if key in fa and fa[key] not in (None, "", {}):
                lines.append(f"{label}: {_short(fa[key])}")
        rig = decode_attr(fa.get("rig"), parse_json=True)
        if isinstance(rig, Mapping):
            parts = [
                f"{k}={_short(rig[k], 40)}"
                for k in ("kind", "rig_file", "clock", "seed")
                if k in rig
            ]
            lines.append("rig: " + ", ".join(parts))
        elif isinstance(rig, str) and rig:
            lines.append(f"rig: {_short(rig)}")
        lim = decode_attr(fa.get("limits"), parse_json=True)
        if isinstance(lim, Mapping):
            lines.append("safety limits: " + ", ".join(f"{k} {v}" for k, v in lim.items()))
        if not structured:
            known = {k for k, _ in FILE_KEYS} | {"rig", "limits"}
            rest = [(k, v) for k, v in flatten({k: v for k, v in fa.items() if k not in known})]
            lines += [f"{k}: {v}" for k, v in rest[:10]]
            if len(rest) > 10:
                lines.append(f"… {len(rest) - 10} more attributes")
        blocks.append((file, lines))
        runs_v = prov.get("runs")
        runs: Mapping[str, Any] = runs_v if isinstance(runs_v, Mapping) else {}
        for name in inp.get("runs") or list(runs):
            a = runs.get(name)
            if not isinstance(a, Mapping):
                continue
            tm_v = a.get("timing")
            tm: Mapping[str, Any] = tm_v if isinstance(tm_v, Mapping) else {}
            rows.append(
                {
                    "run": f"{Path(file).name}:{name}",
                    "role": a.get("role", ""),
                    "status": a.get("status", ""),
                    "p": a.get("muscle_pressure_MPa"),
                    "f": a.get("frequency_Hz"),
                    "waveform": a.get("waveform", ""),
                    "cycles": a.get("cycles"),
                    "duration_s": tm.get("duration_s"),
                    "samples": tm.get("n_samples"),
                    "late": tm.get("late"),
                    "missed": tm.get("missed"),
                    "p99_ms": None
                    if tm.get("lateness_p99_s") is None
                    else 1e3 * float(tm["lateness_p99_s"]),
                    "max_ms": None
                    if tm.get("lateness_max_s") is None
                    else 1e3 * float(tm["lateness_max_s"]),
                }
            )
    return blocks, rows


def _cell(v: Any, spec: str = "g") -> str:
    if v is None or v == "":
        return "—"
    if isinstance(v, int | float) and not isinstance(v, bool):
        return format(v, spec)
    return str(v)


@style.styled
def provenance_figure(
    blocks: Sequence[tuple[str, Sequence[str]]],
    rows: Sequence[Mapping[str, Any]] = (),
    *,
    title: str = "Datasets, provenance and recorded timing",
) -> Figure:
    """Provenance of each input file (a few lines each) and a table of its runs with the
    recorded status and timing (see :func:`summarize_provenance`)."""
    fig = style.new_figure(title, layout=False)
    y = 0.92
    lines_left = 22
    for file, lines in blocks:
        if lines_left <= 0:
            fig.text(0.04, y, "… more files (see identification.json inputs)", fontsize=8.5)
            y -= 0.03
            break
        fig.text(0.04, y, file, fontweight="bold", fontsize=10, va="top")
        y -= 0.03
        shown = list(lines[: max(lines_left, 1)])
        wrapped = [w for ln in shown for w in style.wrap(ln, 170, subsequent_indent="    ")]
        if wrapped:
            fig.text(0.05, y, "\n".join(wrapped), fontsize=8.5, va="top", linespacing=1.35)
        y -= 0.0205 * len(wrapped) + 0.025
        lines_left -= len(wrapped)
    if rows:
        head = [
            "run",
            "role",
            "status",
            "p\n(MPa)",
            "f\n(Hz)",
            "waveform",
            "cycles",
            "duration\n(s)",
            "samples",
            "late",
            "missed",
            "lateness\np99 (ms)",
            "lateness\nmax (ms)",
        ]
        cells = [
            [
                r["run"],
                _cell(r["role"]),
                _cell(r["status"]),
                _cell(r["p"], ".4g"),
                _cell(r["f"], "g"),
                _cell(r["waveform"]),
                _cell(r["cycles"], "g"),
                _cell(r["duration_s"], ".2f"),
                _cell(r["samples"], ".0f"),
                _cell(r["late"], ".0f"),
                _cell(r["missed"], ".0f"),
                _cell(r["p99_ms"], ".3f"),
                _cell(r["max_ms"], ".3f"),
            ]
            for r in rows
        ]
        h = min(0.027 * (len(rows) + 2), y - 0.06)
        fig.text(0.04, y, "Runs as recorded", fontweight="bold", fontsize=10, va="top")
        ax = fig.add_axes((0.04, y - 0.03 - h, 0.92, h))
        _table(
            ax,
            cells,
            head,
            col_widths=[
                0.2,
                0.09,
                0.07,
                0.05,
                0.045,
                0.07,
                0.05,
                0.06,
                0.06,
                0.04,
                0.05,
                0.07,
                0.07,
            ],
            row_height=1.25,
        )
    return fig
