"""Each report figure alone, on small data: the numbers drawn are the numbers given."""

from __future__ import annotations

import numpy as np
import pytest
import reports_fixtures as rf
from matplotlib import rc_context as mpl_rc
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.text import Text

from pmalab.errors import OutputExistsError
from pmalab.reports import ReportError, save_figure
from pmalab.reports import figures as F
from pmalab.reports.build import plan_pages
from pmalab.reports.data import Trace, load_report_dir
from pmalab.reports.figures_text import summarize_provenance
from pmalab.reports.style import MIN_FONT_PT


def _trace(n: int = 50, p: float = 0.4, role: str = "identification") -> Trace:
    tr = rf.synthetic_trace(p, 0.15, n=n)
    return Trace(key="k", role=role, file="a.h5", run="r1", muscle_pressure_MPa=p,
                 frequency_Hz=0.15, waveform="sine", model="bouc-wen", **tr)


def _new_axes():
    return Figure().add_subplot()


def test_error_loop_has_one_segment_per_sample_pair_coloured_by_abs_error():
    t = _trace(50)
    ax = _new_axes()
    lc = F.error_loop(ax, t.position, t.force, t.force_model)
    segs = lc.get_segments()
    assert len(segs) == 49
    err = np.abs(t.force_model - t.force)
    np.testing.assert_allclose(lc.get_array(), 0.5 * (err[:-1] + err[1:]))
    # segments follow the model loop (x, F_model)
    np.testing.assert_allclose(segs[10][0], [t.position[10], t.force_model[10]])
    np.testing.assert_allclose(segs[10][1], [t.position[11], t.force_model[11]])
    # long runs are thinned to at most max_points samples
    long = _trace(5000)
    lc2 = F.error_loop(_new_axes(), long.position, long.force, long.force_model, max_points=2000)
    assert len(lc2.get_segments()) == len(range(0, 5000, 3)) - 1 == 1666


def test_loops_figure_gives_each_run_its_own_error_scale():
    ts = [_trace(80, p) for p in (0.3, 0.45, 0.6)]
    ts[2].force_model = ts[2].force_model + 20.0  # a bad run must not wash out the others
    fig = F.loops_figure(ts, fit_percent=[95.0, None, 80.0])
    lcs = [c for ax in fig.axes if ax.get_label() != "<colorbar>" for c in ax.collections]
    assert len(lcs) == 3
    for lc, t in zip(lcs, ts):
        e = np.abs(t.error)
        assert lc.norm.vmax == pytest.approx(np.percentile(0.5 * (e[:-1] + e[1:]), 98.0))
    assert lcs[2].norm.vmax > 3 * lcs[0].norm.vmax
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert "fit 95.0 %" in titles[0] and f"fit {ts[1].fit_percent:.1f} %" in titles[1]


def test_loops_page_legend_lies_outside_every_panel():
    """One legend for the page, below the panels: inside a panel, "best" could find no place
    free of data and put it across a branch of the loop."""
    from pmalab.reports import style

    fig = F.loops_figure([_trace(80, p) for p in (0.3, 0.45, 0.6, 0.5)])
    with mpl_rc(style.RC):
        style.lay_out(fig)
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert len(panels) == 4 and all(ax.get_legend() is None for ax in panels)
    (leg,) = fig.legends
    assert [t.get_text() for t in leg.get_texts()] == ["measured", "model (colour = |error|)"]
    canvas = FigureCanvasAgg(fig)  # drawn as the PNG export draws it
    canvas.draw()
    renderer = canvas.get_renderer()
    box = leg.get_window_extent(renderer)
    for ax in fig.axes:  # no panel and no colour bar under it
        assert not box.overlaps(ax.get_window_extent(renderer)), ax.get_title()
    assert box.y1 < min(ax.get_window_extent(renderer).y0 for ax in panels)


def test_ladder_plot_y_data_are_the_nrmse_values():
    ladder = rf.diagnosis_doc()["ladder"]
    line = F.plot_ladder(_new_axes(), ladder)
    np.testing.assert_allclose(line.get_ydata(), [0.12, 0.04, 0.037])
    np.testing.assert_array_equal(line.get_xdata(), [0, 1, 2])
    labels = [t.get_text() for t in line.axes.get_xticklabels()]
    assert labels == ["base model", "+ viscous-friction", "+ asymmetric-hysteresis"]


