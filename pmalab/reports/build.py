"""Assembling the multi-page PDF report from a result directory.

:func:`plan_pages` decides which pages exist (pages of absent parts are skipped, never
left blank); :func:`build_report` renders them one at a time into a PDF (and optionally
PNG/SVG files), writing to a temporary file that replaces ``out`` only when complete.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib as mpl
from matplotlib.figure import Figure

from pmalab.identify.headline import error_fall, worst_runs
from pmalab.identify.messages import is_detail, is_note, prefixed, read_messages
from pmalab.reports import style
from pmalab.reports.data import IMPROVED, ReportData, Trace, load_report_dir
from pmalab.reports.errors import ReportError
from pmalab.reports.figures_active import active_figure, has_active_rounds
from pmalab.reports.figures_compare import (
    compare_figure,
    hysteresis_component_figure,
    linear_component,
)
from pmalab.reports.figures_diagnosis import (
    campaign_figure,
    effects_figure,
    residual_diagnostics_figure,
)
from pmalab.reports.figures_laws import (
    LAWS_PER_PAGE,
    held_out_keys,
    laws_figure,
    laws_loops_figure,
)
from pmalab.reports.figures_parameters import (
    WARNINGS_LINES_PER_COLUMN,
    bullet_lines,
    correlation_figure,
    metrics_table_figure,
    parameter_table_figure,
    parameters_vs_pressure_figure,
    table_page_warning_capacity,
    warnings_figure,
)
from pmalab.reports.figures_signals import (
    before_after_figure,
    loops_figure,
    position_validation_figure,
    time_history_figure,
    validation_figure,
)
from pmalab.reports.figures_text import (
    provenance_figure,
    summarize_provenance,
    timing_stats,
    title_page_figure,
)
from pmalab.reports.figures_trajectory import trajectory_figure, trajectory_table_figure
from pmalab.reports.pdf import PageSpec, ReportPlan, write_plan

TIME_PER_PAGE = 3
LOOPS_PER_PAGE = 6
VALIDATION_PER_PAGE = 2
PARAMS_PER_PAGE = 9
TABLE_RUNS_PER_PAGE = 7
CORR_PER_PAGE = 6
MAX_RESIDUAL_PAGES = 4
BEFORE_AFTER_RUNS = 3
PROVENANCE_ROWS_PER_PAGE = 16
KEY_RUNS = 3
#: held-out runs whose loops are drawn law beside law (those that separate the laws most)
LAWS_LOOP_RUNS = 3


@dataclass
class Page:
    """One report page: a title (for the contents and progress lines), a file-name slug
    (for PNG/SVG export) and a function that draws it."""

    title: str
    slug: str
    make: Callable[[], Figure]


def _chunks(seq: Sequence[Any], n: int) -> list[Sequence[Any]]:
    return [seq[i : i + n] for i in range(0, len(seq), n)]


def _part(i: int, n: int) -> str:
    return f" ({i + 1}/{n})" if n > 1 else ""


def _key(file: str, run: str) -> tuple[str, str]:
    return (Path(file).name, run)


def _ordered(traces: list[Trace], rows: Sequence[dict]) -> tuple[list[Trace], list[float | None]]:
    """Traces in the order of the JSON rows (then any others by pressure), with the JSON's
    fit % for each (None where the trace has no JSON row)."""
    by_key = {_key(t.file, t.run): t for t in traces}
    out, fits, used = [], [], set()
    for r in rows:
        t = by_key.get(_key(r["file"], r["run"]))
        if t is not None and id(t) not in used:
            out.append(t)
            fits.append(r.get("fit_percent"))
            used.add(id(t))
    rest = sorted((t for t in traces if id(t) not in used), key=lambda t: t.muscle_pressure_MPa)
    return out + rest, fits + [None] * len(rest)


def _units(doc: dict) -> dict[str, str]:
    u = doc.get("parameter_units")
    return {str(k): str(v) for k, v in u.items()} if isinstance(u, dict) else {}


def plan_pages(data: ReportData) -> list[Page]:
    """The report's pages, in order, for what the directory holds."""
    ident, diag = data.identification, data.diagnosis
    pages: list[Page] = []
    # identification runs by pressure level (stable: equal pressures keep their order)
    id_rows: list[dict] = (
        sorted(ident["runs"], key=lambda r: r["muscle_pressure_MPa"]) if ident else []
    )
    val_rows: list[dict] = list(ident.get("validation") or []) if ident else []

    # several laws on the same runs (identify --model a,b,c): ranked, then law beside law
    if data.laws:
        pages += _laws_pages(data)

    # datasets/provenance
    inputs = list(ident.get("inputs") or []) if ident else []
    if any(inp.get("provenance") for inp in inputs):
        blocks, prov_rows = summarize_provenance(inputs)
        pc = _chunks(prov_rows, PROVENANCE_ROWS_PER_PAGE) or [[]]
        for i, chunk in enumerate(pc):
            title = "Datasets, provenance and recorded timing" + _part(i, len(pc))
            pages.append(
                Page(
                    title,
                    f"provenance-{i + 1}",
                    lambda b=blocks if i == 0 else [], c=chunk, t=title: provenance_figure(
                        b, c, title=t
                    ),
                )
            )

    # fit metrics (validation rows borrow waveform/frequency from their traces)
    tr_by_key = {_key(t.file, t.run): t for t in data.traces}
    for r in val_rows:
        t = tr_by_key.get(_key(r["file"], r["run"]))
        if t is not None:
            r.setdefault("waveform", t.waveform)
            r.setdefault("frequency_Hz", t.frequency_Hz)
    if id_rows or val_rows:
        rows = [{**r, "role": "identification"} for r in id_rows] + [
            {**r, "role": "validation"} for r in val_rows
        ]
        for i, chunk in enumerate(_chunks(rows, 18)):
            pages.append(
                Page(
                    "Fit quality table" + _part(i, math.ceil(len(rows) / 18)),
                    f"metrics-{i + 1}",
                    lambda c=chunk: metrics_table_figure(c),
                )
            )

    # time histories and loops: identification runs, else the diagnosis base model's runs
    id_traces, id_fits = _ordered(data.traces_with_role("identification"), id_rows)
    model = data.model or "model"
    what = f"identification, {model}"
    if not id_traces:
        id_traces, id_fits = _ordered(data.traces_with_role("diagnosis"), [])
        what = f"base model {model} (diagnosis)"
    th = _chunks(id_traces, TIME_PER_PAGE)
    for i, chunk in enumerate(th):
        title = f"Time histories — {what}" + _part(i, len(th))
        pages.append(
            Page(title, f"time-{i + 1}", lambda c=chunk, t=title: time_history_figure(c, title=t))
        )
    lp = list(zip(_chunks(id_traces, LOOPS_PER_PAGE), _chunks(id_fits, LOOPS_PER_PAGE)))
    for i, (chunk, fits) in enumerate(lp):
        title = f"Measured vs model loops per pressure level — {what}" + _part(i, len(lp))
        pages.append(
            Page(
                title,
                f"loops-{i + 1}",
                lambda c=chunk, f=fits, t=title: loops_figure(c, title=t, fit_percent=f),
            )
        )

    # parameters
    if ident and id_rows and ident["parameter_names"]:
        names = list(ident["parameter_names"])
        units = _units(ident)
        fits = ident.get("pressure_fits") or {}
        stats = ident.get("pressure_fit_stats") or {}
        states = list(ident.get("state_parameters") or ["h0"])
        vps = [float(v["muscle_pressure_MPa"]) for v in val_rows]
        pc = _chunks(names, PARAMS_PER_PAGE)
        for i, chunk in enumerate(pc):
            title = (
                "Parameters against muscle pressure: per-run fits and the pressure laws"
                + _part(i, len(pc))
            )
            pages.append(
                Page(
                    title,
                    f"parameters-{i + 1}",
                    lambda c=chunk, t=title: _parameter_page(ident, id_rows, c, vps, t),
                )
            )
        # long records: the model along each run (fatigue, creep), plot then table
        fixed_all = [
            n for n in ident["parameter_names"] if all(n in (r.get("fixed") or []) for r in id_rows)
        ]
        for j, tr in enumerate(ident.get("trajectory") or []):
            tt = f"Parameter trajectory along {tr.get('run', '')}: drift over the record"
            pages.append(
                Page(
                    tt,
                    f"trajectory-{j + 1}",
                    lambda tr=tr, t=tt: trajectory_figure(
                        tr, units=units, fixed=fixed_all, title=t
                    ),
                )
            )
            tt2 = f"Parameter trajectory along {tr.get('run', '')}: windows and trends"
            pages.append(
                Page(
                    tt2,
                    f"trajectory-table-{j + 1}",
                    lambda tr=tr, t=tt2: trajectory_table_figure(
                        tr, units=units, fixed=fixed_all, title=t
                    ),
                )
            )
        # typed messages (identification.json "messages"); an older file's plain
        # "warnings" list reads as warnings
        msgs: list[str] = (
            [*read_messages(ident["messages"])]
            if ident.get("messages")
            else list(ident.get("warnings") or [])
        )
        for r in id_rows:  # run messages, the method's details left out
            run_msgs: list[str] = (
                [*read_messages(r["messages"])]
                if r.get("messages")
                else list(r.get("warnings") or [])
            )
            head = f"{r['run']} (p = {r['muscle_pressure_MPa']:.3f} MPa): "
            msgs += [prefixed(head, m) for m in run_msgs]
        msgs = [m for m in msgs if not is_detail(m)]
        # what to check first, then what was done (the terminal's warning:/note: split)
        warnings = [f"warning: {w}" for w in msgs if not is_note(w)] + [
            f"note: {w}" for w in msgs if is_note(w)
        ]
        fixed_all = [n for n in names if all(n in (r.get("fixed") or []) for r in id_rows)]
        tc = _chunks(id_rows, TABLE_RUNS_PER_PAGE)
        for i, chunk in enumerate(tc):
            title = "Identified parameters (value ± standard error) and identifiability" + _part(
                i, len(tc)
            )
            pages.append(
                Page(
                    title,
                    f"parameter-table-{i + 1}",
                    lambda c=chunk, t=title: parameter_table_figure(
                        names,
                        c,
                        fits,
                        stats,
                        units=units,
                        warnings=warnings,
                        state_parameters=states,
                        fixed_all=fixed_all,
                        title=t,
                    ),
                )
            )
        # warnings that do not fit under the tables get pages of their own
        if len(bullet_lines(warnings)) > table_page_warning_capacity(len(names), bool(fits)):
            per_page, groups, cur, n = 2 * WARNINGS_LINES_PER_COLUMN, [], [], 0
            for w in warnings:
                k = len(bullet_lines([w], 95))
                if cur and n + k > per_page:
                    groups.append(cur)
                    cur, n = [], 0
                cur.append(w)
                n += k
            groups.append(cur)
            for i, g in enumerate(groups):
                title = "Identifiability and fit warnings (all)" + _part(i, len(groups))
                pages.append(
                    Page(
                        title, f"warnings-{i + 1}", lambda g=g, t=title: warnings_figure(g, title=t)
                    )
                )
        corr = [
            {
                "title": f"{r['run']}  (p = {r['muscle_pressure_MPa']:.3f} MPa)",
                "names": r["correlation"]["names"],
                "matrix": r["correlation"]["matrix"],
            }
            for r in id_rows
            if r.get("correlation") and r["correlation"]["names"]
        ]
        cc = _chunks(corr, CORR_PER_PAGE)
        for i, chunk in enumerate(cc):
            title = "Parameter correlation (identifiability); |ρ| > 0.95 outlined" + _part(
                i, len(cc)
            )
            pages.append(
                Page(
                    title,
                    f"correlation-{i + 1}",
                    lambda c=chunk, t=title: correlation_figure(c, title=t),
                )
            )

    # validation overlays
    val_traces, val_fits = _ordered(data.traces_with_role("validation"), val_rows)
    vc = list(zip(_chunks(val_traces, VALIDATION_PER_PAGE), _chunks(val_fits, VALIDATION_PER_PAGE)))
    by_position = bool(ident) and ident.get("output") == "position"
    for i, (chunk, fits_) in enumerate(vc):
        if by_position and all(t.position_model is not None for t in chunk):
            title = (
                "Validation: simulated position (output error), free run from the "
                "measured force" + _part(i, len(vc))
            )
            pages.append(
                Page(
                    title,
                    f"validation-{i + 1}",
                    lambda c=chunk, t=title: position_validation_figure(c, title=t),
                )
            )
            continue
        title = "Validation: pressure-quadratic model, free-run prediction" + _part(i, len(vc))
        pages.append(
            Page(
                title,
                f"validation-{i + 1}",
                lambda c=chunk, f=fits_, t=title: validation_figure(c, fit_percent=f, title=t),
            )
        )

    # diagnosis
    if diag:
        diags = diag.get("diagnostics") or {}
        final_name = _final_model_name(diag)
        per_run = [
            {"label": k, "nrmse": d.get("nrmse"), "nrmse_final": d.get("nrmse_final")}
            for k, d in diags.items()
        ]
        if any(r["nrmse"] is not None for r in per_run) or diag.get("campaign_diagnostics"):
            pages.append(
                Page(
                    "Where the base model fails across the campaign",
                    "campaign",
                    lambda: campaign_figure(
                        [r for r in per_run if r["nrmse"] is not None],
                        diag.get("campaign_diagnostics"),
                        final_model=final_name,
                    ),
                )
            )
        # residual panels for the worst runs (one definition with `pmalab diagnose`)
        drawable = [
            (k, diags[k])
            for k in worst_runs(diags)
            if diags[k].get("binned") or diags[k].get("acf") or diags[k].get("ccf_input")
        ]
        shown = drawable[:MAX_RESIDUAL_PAGES]
        for i, (label, d) in enumerate(shown):
            title = f"Residual diagnostics — {label}"
            if len(drawable) > len(shown):
                title += f" (worst {i + 1} of {len(drawable)} runs)"
            pages.append(
                Page(
                    title,
                    f"residuals-{i + 1}",
                    lambda lb=label, dd=d: residual_diagnostics_figure(lb, dd),
                )
            )
        # base vs final model, when the ladder added effects
        if final_name is not None:
            finals = {_key(t.file, t.run): t for t in data.traces_with_role("diagnosis-final")}
            order = {k: i for i, k in enumerate(worst_runs(diags))}
            pairs = [
                (t, finals[_key(t.file, t.run)])
                for t in data.traces_with_role("diagnosis")
                if _key(t.file, t.run) in finals
            ]
            pairs.sort(key=lambda p: (order.get(p[0].label, len(order)), -p[0].nrmse))
            if pairs:
                chosen = pairs[:BEFORE_AFTER_RUNS]
                pages.append(
                    Page(
                        "The error falling: base model vs final model",
                        "before-after",
                        lambda c=chosen: before_after_figure(
                            c, base_name=f"base {diag['model']}", final_name=final_name
                        ),
                    )
                )
        if diag["ranking"] or diag.get("ladder"):
            pages.append(
                Page(
                    "Effect ranking and ladder",
                    "effects",
                    lambda: effects_figure(
                        diag["ranking"],
                        diag.get("ladder") or [],
                        ambiguous=diag.get("ambiguous") or [],
                        suggested_experiment=diag.get("suggested_experiment"),
                        summary=diag.get("summary"),
                        model=diag["model"],
                    ),
                )
            )
        if has_active_rounds(diag):
            pages.append(
                Page(
                    "Active identification: experiments run and the ranking after each",
                    "active",
                    lambda: active_figure(diag),
                )
            )

    if ident and data.improved:
        pages += _comparison_pages(data)

    contents = [p.title for p in pages]
    pages.insert(0, Page("Title page", "title", lambda: _title_page(data, contents)))
    return pages


