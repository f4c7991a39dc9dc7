"""The PDF report: page plan, rendering back with pypdfium2 (page count, no blank page),
the CLI verb, no overwrite without --force, one clear error per bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import reports_fixtures as rf

from pmalab.cli import main
from pmalab.errors import OutputExistsError
from pmalab.reports import ReportError, build_report, load_report_dir, plan_pages

pdfium = pytest.importorskip("pypdfium2")

A4_LANDSCAPE_PT = (841.9, 595.3)


def render_pages(pdf: Path, scale: float = 0.4) -> list[np.ndarray]:
    """Every page of a PDF as an RGB array (white background)."""
    doc = pdfium.PdfDocument(str(pdf))
    try:
        out = []
        for i in range(len(doc)):
            page = doc[i]
            w, h = page.get_size()
            assert (w, h) == pytest.approx(A4_LANDSCAPE_PT, abs=1.0)
            out.append(np.asarray(page.render(scale=scale).to_pil().convert("RGB")))
        return out
    finally:
        doc.close()


def ink_fraction(img: np.ndarray) -> float:
    """Fraction of pixels that are not (nearly) white."""
    return float(np.mean(np.min(img, axis=2) < 235))


@pytest.fixture(scope="module")
def full_report(tmp_path_factory):
    d = rf.write_full_dir(tmp_path_factory.mktemp("full") / "res")
    lines: list[str] = []
    # two page workers under the platform's default start method (the suite's other
    # reports render in process: conftest)
    out = build_report(d, d.parent / "report.pdf", progress=lines.append, jobs=2)
    return d, out, lines


FULL_PAGES = [
    "Title page",
    "Datasets, provenance and recorded timing",
    "Fit quality table",
    "Time histories — identification, bouc-wen",
    "Measured vs model loops per pressure level — identification, bouc-wen",
    "Parameters against muscle pressure: per-run fits and the pressure laws",
    "Identified parameters (value ± standard error) and identifiability",
    "Parameter correlation (identifiability); |ρ| > 0.95 outlined",
    "Validation: pressure-quadratic model, free-run prediction",
    "Where the base model fails across the campaign",
    "Residual diagnostics — ident.h5:p3102",
    "Residual diagnostics — ident.h5:p4762",
    "Effect ranking and ladder",
]


def test_full_report_pages_render_and_none_is_blank(full_report):
    _, out, lines = full_report
    imgs = render_pages(out)
    assert len(imgs) == len(FULL_PAGES) == 13
    for i, img in enumerate(imgs):
        frac = ink_fraction(img)
        assert frac > 0.01, f"page {i + 1} ({FULL_PAGES[i]}) looks blank: {frac:.4f}"
    # one progress line per page, in order
    assert lines == [f"page {i}/13: {t}" for i, t in enumerate(FULL_PAGES, 1)]
    # Type 3 fonts: matplotlib 3.11 garbles ligatures ("fi") in Type 42 subsets across pages
    raw = out.read_bytes()
    assert b"/Type3" in raw and b"/FontFile2" not in raw


def test_page_plan_matches_contents(full_report):
    d, _, _ = full_report
    assert [p.title for p in plan_pages(load_report_dir(d))] == FULL_PAGES


def test_identification_only(tmp_path):
    d = rf.write_identification_dir(tmp_path / "id")
    titles = [p.title for p in plan_pages(load_report_dir(d))]
    assert titles == FULL_PAGES[:9]
    # one pressure level and no validation: no validation page, one loop, one time page
    d1 = rf.write_identification_dir(tmp_path / "id1", pressures=[0.4762], validation=[])
    titles = [p.title for p in plan_pages(load_report_dir(d1))]
    assert "Validation: pressure-quadratic model, free-run prediction" not in titles
    assert sum(t.startswith("Time histories") for t in titles) == 1
    assert len(titles) == 8


def test_diagnosis_only_report(tmp_path):
    d = rf.write_diagnosis_dir(tmp_path / "diag")
    out = build_report(d, tmp_path / "diag.pdf")
    imgs = render_pages(out)
    titles = [p.title for p in plan_pages(load_report_dir(d))]
    assert titles == ["Title page", "Time histories — base model bouc-wen (diagnosis)",
                      "Measured vs model loops per pressure level — base model bouc-wen "
                      "(diagnosis)",
                      "Where the base model fails across the campaign",
                      "Residual diagnostics — ident.h5:p3102",
                      "Residual diagnostics — ident.h5:p4762",
                      "The error falling: base model vs final model",
                      "Effect ranking and ladder"]
    assert len(imgs) == 8
    assert min(ink_fraction(i) for i in imgs) > 0.01
    # without predictions.h5 the signal pages are skipped, not blank
    d2 = rf.write_diagnosis_dir(tmp_path / "diag2", with_predictions=False)
    assert len(plan_pages(load_report_dir(d2))) == 5


def test_no_overwrite_without_force_and_atomic_replace(tmp_path, full_report):
    d, _, _ = full_report
    dst = tmp_path / "r.pdf"
    dst.write_bytes(b"old")
    with pytest.raises(OutputExistsError, match=r"r\.pdf: already exists"):
        build_report(d, dst)
    assert dst.read_bytes() == b"old"
    # a bad directory with --force leaves the old PDF untouched and no temporary file
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "identification.json").write_text("{")
    with pytest.raises(ReportError):
        build_report(bad, dst, force=True)
    assert dst.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad", "r.pdf"]


def test_cli_report_with_png_export(tmp_path, capsys):
    d = rf.write_diagnosis_dir(tmp_path / "diag", with_predictions=False)
    out, png = tmp_path / "out" / "rep.pdf", tmp_path / "png"
    assert main(["report", str(d), "--out", str(out), "--png", str(png), "-v"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[:5] == ["page 1/5: Title page",
                           "page 2/5: Where the base model fails across the campaign",
                           "page 3/5: Residual diagnostics — ident.h5:p3102",
                           "page 4/5: Residual diagnostics — ident.h5:p4762",
                           "page 5/5: Effect ranking and ladder"]
    assert printed[-1] == f"report written: {out}"
    assert sorted(p.name for p in png.iterdir()) == [
        "01-title.png", "02-campaign.png", "03-residuals-1.png", "04-residuals-2.png",
        "05-effects.png"]
    # second time: refused (exit 2, one line), then --force works; piped (not a terminal)
    # and without -v it prints no progress, only where the PDF is
    assert main(["report", str(d), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already exists (use --force" in err[0]
    assert main(["report", str(d), "--out", str(out), "--force"]) == 0
    cap = capsys.readouterr()
    assert cap.out.splitlines() == [f"report written: {out}"] and cap.err == ""
    assert main(["report", str(d), "--out", str(out), "--force", "--quiet", "--svg",
                 str(tmp_path / "svg")]) == 0
    assert capsys.readouterr().out == ""
    assert len(list((tmp_path / "svg").glob("*.svg"))) == 5


# --------------------------------------------------------------------------- bad input
def _mutate_json(d: Path, name: str, fn) -> None:
    p = d / name
    obj = json.loads(p.read_text())
    fn(obj)
    p.write_text(json.dumps(obj))


@pytest.fixture
def ident_dir(tmp_path):
    return rf.write_identification_dir(tmp_path / "res")


@pytest.mark.parametrize("mutate, needle", [
    (lambda o: o["runs"][0].pop("nrmse"), "identification.json: runs[0].nrmse: missing key"),
    (lambda o: o.pop("model"), "identification.json: model: missing key"),
    (lambda o: o["runs"][1]["parameters"].pop("k"),
     "identification.json: runs[1].parameters.k: missing key"),
    (lambda o: o["runs"][0]["parameters"].__setitem__("A", "big"),
     'identification.json: runs[0].parameters.A: expected a number, got "big"'),
    (lambda o: o.__setitem__("runs", {}), "identification.json: runs: expected a list, got an object"),
    (lambda o: o["runs"][2]["correlation"]["matrix"].pop(),
     "identification.json: runs[2].correlation.matrix: has 4 rows for 5 names"),
    (lambda o: o["validation"][1].pop("muscle_pressure_MPa"),
     "identification.json: validation[1].muscle_pressure_MPa: missing key"),
])
def test_bad_identification_json(ident_dir, mutate, needle):
    _mutate_json(ident_dir, "identification.json", mutate)
    with pytest.raises(ReportError) as ei:
        build_report(ident_dir, ident_dir / "r.pdf")
    assert needle in str(ei.value) and "\n" not in str(ei.value)
    assert not (ident_dir / "r.pdf").exists()


@pytest.mark.parametrize("mutate, needle", [
    (lambda o: o["ranking"][0].pop("significant"),
     "diagnosis.json: ranking[0].significant: missing key"),
    (lambda o: o["ladder"][1].__setitem__("nrmse", None),
     "diagnosis.json: ladder[1].nrmse: expected a number, got null"),
    (lambda o: o["diagnostics"]["ident.h5:p4762"]["binned"]["velocity"]["mean"].pop(),
     "diagnosis.json: diagnostics.ident.h5:p4762.binned.velocity.mean: has 8 values for 9"),
])
def test_bad_diagnosis_json(tmp_path, mutate, needle):
    d = rf.write_diagnosis_dir(tmp_path / "d", with_predictions=False)
    _mutate_json(d, "diagnosis.json", mutate)
    with pytest.raises(ReportError, match=None) as ei:
        build_report(d, tmp_path / "r.pdf")
    assert needle in str(ei.value)


def test_missing_and_empty_directories(tmp_path):
    with pytest.raises(ReportError, match="nope: no such directory"):
        build_report(tmp_path / "nope", tmp_path / "r.pdf")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReportError, match=r"holds neither identification\.json nor diagnosis"):
        build_report(tmp_path / "empty", tmp_path / "r.pdf")
    (tmp_path / "empty" / "diagnosis.json").write_text('{"model": "duhem", ')
    with pytest.raises(ReportError, match=r"diagnosis.json: malformed JSON at line 1"):
        build_report(tmp_path / "empty", tmp_path / "r.pdf")
    (tmp_path / "empty" / "diagnosis.json").write_text("[1, 2]")
    with pytest.raises(ReportError, match="expected a JSON object at the top level"):
        build_report(tmp_path / "empty", tmp_path / "r.pdf")
    with pytest.raises(ReportError, match=r"r.txt: the report must be a .pdf file"):
        build_report(tmp_path / "empty", tmp_path / "r.txt")
    (tmp_path / "dir.pdf").mkdir()
    with pytest.raises(ReportError, match=r"dir\.pdf: is a directory"):
        build_report(tmp_path / "empty", tmp_path / "dir.pdf", force=True)
    (tmp_path / "file").write_text("x")
    good = rf.write_diagnosis_dir(tmp_path / "good", with_predictions=False)
    with pytest.raises(ReportError, match=r"file/r\.pdf: cannot write"):
        build_report(good, tmp_path / "file" / "r.pdf")


@pytest.mark.parametrize("mutate, needle", [
    (lambda f: f.attrs.__setitem__("format", "pmalab.run"),
     "predictions.h5: format: expected 'pmalab.predictions', got 'pmalab.run'"),
    (lambda f: f["runs/ident__p3102"].__delitem__("force_model"),
     "predictions.h5: /runs/ident__p3102/force_model: missing dataset"),
    (lambda f: f["runs/val__p0304"].attrs.__delitem__("role"),
     "predictions.h5: /runs/val__p0304: attr 'role': expected a string"),
])
def test_bad_predictions(ident_dir, mutate, needle):
    with h5py.File(ident_dir / "predictions.h5", "a") as f:
        mutate(f)
    with pytest.raises(ReportError) as ei:
        load_report_dir(ident_dir)
    assert needle in str(ei.value)


def test_unequal_prediction_lengths(ident_dir):
    with h5py.File(ident_dir / "predictions.h5", "a") as f:
        g = f["runs/ident__p4762"]
        data = g["force"][()][:-3]
        del g["force"]
        g.create_dataset("force", data=data)
    with pytest.raises(ReportError, match=r"/runs/ident__p4762: datasets have unequal lengths"):
        load_report_dir(ident_dir)


def test_cli_error_is_one_line(tmp_path, capsys):
    d = rf.write_diagnosis_dir(tmp_path / "d", with_predictions=False)
    shutil.copy(d / "diagnosis.json", d / "identification.json")
    assert main(["report", str(d), "--out", str(tmp_path / "r.pdf")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"pmalab report: error: {d / 'identification.json'}: parameter_names: "
                   "missing key"]


def test_many_runs_are_split_over_pages(tmp_path):
    ps = [0.1, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6]
    d = rf.write_identification_dir(tmp_path / "many", pressures=ps, validation=rf.VAL_RUNS * 1)
    titles = [p.title for p in plan_pages(load_report_dir(d))]
    assert [t for t in titles if t.startswith("Time histories")] == [
        f"Time histories — identification, bouc-wen ({i}/3)" for i in (1, 2, 3)]
    assert sum(t.startswith("Measured vs model loops") for t in titles) == 2
    assert sum(t.startswith("Identified parameters") for t in titles) == 2
    assert sum(t.startswith("Parameter correlation") for t in titles) == 2
    assert sum(t.startswith("Parameters against") for t in titles) == 1


def test_identify_and_diagnose_directories_merge_into_one_report(tmp_path):
    di = rf.write_identification_dir(tmp_path / "ident")
    dd = rf.write_diagnosis_dir(tmp_path / "diag")
    with h5py.File(dd / "predictions.h5", "a") as f:  # a role the report does not draw
        f["runs/diag__p3102"].attrs["role"] = "scratch"
    data = load_report_dir([di, dd])
    assert data.directories == [di, dd]
    titles = [p.title for p in plan_pages(data)]
    assert titles[:9] == FULL_PAGES[:9]
    assert titles[9:] == ["Where the base model fails across the campaign",
                           "Residual diagnostics — ident.h5:p3102",
                           "Residual diagnostics — ident.h5:p4762",
                           "The error falling: base model vs final model",
                           "Effect ranking and ladder"]
    # two directories holding the same document: one clear error
    dd2 = rf.write_diagnosis_dir(tmp_path / "diag2", with_predictions=False)
    with pytest.raises(ReportError, match=r"diag2/diagnosis\.json: a second diagnosis\.json"):
        load_report_dir([dd, dd2])


def test_long_warning_lists_get_their_own_pages(tmp_path):
    d = rf.write_identification_dir(tmp_path / "w")
    _mutate_json(d, "identification.json", lambda o: o.__setitem__(
        "warnings", [f"warning number {i}: rho(beta,gamma) = 0.99" for i in range(150)]))
    titles = [p.title for p in plan_pages(load_report_dir(d))]
    warn = [t for t in titles if t.startswith("Identifiability and fit warnings")]
    assert warn == ["Identifiability and fit warnings (all) (1/2)",
                    "Identifiability and fit warnings (all) (2/2)"]
    # right after the parameter table
    i = titles.index(warn[0])
    assert titles[i - 1].startswith("Identified parameters")
    # a short list stays on the table page
    _mutate_json(d, "identification.json", lambda o: o.__setitem__("warnings", ["one"]))
    assert not any("warnings (all)" in p.title for p in plan_pages(load_report_dir(d)))


def test_identification_without_predictions_skips_signal_pages(tmp_path):
    d = rf.write_identification_dir(tmp_path / "np")
    (d / "predictions.h5").unlink()
    titles = [p.title for p in plan_pages(load_report_dir(d))]
    assert titles == [FULL_PAGES[i] for i in (0, 1, 2, 5, 6, 7)]


def test_planning_a_report_loads_no_fitting_code(tmp_path):
    """`pmalab report` of result directories asks whether its input is a static
    characterization; answering must not import the identification's compiled laws (numba,
    SciPy: a third of a second before the first page on every report)."""
    d = rf.write_diagnosis_dir(tmp_path / "diag", with_predictions=False)
    code = (
        "import sys\n"
        "from pmalab.reports.build import _plan_for\n"
        "plan, args, _ = _plan_for([sys.argv[1]])\n"
        "assert len(plan(*args).pages) == 5\n"
        "print(sorted(m for m in ('numba', 'scipy', 'pmalab.identify.laws') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(d)], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "[]"