def test_ranking_bars_and_significance_colours():
    ranking = rf.diagnosis_doc()["ranking"]
    before, after = F.plot_ranking(_new_axes(), ranking, ambiguous=["sensor-delay"])
    np.testing.assert_allclose([b.get_width() for b in before], [0.12, 0.12, 0.12])
    np.testing.assert_allclose([b.get_width() for b in after], [0.04, 0.11, 0.118])
    greens = [b.get_facecolor()[1] > 0.5 and b.get_facecolor()[0] < 0.3 for b in after]
    assert greens == [True, False, False]
    # best effect drawn on top
    assert after[0].get_y() > after[1].get_y() > after[2].get_y()
    labels = [t.get_text() for t in before[0].axes.get_yticklabels()]
    assert labels == ["viscous-friction", "asymmetric-hysteresis", "sensor-delay (ambiguous)"]


def test_parameter_vs_pressure_draws_points_and_quadratic():
    ax = _new_axes()
    q = [1.0, -2.0, 3.0]
    F.plot_parameter_vs_pressure(ax, "k", [0.2, 0.4, 0.6], [0.9, 0.7, 1.1], [0.1, None, 0.2],
                                 q, stat={"r2": 0.97, "degree": 2, "method": "per-run"},
                                 unit="N/mm", validation_pressures=[0.5])
    (curve,) = [ln for ln in ax.lines if len(ln.get_xdata()) == 100]
    p = curve.get_xdata()
    np.testing.assert_allclose(curve.get_ydata(), 1 - 2 * p + 3 * p**2)
    assert p.min() < 0.2 and p.max() > 0.6  # spans the identification pressures
    assert ax.get_title() == "k (N/mm)\nquadratic through the points, order 2, R² 0.970"
    pts = next(ln for ln in ax.lines if len(ln.get_xdata()) == 3)
    np.testing.assert_allclose(pts.get_ydata(), [0.9, 0.7, 1.1])


def test_joint_law_is_the_drawn_law_and_an_unreadable_r2_is_never_shown():
    """The joint law (what predictions use) is the solid line; the quadratic through the
    per-run points is dashed; its R² against the per-run values (−100 here) is not shown."""
    ax = _new_axes()
    joint, per_run = [0.86, 0.0, 0.0], [1.0, 0.5, -0.5]
    F.plot_parameter_vs_pressure(
        ax, "beta", [0.2, 0.4, 0.6], [1.03, 1.09, 1.05], [0.06, 0.4, 0.3], joint,
        stat={"r2": -100.2, "degree": 0, "method": "joint", "per_run_quadratic": per_run})
    solid = [ln for ln in ax.lines if len(ln.get_xdata()) == 100 and ln.get_linestyle() == "-"]
    dashed = [ln for ln in ax.lines if ln.get_linestyle() == "--"]
    np.testing.assert_allclose(solid[0].get_ydata(), 0.86)
    p = dashed[0].get_xdata()
    np.testing.assert_allclose(dashed[0].get_ydata(), 1.0 + 0.5 * p - 0.5 * p**2)
    assert solid[0].get_label() == "law used for prediction (joint fit)"
    assert ax.get_title() == "beta\njoint law, order 0"
    assert "R²" not in ax.get_title() and "-100" not in ax.get_title()


def test_coefficients_print_round_off_and_negative_zero_as_zero():
    assert F.coef_text([-0.4047, -22.53, 2.842e-14]) == ["-0.4047", "-22.53", "0"]
    assert F.coef_text([0.8628, 0.0, -0.0]) == ["0.8628", "0", "0"]
    assert F.coef_text([None, 1.5, 0.0]) == ["—", "1.5", "0"]