def _laws_pages(data: ReportData) -> list[Page]:
    """The laws table with every held-out run's error per law on one scale, then, for the
    held-out runs that separate the laws most, their loops law beside law (one error
    scale).  The pages after these are the best law's."""
    entries, floor = data.laws, data.laws_noise_floor
    pages = [
        Page(
            f"Hysteresis laws compared on the held-out runs (best first: {entries[0].law})",
            "laws",
            lambda: laws_figure(entries, floor),
        )
    ]
    groups = _chunks(list(range(len(entries))), LAWS_PER_PAGE)
    for key in held_out_keys(entries, LAWS_LOOP_RUNS):
        for gi, idx in enumerate(groups):
            title = f"Loops of every law on one error scale — held-out {key[1]}" + _part(
                gi, len(groups)
            )
            pages.append(
                Page(
                    title,
                    f"laws-loops-{key[1]}-{gi + 1}",
                    lambda k=key, ix=idx, t=title: laws_loops_figure(
                        [entries[i] for i in ix], k, colour_offset=ix[0], title=t
                    ),
                )
            )
    return pages


def model_name(doc: dict) -> str:
    """``bouc-wen + asymmetric-hysteresis`` (or the bare law) of an identification."""
    return " + ".join([str(doc.get("model", "")), *(str(e) for e in doc.get("effects") or [])])


