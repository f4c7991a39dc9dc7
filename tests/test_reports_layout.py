"""Layout: on every report page no two texts overlap and no text leaves the page; the
base-vs-improved pages (two identification directories) and the hysteretic component."""

from __future__ import annotations

import json

import numpy as np
import pytest
import reports_fixtures as rf
from matplotlib.figure import Figure

from pmalab.identify.headline import error_fall
from pmalab.reports import ReportError, load_report_dir, plan_pages
from pmalab.reports.build import draw_page
from pmalab.reports.figures_signals import LOOP_MAX_POINTS
from pmalab.reports.layout import page_problems, text_problems

COMPARE_PAGES = [
    "Base vs improved: validation error per run, parameter changes",
    "Added effect (asymmetric-hysteresis): parameters ± s.e. against pressure",
    "Base vs improved: measured vs model loops (same |error| scale)",
    "Hysteretic component F − (k·x + c0), base vs improved — p0498",
    "Hysteretic component F − (k·x + c0), base vs improved — p0304",
]


@pytest.fixture(scope="module")
def dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("layout")
    return (rf.write_identification_dir(root / "base"), rf.write_improved_dir(root / "improved"),
            rf.write_diagnosis_dir(root / "diag"))


@pytest.fixture(scope="module")
def pages(dirs):
    return plan_pages(load_report_dir(list(dirs)))


def test_checker_finds_overlaps_and_text_off_the_page():
    fig = Figure(figsize=(6, 4))
    fig.text(0.5, 0.5, "first label")
    fig.text(0.52, 0.5, "second label")  # on top of the first
    fig.text(0.98, 0.9, "runs off the right edge")
    fig.text(0.1, 0.1, "   ")  # empty: ignored
    probs = text_problems(fig)
    assert "'first label' overlaps 'second label'" in probs
    assert "'runs off the right edge' leaves the page" in probs
    assert len(probs) == 2


def test_checker_compares_slanted_tick_labels_as_rotated_boxes():
    """Slanted labels whose bounding boxes overlap but whose glyphs do not are fine; the
    same labels horizontal and crowded are reported."""
    fig = Figure(figsize=(6, 4))
    ax = fig.add_subplot()
    names = [f"campaign.h5:pressure-{i}00kPa" for i in range(1, 9)]
    ax.set_xticks(range(8), names, rotation=60, ha="right", rotation_mode="anchor")
    fig.subplots_adjust(left=0.4, bottom=0.6)
    assert text_problems(fig) == []
    # ... although their axis-aligned bounding boxes do overlap
    boxes = [lb.get_window_extent() for lb in ax.get_xticklabels()]
    assert boxes[0].overlaps(boxes[1])
    ax.set_xticks(range(8), names, rotation=0, ha="center")
    assert any("overlaps" in p for p in text_problems(fig))


def test_every_page_is_free_of_overlapping_or_cut_text(pages, dirs):
    data = load_report_dir(list(dirs))
    bad = {p.title: page_problems(draw_page(p, data, i, len(pages)))
           for i, p in enumerate(pages, 1)}
    bad = {t: v for t, v in bad.items() if v}
    assert not bad, "\n".join(f"{t}: {v[:4]}" for t, v in bad.items())


def test_two_identifications_add_the_base_vs_improved_pages(pages, dirs):
    titles = [p.title for p in pages]
    assert titles[-len(COMPARE_PAGES):] == COMPARE_PAGES
    # the diagnosis pages come first: measure, fit, diagnose, add, see the error fall
    assert titles.index("Effect ranking and ladder") < titles.index(COMPARE_PAGES[0])
    base, imp = (json.loads((d / "identification.json").read_text()) for d in dirs[:2])
    sentence = error_fall(base, imp).sentence()
    fig = pages[titles.index(COMPARE_PAGES[0])].make()
    texts = [t.get_text().replace("\n", " ") for t in fig.findobj(lambda a: hasattr(a, "get_text"))
             if hasattr(a := t, "get_text") and isinstance(a.get_text(), str)]
    assert any(sentence[1:] in t for t in texts)  # the one error-fall figure, word for word
    title_fig = pages[0].make()
    assert any(sentence[1:] in " ".join(t.get_text().split()) for t in title_fig.texts)
    # validation bars: base, improved per run and the mean, from the JSON nrmse values
    ax = next(a for a in fig.axes if a.get_title().startswith("Validation runs"))
    heights = [round(p.get_height(), 6) for p in ax.patches]
    want_b = [v["nrmse"] for v in base["validation"]]
    want_i = [v["nrmse"] for v in imp["validation"]]
    assert heights == [round(x, 6) for x in [*want_b, np.mean(want_b), *want_i, np.mean(want_i)]]