def test_residual_panels_and_correlation_bounds():
    diag = rf.diagnosis_doc()["diagnostics"]["ident.h5:p4762"]
    fig = F.residual_diagnostics_figure("ident.h5:p4762", diag)
    visible = [ax for ax in fig.axes if ax.get_visible() and ax.get_label() != "<colorbar>"]
    # 7 binned variables less "direction" (the same split as "branch") + ACF + CCF + loop
    # regions + loop phase
    assert len(visible) == 10
    assert not any("direction" in ax.get_title() for ax in visible)
    labels = [ax.get_xlabel() for ax in visible]
    assert "Pressure p − p_nom (kPa)" in labels  # small MPa shown in kPa
    assert "Contraction x (mm)" in labels and labels.count("Lag (s)") == 2
    acf_ax = visible[6]
    assert "lags outside ±" in acf_ax.get_title() and "95 % bound" in acf_ax.get_ylabel()
    assert acf_ax.get_legend() is None  # the bound is named in the title, over no data
    assert "worst region: stretch, high contraction" in fig._suptitle.get_text()
    regions = visible[8]
    np.testing.assert_allclose(regions.images[0].get_array(), [[3.1, 4.0, 6.1], [2.5, 3.0, 3.3]])


def test_region_means_are_written_without_powers_of_ten():
    """A mean residual of -117 N is written '-117' in its heatmap cell ('-1.2e+02' overran
    the cell into its neighbour's text); small means keep two significant digits."""
    from matplotlib.axes import Axes

    from pmalab.reports.figures_diagnosis import plot_regions

    regions = [
        {"branch": "stretch (x falling)", "position": p, "rms": r, "mean": m}
        for p, r, m in (("low", 42.2, 16.4), ("mid", 117.0, -117.3), ("high", 3.1, -0.532))
    ]
    ax = Figure().add_subplot()
    assert isinstance(ax, Axes)
    plot_regions(ax, regions)
    texts = [t.get_text() for t in ax.texts]
    assert texts == ["42.2 N\nmean +16", "117 N\nmean -117", "3.1 N\nmean -0.53"]


def test_correlation_heatmap_outlines_near_collinear_pairs():
    r = rf.identification_doc()[0]["runs"][0]
    fig = F.correlation_figure([{"title": "x", **r["correlation"]}])
    ax = fig.axes[0]
    outlines = [p for p in ax.patches if isinstance(p, Rectangle) and not p.get_fill()]
    assert len(outlines) == 2  # beta-gamma and gamma-beta
    np.testing.assert_allclose(ax.images[0].get_array()[3, 4], 0.998)


def _all_text(fig: Figure) -> list[Text]:
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]


def test_every_page_uses_fonts_of_at_least_8pt(tmp_path):
    d = rf.write_full_dir(tmp_path / "res")
    for page in plan_pages(load_report_dir(d)):
        fig = page.make()
        small = {(t.get_text()[:30], t.get_fontsize()) for t in _all_text(fig)
                 if t.get_fontsize() < MIN_FONT_PT}
        assert not small, f"{page.title}: text below {MIN_FONT_PT} pt: {sorted(small)[:5]}"


def test_save_figure_png_svg_and_no_overwrite(tmp_path):
    fig = F.ladder_figure(rf.diagnosis_doc()["ladder"])
    png = save_figure(fig, tmp_path / "ladder.png")
    svg = save_figure(fig, tmp_path / "sub" / "ladder.svg")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert b"<svg" in svg.read_bytes()[:500]
    with pytest.raises(OutputExistsError):
        save_figure(fig, png)
    save_figure(fig, png, force=True)
    with pytest.raises(ReportError, match="unsupported figure format"):
        save_figure(fig, tmp_path / "ladder.jpg")


def test_standalone_figures_return_figures():
    doc, _ = rf.identification_doc()
    t = _trace(60)
    figs = [
        F.time_history_figure([t]),
        F.validation_figure([_trace(60, 0.5, "validation")], fit_percent=[91.0]),
        F.ranking_figure(rf.diagnosis_doc()["ranking"]),
        F.metrics_table_figure([{**r, "role": "identification"} for r in doc["runs"]]),
        F.parameter_table_figure(doc["parameter_names"], doc["runs"], doc["pressure_fits"]),
        F.title_page_figure(model="duhem"),
        F.provenance_figure(*summarize_provenance(doc["inputs"])),
    ]
    assert all(isinstance(f, Figure) for f in figs)
    table_fig = figs[4]
    cells = table_fig.axes[0].tables[0].get_celld()
    texts = {c.get_text().get_text() for c in cells.values()}
    assert "1 (fixed)" in texts and any(s.startswith("-38.45 ± 0.77") for s in texts)