def _comparison_pages(data: ReportData) -> list[Page]:
    """Base vs improved identification: the error per run with the one error-fall figure,
    the added effect's parameters, loops and the hysteretic component side by side."""
    base, imp = data.identification or {}, data.improved or {}
    bname, iname = model_name(base), model_name(imp)
    fall = error_fall(base, imp)
    headline = fall.sentence() if fall else "no validation run was predicted by both models"
    pages = [
        Page(
            "Base vs improved: validation error per run, parameter changes",
            "compare",
            lambda: compare_figure(base, imp, headline, base_name=bname, improved_name=iname),
        )
    ]
    added = [
        n for n in imp.get("parameter_names") or [] if n not in (base.get("parameter_names") or [])
    ]
    rows = sorted(imp.get("runs") or [], key=lambda r: r["muscle_pressure_MPa"])
    if added and rows:
        vps = [float(v["muscle_pressure_MPa"]) for v in imp.get("validation") or []]
        pc = _chunks(added, PARAMS_PER_PAGE)
        for i, chunk in enumerate(pc):
            title = (
                f"Added effect ({', '.join(imp.get('effects') or []) or 'improved model'}): "
                "parameters ± s.e. against pressure" + _part(i, len(pc))
            )
            pages.append(
                Page(
                    title,
                    f"added-parameters-{i + 1}",
                    lambda c=chunk, t=title: _parameter_page(imp, rows, c, vps, t),
                )
            )
    # the runs the error-fall figure is measured on, else the identification runs
    imp_tr = {
        _key(t.file, t.run): t
        for t in data.traces
        if t.role in (IMPROVED + "validation", IMPROVED + "identification")
    }
    val_traces, _ = _ordered(data.traces_with_role("validation"), base.get("validation") or [])
    key_runs = [t for t in val_traces if _key(t.file, t.run) in imp_tr][:KEY_RUNS]
    if not key_runs:
        ids = [t for t in data.traces_with_role("identification") if _key(t.file, t.run) in imp_tr]
        key_runs = sorted(ids, key=lambda t: -t.nrmse)[:KEY_RUNS]
    pairs = [(t, imp_tr[_key(t.file, t.run)]) for t in key_runs]
    if pairs:
        pages.append(
            Page(
                "Base vs improved: measured vs model loops (same |error| scale)",
                "compare-loops",
                lambda: before_after_figure(
                    pairs,
                    base_name=f"base: {bname}",
                    final_name=f"improved: {iname}",
                    title="Base vs improved: measured vs model loops (same |error| scale per run)",
                ),
            )
        )
    for i, (b, m) in enumerate(pairs):
        lin = linear_component(base, b)
        if lin is None:
            continue
        title = f"Hysteretic component F − (k·x + c0), base vs improved — {b.run}"
        pages.append(
            Page(
                title,
                f"hysteresis-{i + 1}",
                lambda b=b, m=m, lin=lin, t=title: hysteresis_component_figure(
                    b, m, lin, base_name=bname, improved_name=iname, title=t
                ),
            )
        )
    return pages