def test_hysteretic_component_subtracts_the_base_linear_part(pages, dirs):
    """Measured F − (k·x + c0) with k, c0 of the base pressure laws at the run's pressure;
    the model curve is drawn over it with the same line removed."""
    base = json.loads((dirs[0] / "identification.json").read_text())
    data = load_report_dir(list(dirs))
    t = next(t for t in data.traces if t.role == "validation" and t.run == "p0498")
    q = base["pressure_fits"]
    k = sum(c * 0.498**j for j, c in enumerate(q["k"]))
    c0 = sum(c * 0.498**j for j, c in enumerate(q["c0"]))
    page = next(p for p in pages if p.title.endswith("— p0498"))
    fig = page.make()
    ax = fig.axes[0]
    measured = ax.lines[0]
    stride = -(-len(t.position) // LOOP_MAX_POINTS)  # the loop's decimation (style.decimate)
    np.testing.assert_allclose(measured.get_xdata(), t.position[::stride])
    np.testing.assert_allclose(measured.get_ydata(),
                               (t.force - (k * t.position + c0))[::stride], rtol=1e-9)
    model = ax.collections[0].get_segments()
    np.testing.assert_allclose([s_[0][1] for s_ in model],
                               (t.force_model - (k * t.position + c0))[::stride][:-1], rtol=1e-9)
    assert measured.get_linewidth() > ax.collections[0].get_linewidth()[0]  # model thinner


def test_a_third_identification_is_refused(tmp_path, dirs):
    third = rf.write_identification_dir(tmp_path / "third")
    with pytest.raises(ReportError, match=r"third/identification\.json: a third "
                                          r"identification\.json"):
        load_report_dir([dirs[0], dirs[1], third])


def test_directories_of_other_recordings_or_given_twice_are_refused(tmp_path, dirs):
    """A wrong directory must not be drawn side by side as if it were the same campaign."""
    with pytest.raises(ReportError, match=r"base: directory given twice: give each once"):
        load_report_dir([dirs[0], dirs[0]])
    other = rf.write_improved_dir(tmp_path / "other")
    doc = json.loads((other / "identification.json").read_text())
    for row in [*doc["runs"], *doc["validation"]]:
        row["file"] = "another-campaign.h5"
    (other / "identification.json").write_text(json.dumps(doc))
    with pytest.raises(ReportError, match=r"other: its identification shares no run with "
                                          r".*base's \(files another-campaign\.h5 against "):
        load_report_dir([dirs[0], other])
    diag = rf.write_diagnosis_dir(tmp_path / "diag", with_predictions=False)
    doc = json.loads((diag / "diagnosis.json").read_text())
    doc["diagnostics"] = {k.replace(k.split(":")[0], "another-campaign.h5"): v
                          for k, v in doc["diagnostics"].items()}
    (diag / "diagnosis.json").write_text(json.dumps(doc))
    with pytest.raises(ReportError, match=r"diag: its diagnosis shares no run with "):
        load_report_dir([dirs[0], diag])
    load_report_dir([dirs[0], dirs[1]])  # the same runs: accepted


def test_runs_that_never_were_in_a_file_still_pair_up(tmp_path):
    """Results saved from Python on in-memory runs ("file": "", diagnosis labels without
    "file:"): the same runs, so the report takes them together."""
    ident = rf.write_identification_dir(tmp_path / "ident")
    doc = json.loads((ident / "identification.json").read_text())
    for row in [*doc["runs"], *doc["validation"]]:
        row["file"] = ""
    (ident / "identification.json").write_text(json.dumps(doc))
    diag = rf.write_diagnosis_dir(tmp_path / "diag", with_predictions=False)
    ddoc = json.loads((diag / "diagnosis.json").read_text())
    ddoc["diagnostics"] = {k.split(":", 1)[1] + "[held-out]": v
                           for k, v in ddoc["diagnostics"].items()}
    (diag / "diagnosis.json").write_text(json.dumps(ddoc))
    data = load_report_dir([ident, diag])
    assert data.diagnosis is not None


def test_a_page_is_checked_in_the_layout_its_pdf_page_has():
    """page_problems draws the page into a PDF, keeps that layout (as the PNG/SVG export
    does) and checks it: the axes stay where the PDF put them, and a text cut at the page's
    edge is still found."""
    from pmalab.reports import style

    fig = style.new_figure("A page")
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1000])
    ax.set_ylabel(style.FORCE)
    assert page_problems(fig) == []
    placed = ax.get_position().bounds
    assert placed[0] > 0.03  # moved right of the figure's edge for the tick labels
    fig.text(0.995, 0.5, "runs off the right edge")
    assert page_problems(fig) == ["'runs off the right edge' leaves the page"]
    assert ax.get_position().bounds == placed  # the kept layout: drawn again, not moved


def test_the_checked_layout_is_the_pdf_pages_layout(pages, dirs):
    """page_problems lays a page out without writing it; the axes land exactly where
    saving the page into a PDF puts them."""
    import io

    import matplotlib as mpl
    from matplotlib.backends.backend_pdf import PdfPages

    from pmalab.reports import style

    data = load_report_dir(list(dirs))
    i = next(k for k, p in enumerate(pages, 1) if p.title.startswith("Measured vs model loops"))
    saved, checked = (draw_page(pages[i - 1], data, i, len(pages)) for _ in range(2))
    with mpl.rc_context(style.RC), PdfPages(io.BytesIO()) as pdf:
        pdf.savefig(saved)
    assert page_problems(checked) == []
    want = [ax.get_position().bounds for ax in saved.axes]
    np.testing.assert_allclose([ax.get_position().bounds for ax in checked.axes], want, atol=1e-9)


def test_layout_check_of_a_missing_directory_is_one_line(tmp_path, capsys):
    """``python -m pmalab.reports.layout DIR`` on a directory that is not there: one line
    naming it, exit 2, no traceback."""
    from pmalab.reports.layout import main

    assert main([str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nowhere: no such directory" in err