def test_provenance_summary_structured_and_free_form():
    doc, _ = rf.identification_doc()
    blocks, rows = summarize_provenance(doc["inputs"])
    assert [b[0] for b in blocks] == ["ident.h5", "val.h5"]
    lines = blocks[0][1]
    assert lines[0].startswith("sha256 abababab") and lines[0].endswith("1.2 MB")
    assert "rig: kind=sim, rig_file=sim, seed=0" in lines
    assert "safety limits: max_force_N 2000.0" in lines  # JSON text attr parsed
    assert not any("truth_values" in ln for ln in lines)
    assert [r["run"] for r in rows] == ["ident.h5:p3102", "ident.h5:p4762", "ident.h5:p6000"]
    assert rows[0]["p99_ms"] == pytest.approx(0.02) and rows[0]["samples"] == 6668.0
    # an unstructured provenance mapping is shown as key: value lines, no run rows
    blocks, rows = summarize_provenance([{"file": "x.csv", "provenance": {
        "operator": "A. B.", "rig": "bench 2", "extra": {"a": 1}}}])
    assert blocks == [("x.csv", ["rig: bench 2", "operator: A. B.", "extra.a: 1"])]
    assert rows == []


def test_before_after_uses_the_base_error_scale_for_both_rows():
    base = _trace(120, 0.4, "diagnosis")
    final = _trace(120, 0.4, "diagnosis-final")
    final.force_model = final.force + 0.1 * (base.force_model - base.force)
    fig = F.before_after_figure([(base, final)], final_name="bouc-wen + viscous-friction")
    data_axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    (lc_base,), (lc_final,) = (ax.collections for ax in data_axes)
    assert lc_base.norm is lc_final.norm
    np.testing.assert_allclose(lc_final.get_array(), 0.1 * lc_base.get_array(), rtol=1e-9)
    assert "bouc-wen + viscous-friction" in data_axes[1].get_title()


def test_campaign_figure_sorts_runs_worst_first():
    fig = F.campaign_figure(
        [{"label": "a", "nrmse": 0.1, "nrmse_final": 0.05},
         {"label": "b", "nrmse": 0.3, "nrmse_final": 0.1}],
        rf.diagnosis_doc()["campaign_diagnostics"], final_model="bw + visc")
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["b", "a"]
    heights = [p.get_height() for p in ax.patches]
    np.testing.assert_allclose(heights, [0.3, 0.1, 0.1, 0.05])
    assert len(fig.axes) == 3  # NRMSE bars + pressure level + frequency


def test_contents_group_consecutive_pages_of_one_kind():
    from pmalab.reports.figures_text import contents_entries

    titles = ["Fit quality table", "Time histories — identification (1/2)",
              "Time histories — identification (2/2)", "Residual diagnostics — a (worst 1 of 2)",
              "Residual diagnostics — b (worst 2 of 2)", "Effect ranking and ladder"]
    assert contents_entries(titles) == [
        ("2", "Fit quality table"), ("3–4", "Time histories — identification"),
        ("5–6", "Residual diagnostics (2 runs)"), ("7", "Effect ranking and ladder")]


def test_contents_titles_are_cut_only_when_they_do_not_fit_their_column():
    """The demo's longest contents titles fit a half-page column in full (a count of
    characters cut them two letters short); a title too long for its column is cut at a
    word, and no contents text overlaps another or leaves the page."""
    from pmalab.reports.layout import text_problems

    long_ok = ["Parameters against muscle pressure: per-run fits and the pressure laws",
               "Added effect (asymmetric-hysteresis): parameters ± s.e. against pressure"]
    too_long = "Residual diagnostics, " + "and very long words " * 8 + "end"
    fig = F.title_page_figure(model="bouc-wen", contents=[*long_ok, too_long])
    texts = "\n".join(t.get_text() for t in fig.texts)
    assert all(t in texts for t in long_ok), texts
    cut = next(ln for ln in texts.splitlines() if "Residual diagnostics" in ln)
    assert cut.endswith("…") and "end" not in cut
    assert too_long.startswith(cut[:-1].split(". ", 1)[1] + " ")  # cut between words
    assert text_problems(fig) == []