def _parameter_page(
    doc: dict, rows: list[dict], names: Sequence[str], vps: list[float], title: str
) -> Figure:
    """Parameters against pressure for ``names`` of one identification document."""
    nan = float("nan")
    stats = doc.get("pressure_fit_stats") or {}
    return parameters_vs_pressure_figure(
        names,
        [float(r["muscle_pressure_MPa"]) for r in rows],
        {n: [r["parameters"].get(n, nan) for r in rows] for n in names},
        {n: [(r.get("stderr") or {}).get(n) for r in rows] for n in names},
        doc.get("pressure_fits") or {},
        {n: (stats.get(n) or {}) for n in names},
        units=_units(doc),
        validation_pressures=vps,
        state_parameters=list(doc.get("state_parameters") or ["h0"]),
        fixed=[n for n in names if rows and all(n in (r.get("fixed") or []) for r in rows)],
        title=title,
    )


def _final_model_name(diag: dict) -> str | None:
    """``bouc-wen + viscous-friction`` when the ladder added effects, else None; the law is
    the one in force at the ladder's last step (a step may change it: ``maxwell-slip +
    pressure-variation``)."""
    ladder = diag.get("ladder") or []
    if len(ladder) < 2:
        return None
    law = ladder[-1].get("law") or diag["model"]
    effects = [e for e in ladder[-1].get("effects") or [] if e]
    if not effects and "law" not in ladder[-1]:
        effects = [s.get("added") for s in ladder[1:] if s.get("added")]
    return f"{law} + {', '.join(str(e) for e in effects)}" if effects else str(law)


def _title_page(data: ReportData, contents: list[str]) -> Figure:
    doc = data.identification or data.diagnosis or {}
    datasets = []
    order = ("identification", "validation", "diagnosis")
    # one row per run: final-model copies and runs already listed under another role
    # (an identify and a diagnose directory merged) are left out
    shown: list[Trace] = []
    listed: set[tuple[str, str]] = set()
    for t in sorted(
        (t for t in data.traces if t.role in order),
        key=lambda t: (order.index(t.role), t.muscle_pressure_MPa),
    ):
        if _key(t.file, t.run) not in listed:
            listed.add(_key(t.file, t.run))
            shown.append(t)
    for t in shown:
        datasets.append(
            {
                "role": t.role,
                "label": t.label,
                "p": t.muscle_pressure_MPa,
                "f": t.frequency_Hz,
                "waveform": t.waveform,
                **timing_stats(t.time),
            }
        )
    effects = list(doc.get("effects") or [])
    summary = (data.diagnosis or {}).get("summary")
    inputs = _with_roles(data.identification) or _inputs_by_role(data)
    headline = None
    if data.identification and data.improved:
        fall = error_fall(data.identification, data.improved)
        headline = fall.sentence() if fall else None
    return title_page_figure(
        model=data.model,
        effects=effects,
        improved_model=model_name(data.improved) if data.improved else None,
        headline=headline,
        directory=_directories(data),
        created=str(doc.get("created", "")),
        version=str(doc.get("pmalab_version", "")),
        inputs=inputs,
        datasets=datasets,
        summary=summary,
        contents=contents,
    )