def test_wrapped_page_text_never_splits_a_number_from_its_unit():
    """A wrapped heading broke '-117' and 'N' across two lines; at every width the page
    text keeps each number with its unit (the other words still wrap)."""
    import itertools
    import re

    from pmalab.reports.style import wrap

    text = (
        "worst region: stretch, high contraction (x 14.7–20.0 mm): rms error 6.1 N (1.5× the "
        "run's 4.2 N), mean -117 N at 2.5 Hz, 350 kPa, 12 %: model tension too low"
    )
    units = ("N", "mm", "Hz", "kPa", "%")
    for width in range(16, 60):  # from the longest bound word on (shorter breaks words)
        lines = wrap(text, width)
        assert len(lines) > 1
        for a, b in itertools.pairwise(lines):
            assert not (re.search(r"\d$", a) and b.split()[0] in units), (width, a, b)
        assert " ".join(lines) == text  # nothing lost or changed


def test_control_metrics_page_notes_keep_numbers_with_units():
    """The control metrics page's notes (the papers' figures) are wrapped as the rest of the
    page text: a figure's number stays with its unit (at every length of the experiment's
    title before them), and the lines stay on the page."""
    import itertools
    import re

    from pmalab.reports.figures_control import ControlFileData, metrics_table_figure
    from pmalab.reports.layout import text_problems

    seeds = {
        "Smith 2019, step response of the antagonistic pair": {
            "classic_overshoot_pct": 31.0, "classic_rise_s": 0.42,
            "sliding_mode_overshoot_pct": 4.5, "sliding_mode_rise_s": 0.61,
            "tracking_error_mm": 0.35, "supply_MPa": 0.6, "hold_error_mm": 0.12,
        }
    }
    unit = re.compile(r"(?:MPa|mm|s|%)(?![\w/])")  # a line that starts with a unit
    for k in range(0, 40, 2):
        f = ControlFileData("x.h5", f"Position square wave {'a' * k}", {"seeds": seeds}, [])
        fig = metrics_table_figure([f], "Control experiments: metrics")
        assert text_problems(fig) == [], k
        lines = []
        for t in fig.texts:
            text = t._get_wrapped_text() if t.get_wrap() else t.get_text()  # as drawn
            lines += text.split("\n")
        assert any("supply 0.6" in ln for ln in lines), lines
        for a, b in itertools.pairwise(lines):
            assert not (re.search(r"\d$", a) and unit.match(b)), (k, a, b)


def test_a_cut_title_page_summary_keeps_numbers_with_units():
    """The diagnosis summary on the title page is cut after three lines with '…': the cut
    falls between words, never between a number and its unit (at every position)."""
    import re

    for k in range(210, 226):  # k one-letter words: '-117 N' ends up about the cut
        summary = "w " * k + "mean -117 N at 2.5 Hz, " + "and more words after it " * 12
        fig = F.title_page_figure(model="bouc-wen", summary=summary)
        (last,) = [ln for t in fig.texts for ln in t.get_text().split("\n") if ln.endswith("…")]
        assert not re.search(r"\d …$", last), (k, last)
        assert len(last) <= 150 and " ".join(last[:-2].split()) in " ".join(summary.split())


def test_wrapped_page_text_keeps_compound_units_with_their_numbers():
    """Compound units (a stiffness in N/mm, a drift in N/s or %/h, a damping in N·s/mm)
    stay with their numbers as the simple ones do."""
    import itertools
    import re

    from pmalab.reports.style import wrap

    text = (
        "k·x + c0 with k = 4.2 N/mm, c0 = 12.5 N; the zero drifts 8 N/s (3.1 %/h) and the "
        "damping is 0.12 N·s/mm at 12 mm/s, the stiffness 0.8 N/mm² over the run"
    )
    unit = re.compile(r"(?:N|mm|%)(?:[/·][\w²%]+)*(?![\w/·²])")
    for width in range(18, 70):
        lines = wrap(text, width)
        for a, b in itertools.pairwise(lines):
            assert not (re.search(r"\d$", a) and unit.match(b)), (width, a, b)
        assert " ".join(lines) == text