def _with_roles(ident: dict | None) -> list[dict]:
    """identification.json's ``inputs``, each with the ``roles`` of its runs (files written
    without them: a run the document validates on is held out)."""
    if not ident:
        return []
    held = {
        (Path(str(v.get("file", ""))).name, v.get("run")) for v in ident.get("validation") or []
    }
    out = []
    for inp in ident.get("inputs") or []:
        name = Path(str(inp.get("file", ""))).name
        roles = dict(inp.get("roles") or {})
        for r in inp.get("runs") or []:
            roles.setdefault(r, "validation" if (name, r) in held else "identification")
        out.append({**inp, "roles": roles})
    return out


def _inputs_by_role(data: ReportData) -> list[dict]:
    """The data files and their runs by role (``{"file", "runs", "roles"}``, as
    identification.json's ``inputs``) when no identification directory lists them: the
    diagnosis's split of the campaign (identification runs and held-out runs), else the
    traces, each run once (a diagnosis holds a held-out run for the base and the final
    model; both are the run's validation)."""
    by_file: dict[str, dict] = {}

    def add(file: str, run: str, role: str) -> None:
        d = by_file.setdefault(file or "?", {"file": file or "?", "runs": [], "roles": {}})
        if run not in d["roles"]:
            d["runs"].append(run)
            d["roles"][run] = role

    st = (data.diagnosis or {}).get("settings") or {}
    ident_runs, held_out = st.get("identification_runs"), st.get("held_out")
    if isinstance(ident_runs, list) and isinstance(held_out, list):
        for role, labels in (("identification", ident_runs), ("validation", held_out)):
            for label in labels:
                file, sep, run = str(label).rpartition(":")
                add(file if sep else "", run, role)
        return list(by_file.values())
    order = ("identification", "validation", "diagnosis", "diagnosis-final")
    for t in sorted(data.traces, key=lambda t: order.index(t.role) if t.role in order else 9):
        role = "identification" if t.role.endswith("identification") else "validation"
        add(Path(t.file).name, t.run, role)
    return list(by_file.values())


def _directories(data: ReportData, limit: int = 110) -> str:
    """The result directories for the title page: full paths, or their names when the
    paths would not fit on one line."""
    dirs = data.directories or [data.directory]
    full = ", ".join(str(d) for d in dirs)
    return full if len(full) <= limit else ", ".join(d.name for d in dirs)


def _slug(s: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", s.lower()).strip("-")


def _names(data: ReportData) -> str:
    return " + ".join(d.name for d in data.directories or [data.directory])


def draw_page(page: Page, data: ReportData, i: int, n: int) -> Figure:
    """Page ``i`` of ``n`` as it goes into the PDF (with its footer)."""
    fig = page.make()
    _footer(fig, data, i, n)
    return fig


def _footer(fig: Figure, data: ReportData, i: int, n: int) -> None:
    with mpl.rc_context(style.RC):
        fig.text(
            0.99,
            0.005,
            f"pmalab report · {data.model} · {_names(data)} · page {i}/{n}",
            ha="right",
            va="bottom",
            fontsize=8,
            color="0.4",
        )


def build_report(
    directory: str | Path | Sequence[str | Path],
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
    """Render the report of result directories into one PDF (``pmalab report``).

    Parameters
    ----------
    directory
        A result directory, or several merged (e.g. the base identification, the improved
        one and the diagnosis: drawn side by side on one error scale).
    out
        The PDF to write.
    force
        Overwrite existing outputs.
    png_dir, svg_dir
        Also export every page as ``NN-<slug>.png`` / ``.svg`` there.
    progress
        Receives one line per page written (``pmalab report -v`` prints them).
    bar
        Draw a progress bar on stderr (the CLI's default on a terminal).
    jobs
        Worker processes rendering the pages (default: the CPUs this process may use; 1
        renders in this process).  The PDF's pages are the same either way.
    start_method
        The multiprocessing start method (default: the platform's).

    Returns
    -------
    Path
        The PDF written.

    Raises
    ------
    pmalab.reports.errors.ReportError
        A directory that is not a result directory, or contents the report cannot read.
    pmalab.errors.OutputExistsError
        ``out`` exists and ``force`` is false.
    """
    out = Path(out)
    if out.suffix.lower() != ".pdf":
        raise ReportError(f"{out}: the report must be a .pdf file")
    if out.is_dir():
        raise ReportError(f"{out}: is a directory")
    plan, args, subject = _plan_for(
        [directory] if isinstance(directory, str | Path) else list(directory)
    )
    return write_plan(
        plan,
        args,
        out,
        force,
        subject=subject,
        png_dir=png_dir,
        svg_dir=svg_dir,
        progress=progress,
        bar=bar,
        jobs=jobs,
        start_method=start_method,
    )


def _plan_for(inputs: list[str | Path]) -> tuple[Callable[..., ReportPlan], tuple, str]:
    """The planning function, its (picklable) arguments and the PDF's subject for
    ``inputs``: a static characterization alone, antagonistic-pair run files, control run
    files (``pmalab control``), else result directories; mixtures are refused."""
    from pmalab.reports.control import control_plan, is_control_file
    from pmalab.reports.pair import is_pair_file, pair_plan
    from pmalab.reports.static import STATIC_SUBJECT, is_static_dir, static_plan

    statics = [p for p in inputs if is_static_dir(p)]
    if statics:
        if len(inputs) != 1:
            raise ReportError(
                f"{statics[0]}: a static characterization (identify --static) is reported "
                "on its own: give its directory alone"
            )
        return static_plan, (str(Path(statics[0])),), STATIC_SUBJECT
    pairs = [p for p in inputs if is_pair_file(p)]
    if pairs:
        if len(pairs) != len(inputs):
            raise ReportError(
                f"{inputs[0] if inputs[0] not in pairs else inputs[-1]}: give antagonistic-"
                "pair run files without other inputs"
            )
        return pair_plan, ([str(p) for p in pairs],), ""
    controls = [p for p in inputs if is_control_file(p)]
    if controls:
        if len(controls) != len(inputs):
            raise ReportError(
                f"{inputs[0] if inputs[0] not in controls else inputs[-1]}: give "
                "control run files (pmalab control) without result directories"
            )
        return control_plan, ([str(p) for p in controls],), ""
    return report_plan, ([str(p) for p in inputs],), "pneumatic muscle identification"


def report_plan(inputs: list[str]) -> ReportPlan:
    """The pages of the report of the result directories ``inputs`` (merged), as
    :func:`plan_pages` plans them, each drawn with its footer (:func:`draw_page`)."""
    data = load_report_dir(inputs[0] if len(inputs) == 1 else inputs)
    specs = [
        PageSpec(_slug(p.slug), p.title, lambda i, n, p=p: draw_page(p, data, i, n))
        for p in plan_pages(data)
    ]
    return ReportPlan(specs, f"pmalab report: {data.model} ({_names(data)})")
